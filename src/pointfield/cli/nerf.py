"""``pointfield nerf train|eval|render|export|exercise``: radiance fields (TinyNeRF, NeRF, the hash-grid field ngp).

Each subcommand calls the Python function of the same name and arguments:
:func:`pointfield.fields.train.train`, :func:`pointfield.fields.run.evaluate`,
:func:`pointfield.fields.run.render`, :func:`pointfield.exercises.tinynerf.exercise`. torch is
imported only when a subcommand runs, so other commands start fast.
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


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Add ``nerf`` and its subcommands to the ``pointfield`` parser."""
    group = subparsers.add_parser(
        "nerf",
        help="train radiance fields on posed images and render new views (hash-grid ngp, TinyNeRF, NeRF)",
        description="Reconstruct a scene from posed photos as a radiance field and render new views: "
        "ngp, the hash-grid field (Instant-NGP; the default, minutes on a CPU), TinyNeRF (the lesson's "
        "small MLP) or NeRF (the original). SCENE is any posed-image dataset pointfield reads "
        "(Blender / NeRF-synthetic, nerfstudio transforms.json, LLFF, COLMAP, tiny_nerf_data.npz); "
        "without SCENE, the built-in synthetic cube.",
    )
    verbs = group.add_subparsers(dest="verb", metavar="SUBCOMMAND", required=True)

    train = verbs.add_parser("train", help="train a radiance field (default: the hash-grid field, ngp) into a run folder")
    train.add_argument("scene", nargs="?", type=Path, metavar="SCENE",
                       help="posed-image dataset (default: the built-in synthetic cube)")
    train.add_argument("--model", choices=("tiny", "nerf", "ngp", "sdf"), default="ngp",
                       help="ngp (hash grid, occupancy grid / proposal sampler: the fast one; default), "
                       "tiny (the lesson's TinyNeRF, 4x128, 64 samples), nerf (8x256 coarse + fine) or sdf "
                       "(a hash-grid signed distance field rendered as NeuS: export --mesh gives its closed "
                       "zero level set)")
    train.add_argument("--out", type=Path, default=Path("runs/nerf"), help="run folder (default runs/nerf)")
    train.add_argument("--steps", type=int, help="optimizer steps (default: tiny 2000, nerf 5000, ngp and sdf 3000)")
    add_max_time_option(train)
    train.add_argument("--batch-rays", type=int, default=1024, help="rays per step (default 1024)")
    add_scene_training_options(train)
    train.add_argument("--background", help="white, black or 'r,g,b' to composite alpha onto (default: the scene's)")
    train.add_argument("--random-background", action=argparse.BooleanOptionalAction, default=None,
                       help="train as if a random colour were behind each ray (in expectation), so that opacity "
                            "matches the images' alpha (default: on where the images have alpha)")
    train.add_argument("--alpha-loss", type=float, default=None, metavar="WEIGHT",
                       help="add WEIGHT x |rendered opacity - alpha| to the loss where the images have alpha "
                            "(default 0: off)")
    train.add_argument("--distortion", type=float, default=None, metavar="WEIGHT",
                       help="weight of the distortion loss, which keeps each ray's density in one thin layer: "
                            "surfaces where they are, for meshes and clouds (default: 0.01 for ngp on a bounded scene, 0 otherwise)")
    train.add_argument("--eval-every", type=int, metavar="STEPS",
                       help="evaluate on held-out views every STEPS steps (default: every epoch, at most 500)")
    train.add_argument("--lr", dest="learning_rate", type=float,
                       help="Adam learning rate, decayed to a tenth over the run (default: 5e-4, ngp and sdf 1e-2)")
    train.add_argument("--scene-box", default="auto", metavar="BOX",
                       help="ngp and sdf only: auto (default: objects on transparent backgrounds are bounded, "
                       "real photos unbounded), bounded, unbounded, or 'x0,y0,z0,x1,y1,z1' (a bounded box)")
    train.add_argument("--device", help=DEVICE_HELP)
    train.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    train.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint")
    train.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    add_view_options(train)
    train.set_defaults(run=run_train)

    evaluate = verbs.add_parser("eval", help="PSNR and SSIM of a trained run on its held-out views")
    evaluate.add_argument("run_dir", type=Path, metavar="RUN", help="a run folder from nerf train")
    evaluate.add_argument("--device", help=DEVICE_HELP)
    evaluate.add_argument("--json", action="store_true", help="print JSON")
    evaluate.set_defaults(run=run_eval)

    render = verbs.add_parser(
        "render", help="render a trained run along a camera path",
        description="Render colour, depth and opacity along a camera path: orbit (a circle around "
        "the scene), spiral (the orbit swinging up and down) or dataset (the scene's own "
        "cameras). OUT ending in .gif or .mp4 gets a video of colour | depth | opacity panels "
        "(or of the --outputs asked for); anything else is a folder of PNGs, with depth maps "
        "(.npy in scene units, 16-bit PNG) for the depth outputs.",
    )
    render.add_argument("run_dir", type=Path, metavar="RUN", help="a run folder from nerf train")
    render.add_argument("--path", choices=("orbit", "spiral", "dataset"), default="orbit", help="camera path (default orbit)")
    render.add_argument("--frames", type=int, help="number of frames (default 60; dataset: every camera)")
    render.add_argument("--out", type=Path, default=Path("render.gif"), help="x.gif, x.mp4 or a folder (default render.gif)")
    render.add_argument("--outputs", nargs="+", metavar="OUTPUT",
                        help="what to write: rgb, depth (expected), median_depth, opacity (default: rgb depth "
                             "opacity); into a folder, depth outputs also come as .npy and 16-bit PNG depth "
                             "maps with their scale in depth_scale.json")
    render.add_argument("--device", help=DEVICE_HELP)
    render.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    render.set_defaults(run=run_render)

    export = verbs.add_parser(
        "export", help="geometry from a trained run: a point cloud or a mesh of rendered depth",
        description="Render the run from the training views (or an orbit) and back-project every "
        "pixel opaque enough into a point with its colour and normal; crop, drop stray points, thin, "
        "and write any point-cloud format. --mesh fuses the rendered depth into a mesh, or with "
        "--method density meshes the field's density itself (a bounded scene: an object in a box).",
    )
    export.add_argument("run_dir", type=Path, metavar="RUN", help="a run folder from nerf train")
    add_cloud_options(export)
    export.set_defaults(run=run_export)

    exercise = verbs.add_parser(
        "exercise", help="the lesson's exercise: TinyNeRF on the cube, as DIR/REPORT.md",
        description="Train TinyNeRF on the synthetic cube for 100 epochs (about 20 minutes on a "
        "2-core laptop CPU: one epoch costs about 18 CPU-seconds; docs/runs.md) and write DIR/REPORT.md: "
        "loss and held-out PSNR at epochs 1, 10 and 100, a "
        "strip of held-out renders, and the first epoch reaching 20 dB.",
    )
    exercise.add_argument("--out", type=Path, default=Path("nerf-exercise"), help="report folder (default nerf-exercise)")
    exercise.add_argument("--epochs", type=int, default=100, help="epochs (default 100)")
    exercise.add_argument("--device", help=DEVICE_HELP)
    exercise.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    exercise.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    exercise.set_defaults(run=run_exercise)


