"""``pointfield splat train|render|export``: 3D Gaussian splatting on any device.

Each subcommand calls the Python function of the same name and arguments in
:mod:`pointfield.splats.train` (train) and :mod:`pointfield.splats.run` (render, export). torch
is imported only when a subcommand runs, so other commands start fast.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from pointfield.cli.geometry_options import (
    add_cloud_options,
    export_geometry_of,
    opacity_error_text,
    refuse_existing,
)
from pointfield.cli.scene_options import add_scene_training_options
from pointfield.cli.training_options import add_max_time_option, clock_text, scores_text, training_budget
from pointfield.cli.view import add_view_options, training_view

DEVICE_HELP = "auto (default), cpu, cuda, cuda:N or mps"
DEFAULT_MAX_SPLATS = 200_000  # pointfield.splats.train.DEFAULT_MAX_SPLATS, without importing torch


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Add ``splat`` and its subcommands to the ``pointfield`` parser."""
    group = subparsers.add_parser(
        "splat",
        help="train 3D Gaussian splats on posed images, render them, export the standard .ply",
        description="Reconstruct a scene from posed photos as 3D Gaussian splats, in plain PyTorch "
        "(CPU, CUDA or MPS). SCENE is any posed-image dataset pointfield reads; without SCENE, the "
        "built-in synthetic cube. Splat files use the standard layout every splat viewer reads.",
    )
    verbs = group.add_subparsers(dest="verb", metavar="SUBCOMMAND", required=True)

    train = verbs.add_parser("train", help="train splats into a run folder")
    train.add_argument("scene", nargs="?", type=Path, metavar="SCENE",
                       help="posed-image dataset (default: the built-in synthetic cube)")
    train.add_argument("--out", type=Path, default=Path("runs/splat"), help="run folder (default runs/splat)")
    train.add_argument("--steps", type=int, help="optimizer steps, one view each (default 3000)")
    add_max_time_option(train)
    add_scene_training_options(train)
    train.add_argument("--background", help="white, black or 'r,g,b' to composite alpha onto (default: the scene's)")
    train.add_argument("--alpha-loss", type=float, default=None, metavar="WEIGHT",
                       help="weight of |rendered opacity - alpha| in the loss where the images have alpha "
                            "(default 0.1; 0: off)")
    train.add_argument("--opacity-entropy", type=float, default=None, metavar="WEIGHT",
                       help="weight of the splats' mean opacity entropy in the loss: splats opaque or gone, "
                            "for geometry export (default off; 0.1 measured, see docs/geometry.md)")
    train.add_argument("--flatness", type=float, default=None, metavar="WEIGHT",
                       help="weight of the splats' mean smallest scale in the loss: discs along surfaces, "
                            "for geometry export (default off; 1 measured)")
    train.add_argument("--depth-distortion", type=float, default=None, metavar="WEIGHT",
                       help="weight of 2DGS's depth distortion in the loss: each pixel's splats in one thin "
                            "layer, for geometry export (default off; 100 measured, see docs/geometry.md)")
    train.add_argument("--antialiased", action="store_true",
                       help="rasterize in gsplat's antialiased mode (Mip-Splatting's 2D filter): outlines "
                            "where they are (on with --mip, the default; with --no-mip default classic 3DGS)")
    train.add_argument("--screen-dilation", type=float, default=None, metavar="PX2",
                       help="variance in px^2 added to every splat's screen footprint (default 0.1 as "
                            "Mip-Splatting's 2D filter; with --no-mip 0.3 as 3DGS, see docs/geometry.md)")
    train.add_argument("--mip", action=argparse.BooleanOptionalAction, default=None,
                       help="Mip-Splatting's 3D smoothing and 2D mip filters: splats that hold up closer than "
                            "the training cameras (implies --antialiased, dilation 0.1 px^2; default on, "
                            "--no-mip: classic 3DGS)")
    train.add_argument("--mip-smoothing", type=float, default=None, metavar="S",
                       help="strength of the 3D filter: variance in squared training-pixel footprints "
                            "(default 0; Mip-Splatting's 0.2, see docs/splats.md)")
    train.add_argument("--max-splats", type=int, default=DEFAULT_MAX_SPLATS,
                       help=f"densification never grows beyond this many splats (default {DEFAULT_MAX_SPLATS:,})")
    train.add_argument("--initial-splats", type=int, default=20_000,
                       help="random splats to start from when the scene has no sparse points (default 20,000)")
    train.add_argument("--init", choices=("auto", "points", "random"), default="auto",
                       help="start from the scene's sparse points (auto: when it has them) or at random")
    train.add_argument("--strategy", choices=("default", "mcmc"), default="default",
                       help="densification: default (3DGS: clone, split, prune) or mcmc (3DGS-MCMC: relocate "
                            "dead splats, grow to --max-splats; robust to a random start)")
    train.add_argument("--eval-every", type=int, metavar="STEPS", help="score held-out views every STEPS steps (default 250)")
    train.add_argument("--device", help=DEVICE_HELP)
    train.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    train.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint")
    train.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    add_view_options(train)
    train.set_defaults(run=run_train)

    render = verbs.add_parser(
        "render", help="render a run or a splat .ply along a camera path",
        description="Render colour, depth and alpha along a camera path: orbit (a circle around "
        "the scene), spiral (the orbit swinging up and down) or dataset (the scene's own "
        "cameras). SOURCE is a run folder from splat train or any standard splat .ply (which "
        "needs --scene for its cameras). OUT ending in .gif or .mp4 gets a video of colour | "
        "depth | alpha panels (or of the --outputs asked for); anything else is a folder of PNGs, "
        "with depth maps (.npy in scene units, 16-bit PNG) for the depth outputs.",
    )
    render.add_argument("source", type=Path, metavar="RUN|SPLATS.ply", help="a run folder or a splat .ply")
    render.add_argument("--scene", type=Path, help="scene whose cameras to use (default: the run's)")
    render.add_argument("--downscale", type=int, default=1, help="with --scene: divide image sizes by this (default 1)")
    render.add_argument("--path", choices=("orbit", "spiral", "dataset"), default="orbit", help="camera path (default orbit)")
    render.add_argument("--frames", type=int, help="number of frames (default 60; dataset: every camera)")
    render.add_argument("--out", type=Path, default=Path("render.gif"), help="x.gif, x.mp4 or a folder (default render.gif)")
    render.add_argument("--device", help=DEVICE_HELP)
    render.add_argument("--rasterizer", choices=("auto", "pointfield", "gsplat"), default="auto",
                        help="pointfield, gsplat (needs gsplat and a CUDA device) or auto: gsplat where it "
                             "can run (default)")
    render.add_argument("--outputs", nargs="+", metavar="OUTPUT",
                        help="what to write: rgb, depth (expected), median_depth, opacity (default: rgb depth "
                             "opacity); into a folder, depth outputs also come as .npy and 16-bit PNG depth "
                             "maps with their scale in depth_scale.json")
    render.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    render.set_defaults(run=run_render)

    export = verbs.add_parser(
        "export", help="write a run's splats as a standard splat .ply, its centres, or a point cloud of rendered depth"
    )
    export.add_argument("run_dir", type=Path, metavar="RUN", help="a run folder from splat train")
    export.add_argument("--out", type=Path, help="the splat .ply to write (the standard 3DGS layout)")
    export.add_argument("--centres", type=Path, metavar="OUT",
                        help="write the splats' centres as a cloud, coloured by their SH degree-0 colour")
    add_cloud_options(export)
    export.set_defaults(run=run_export)


