"""``pointfield scene info|convert|cameras|make``: posed-image datasets.

Each subcommand calls the function of the same name and arguments in :mod:`pointfield.scenes`
(``scene_info``, ``convert_scene``, ``plot_cameras``, ``make_scene``). The scenes package (and
torch with it) is imported only when a scene command runs, so other commands start fast.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from collections.abc import Callable
from typing import Any

SCENE_FORMATS = ("blender", "nerfstudio", "llff", "colmap", "npz")
WRITABLE_FORMATS = ("nerfstudio", "blender")
SYNTHETIC_NAMES = ("cube", "spheres", "still-life")
LAYOUTS = ("sphere", "hemisphere", "ring")


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "scene",
        help="posed-image datasets: info, convert, cameras, make",
        description="Read, convert, picture and make posed-image datasets (Blender, nerfstudio / "
        "instant-ngp, LLFF, COLMAP, tiny_nerf npz). Cameras are converted to one convention, "
        "OpenCV: x right, y down, looking down +z, camera-to-world poses.",
    )
    verbs = parser.add_subparsers(dest="verb", metavar="VERB", required=True)

    info = verbs.add_parser(
        "info", help="summarise a dataset: frames, image size, intrinsics, bounds, points"
    )
    info.add_argument("path", help="dataset folder (or its transforms.json / poses_bounds.npy / .npz)")
    info.add_argument("--json", action="store_true", help="print the summary as JSON")
    _reading_options(info)
    info.set_defaults(run=_run_info)

    convert = verbs.add_parser("convert", help="write a dataset in nerfstudio or Blender format")
    convert.add_argument("input", help="dataset to read (any readable format)")
    convert.add_argument("output", help="folder to write (must not exist, or be empty, unless --overwrite)")
    convert.add_argument(
        "--format", choices=WRITABLE_FORMATS, default="nerfstudio", help="output format (default: nerfstudio)"
    )
    convert.add_argument(
        "--from", dest="input_format", choices=SCENE_FORMATS, help="input format (default: detected)"
    )
    convert.add_argument(
        "--downscale", type=int, default=1, metavar="N", help="area-downscale images by N, cameras to match"
    )
    convert.add_argument(
        "--holdout-every", type=int, metavar="N", help="hold every N-th view out as the test split"
    )
    convert.add_argument("--overwrite", action="store_true", help="replace OUTPUT if it exists")
    convert.set_defaults(run=_run_convert)

    cameras = verbs.add_parser("cameras", help="draw the camera frustums and sparse points to a PNG")
    cameras.add_argument("path", help="dataset folder")
    cameras.add_argument("--out", required=True, help="PNG file to write")
    cameras.add_argument(
        "--max-points", type=int, default=20000, help="sparse points to draw at most (default: 20000)"
    )
    _reading_options(cameras)
    cameras.set_defaults(run=_run_cameras)

    make = verbs.add_parser(
        "make", help="render a synthetic scene to a Blender-format dataset with depth and masks"
    )
    make.add_argument("name", choices=SYNTHETIC_NAMES, help="which scene (cube: the lesson's coloured cube)")
    make.add_argument("--out", required=True, help="folder to write")
    make.add_argument("--views", type=int, default=100, help="number of views (default: 100)")
    make.add_argument("--size", type=int, default=100, help="image width and height in pixels (default: 100)")
    make.add_argument(
        "--layout", choices=LAYOUTS, help="camera placement (default: sphere for cube, hemisphere otherwise)"
    )
    make.add_argument(
        "--radius", type=float, default=4.0, help="camera distance from the origin (default: 4)"
    )
    make.add_argument("--overwrite", action="store_true", help="replace --out if it exists")
    make.set_defaults(run=_run_make)


def _reading_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--format", choices=SCENE_FORMATS, help="read as this format (default: detected)")
    parser.add_argument(
        "--holdout-every", type=int, metavar="N", help="hold every N-th view out as the test split"
    )


def _run_info(args: argparse.Namespace) -> int:
    from pointfield.scenes.tools import format_scene_info, scene_info

    info = _with_warnings_printed(
        lambda: scene_info(args.path, format=args.format, holdout_every=args.holdout_every)
    )
    print(json.dumps(info, indent=2) if args.json else format_scene_info(info))
    return 0


def _run_convert(args: argparse.Namespace) -> int:
    from pointfield.scenes.tools import convert_scene

    out = _with_warnings_printed(
        lambda: convert_scene(
            args.input,
            args.output,
            args.format,
            input_format=args.input_format,
            downscale=args.downscale,
            holdout_every=args.holdout_every,
            overwrite=args.overwrite,
        )
    )
    print(f"wrote {out} ({args.format})")
    return 0


def _run_cameras(args: argparse.Namespace) -> int:
    from pointfield.scenes.tools import plot_cameras

    out = _with_warnings_printed(
        lambda: plot_cameras(
            args.path,
            args.out,
            format=args.format,
            holdout_every=args.holdout_every,
            max_points=args.max_points,
        )
    )
    print(f"wrote {out}")
    return 0


def _run_make(args: argparse.Namespace) -> int:
    from pointfield.scenes.synthetic import make_scene

    out = _with_warnings_printed(
        lambda: make_scene(
            args.name,
            args.out,
            args.views,
            args.size,
            layout=args.layout,
            radius=args.radius,
            overwrite=args.overwrite,
        )
    )
    print(f"wrote {out}: {args.views} views of {args.size}x{args.size} ({args.name})")
    return 0


def _with_warnings_printed(action: Callable[[], Any]) -> Any:
    """Run ``action``, printing each warning as one ``pointfield: warning:`` line on stderr."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            return action()
        finally:
            for warning in caught:
                print(f"pointfield: warning: {warning.message}", file=sys.stderr)