def run_train(args: argparse.Namespace) -> int:
    from pointfield.fields.train import train

    background = args.background
    if background is not None and "," in background:
        background = [float(value) for value in background.split(",")]
    with training_view(args):
        metrics = train(
            args.scene, model=args.model, out=args.out, steps=args.steps, max_time=training_budget(args),
            batch_rays=args.batch_rays, downscale=args.downscale, holdout_every=args.holdout_every,
            background=background, random_background=args.random_background, alpha_loss=args.alpha_loss, distortion=args.distortion, device=args.device, seed=args.seed, resume=args.resume,
            eval_every=args.eval_every, learning_rate=args.learning_rate, progress=args.progress,
            scene_box=[float(v) for v in args.scene_box.split(",")] if "," in args.scene_box else args.scene_box,
        )
        print(f"nerf run {args.out}: {scores_text(metrics)}, {opacity_error_text(metrics)}({clock_text(metrics, args)}); "
              f"see {args.out / 'metrics.json'}")
    return 0


def run_eval(args: argparse.Namespace) -> int:
    from pointfield.fields.run import evaluate
    from pointfield.training.run import to_json

    metrics = evaluate(args.run_dir, device=args.device)
    if args.json:
        print(to_json(metrics, indent=2))
    else:
        print(f"{metrics['views']} held-out views: PSNR {metrics['psnr']:.2f} dB, SSIM {metrics['ssim']:.4f} "
              f"({metrics['render_seconds_per_view']:.2f} s per view)")
    return 0


def run_export(args: argparse.Namespace) -> int:
    from pointfield.errors import PointfieldError

    if args.cloud is None and args.mesh is None:
        raise PointfieldError("nerf export needs --cloud OUT or --mesh OUT")
    refuse_existing(args, "mesh", "cloud")
    export_geometry_of(args)
    return 0


def run_render(args: argparse.Namespace) -> int:
    from pointfield.fields.run import render
    from pointfield.viz.views import PANELS

    result = render(args.run_dir, path=args.path, frames=args.frames, out=args.out, device=args.device,
                    outputs=args.outputs or PANELS, progress=args.progress)
    print(f"wrote {result['frames']} frames ({result['path']}) to {result['out']}")
    return 0


def run_exercise(args: argparse.Namespace) -> int:
    from pointfield.exercises.tinynerf import exercise

    result = exercise(args.out, epochs=args.epochs, device=args.device, seed=args.seed, progress=args.progress)
    reached = result["recognisable_epoch"]
    print(f"wrote {args.out / 'REPORT.md'}: recognisable (>= 20 dB held-out) at "
          + (f"epoch {reached}" if reached is not None else "no epoch"))
    return 0