def run_train(args: argparse.Namespace) -> int:
    from pointfield.splats.train import train

    background = args.background
    if background is not None and "," in background:
        background = [float(value) for value in background.split(",")]
    with training_view(args):
        metrics = train(
            args.scene, out=args.out, steps=args.steps, max_time=training_budget(args), downscale=args.downscale,
            holdout_every=args.holdout_every, background=background, alpha_loss=args.alpha_loss,
            opacity_entropy=args.opacity_entropy, flatness=args.flatness, antialiased=args.antialiased,
            screen_dilation=args.screen_dilation, mip=args.mip, mip_smoothing=args.mip_smoothing,
            depth_distortion=args.depth_distortion,
            device=args.device,
            seed=args.seed,
            resume=args.resume, max_splats=args.max_splats, initial_splats=args.initial_splats,
            init=args.init, strategy=args.strategy, eval_every=args.eval_every, progress=args.progress,
        )
        print(f"splat run {args.out}: {scores_text(metrics)}, {opacity_error_text(metrics)}{metrics['splats']:,} splats "
              f"({clock_text(metrics, args)}); see {args.out / 'metrics.json'}")
    return 0


def run_render(args: argparse.Namespace) -> int:
    from pointfield.splats.run import render
    from pointfield.viz.views import PANELS

    result = render(args.source, scene=args.scene, downscale=args.downscale, path=args.path,
                    frames=args.frames, out=args.out, device=args.device, rasterizer=args.rasterizer,
                    outputs=args.outputs or PANELS, progress=args.progress)
    print(f"wrote {result['frames']} frames ({result['path']}, {result['splats']:,} splats, "
          f"{result['rasterizer']} rasterizer) to {result['out']}")
    return 0


def run_export(args: argparse.Namespace) -> int:
    from pointfield.errors import PointfieldError
    from pointfield.splats.run import export, export_centres

    if args.out is None and args.centres is None and args.cloud is None and args.mesh is None:
        raise PointfieldError("splat export needs --out (splats), --centres, --cloud or --mesh")
    refuse_existing(args, "out", "centres", "mesh", "cloud")
    if args.out is not None:
        result = export(args.run_dir, args.out)
        print(f"wrote {result['splats']:,} splats (SH degree {result['sh_degree']}) to {result['out']}")
    if args.centres is not None:
        result = export_centres(args.run_dir, args.centres)
        print(f"wrote {result['points']:,} splat centres to {result['out']}")
    if args.cloud is not None or args.mesh is not None:
        export_geometry_of(args)
    return 0
