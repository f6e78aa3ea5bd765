"""``pointfield scene info|convert|cameras|make|from-images|from-video``: posed-image datasets.

Each subcommand calls the function of the same name and arguments in :mod:`pointfield.scenes`
(``scene_info``, ``convert_scene``, ``plot_cameras``, ``make_scene``, ``pose_images``,
``pose_video``). The scenes package (and torch with it) is imported only when a scene command
runs, so other commands start fast.
"""

from __future__ import annotations

import argparse
import json

from pointfield.cli import scene_rgbd

SCENE_FORMATS = ("blender", "nerfstudio", "llff", "colmap", "npz")
WRITABLE_FORMATS = ("nerfstudio", "blender")
SYNTHETIC_NAMES = ("cube", "textured-cube", "spheres", "still-life", "textured")
# Mirrors of pointfield.scenes.sfm.pipeline's choices, so that --help needs no pycolmap import.
MATCHING = ("auto", "exhaustive", "retrieval", "sequential")
MAPPERS = ("auto", "incremental", "global")
SFM_CAMERA_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")
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
    make.add_argument("name", choices=SYNTHETIC_NAMES, help="which scene (cube: the lesson's coloured cube; textured-cube: the cube with a texture that pins its faces' depth across views; textured: one that structure from motion can pose)")
    make.add_argument("--out", required=True, help="folder to write")
    make.add_argument("--views", type=int, default=100, help="number of views (default: 100)")
    make.add_argument("--size", type=int, default=100, help="image width and height in pixels (default: 100)")
    make.add_argument(
        "--layout", choices=LAYOUTS, help="camera placement (default: sphere for cube, hemisphere otherwise)"
    )
    make.add_argument(
        "--radius", type=float, default=4.0, help="camera distance from the origin (default: 4)"
    )
    make.add_argument(
        "--supersampling", type=int, default=2,
        help="rays per pixel along each axis, averaged as a camera's pixel averages light (default: 2; "
             "1 gives staircase silhouettes)",
    )
    make.add_argument("--overwrite", action="store_true", help="replace --out if it exists")
    make.set_defaults(run=_run_make)

    from_images = verbs.add_parser(
        "from-images",
        help="pose your own photos by structure from motion (pycolmap, CPU) into a scene",
        description="Find camera poses for a folder of photos (SIFT features, matching, COLMAP "
        "mapping), undistort them and write a scene that `nerf train` and `splat train` take as "
        "it is: transforms.json, colmap/sparse/0, points3D.ply, images_2/4/8, report.json, "
        "cameras.png. A killed run restarts from its last finished stage.",
    )
    from_images.add_argument("photos", nargs="+", help="a folder of photos, or photo files")
    _posing_options(from_images)
    from_images.set_defaults(run=_run_from_images)

    from_video = verbs.add_parser(
        "from-video",
        help="pose the sharpest frames of a video by structure from motion into a scene",
        description="Pick the sharpest frame of each stretch of a video (variance of the "
        "Laplacian), then pose them as `scene from-images` does (sequential matching with "
        "retrieval to close loops).",
    )
    from_video.add_argument("clip", help="video file (anything ffmpeg decodes)")
    from_video.add_argument("--frames", type=int, default=150, help="frames to pose (default: 150)")
    _posing_options(from_video)
    from_video.set_defaults(run=_run_from_video)
    scene_rgbd.add_commands(verbs)


def _posing_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, help="scene folder to write (must not exist unless --overwrite)")
    parser.add_argument(
        "--max-size", type=int, default=800, help="longer image side for features, pixels (default: 800)"
    )
    parser.add_argument("--features", type=int, default=8192, help="SIFT features per image at most (default: 8192)")
    parser.add_argument(
        "--matching",
        choices=MATCHING,
        default="auto",
        help="image pairs to match (default: auto -- exhaustive up to 30 photos, retrieval above, "
        "sequential plus retrieval for video)",
    )
    parser.add_argument(
        "--neighbours", type=int, default=10, help="retrieval partners per image (default: 10)"
    )
    parser.add_argument(
        "--mapper",
        choices=MAPPERS,
        default="auto",
        help="incremental (COLMAP), global (GLOMAP), or auto: incremental, and where it leaves images out "
        "global too, keeping the model with more images (default)",
    )
    parser.add_argument(
        "--camera-model", choices=SFM_CAMERA_MODELS, default="SIMPLE_RADIAL", help="default: SIMPLE_RADIAL"
    )
    parser.add_argument("--overwrite", action="store_true", help="replace --out if it exists")
    # --quiet was this group's own name for it; kept so that scripts written with it still run.
    parser.add_argument("--no-progress", "--quiet", dest="progress", action="store_false", help="no progress bars")


def _posing_settings(args: argparse.Namespace):
    from pointfield.scenes.sfm import PosingOptions

    return PosingOptions(
        max_size=args.max_size,
        features=args.features,
        matching=args.matching,
        neighbours=args.neighbours,
        mapper=args.mapper,
        camera_model=args.camera_model,
    )


def _run_from_images(args: argparse.Namespace) -> int:
    from pointfield.scenes.sfm import pose_images

    photos = args.photos[0] if len(args.photos) == 1 else args.photos
    report = pose_images(
        photos, args.out, options=_posing_settings(args), overwrite=args.overwrite, progress=args.progress
    )
    print(report.format())
    return 0


def _run_from_video(args: argparse.Namespace) -> int:
    from pointfield.scenes.sfm import pose_video

    report = pose_video(args.clip, args.out, frames=args.frames, options=_posing_settings(args),
                        overwrite=args.overwrite, progress=args.progress)
    print(report.format())
    return 0


def _reading_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--format", choices=SCENE_FORMATS, help="read as this format (default: detected)")
    parser.add_argument(
        "--holdout-every", type=int, metavar="N", help="hold every N-th view out as the test split"
    )


def _run_info(args: argparse.Namespace) -> int:
    from pointfield.scenes.tools import format_scene_info, scene_info

    info = scene_info(args.path, format=args.format, holdout_every=args.holdout_every)
    print(json.dumps(info, indent=2) if args.json else format_scene_info(info))
    return 0


def _run_convert(args: argparse.Namespace) -> int:
    from pointfield.scenes.tools import convert_scene

    out = convert_scene(args.input, args.output, args.format, input_format=args.input_format,
                        downscale=args.downscale, holdout_every=args.holdout_every, overwrite=args.overwrite)
    print(f"wrote {out} ({args.format})")
    return 0


def _run_cameras(args: argparse.Namespace) -> int:
    from pointfield.scenes.tools import plot_cameras

    out = plot_cameras(args.path, args.out, format=args.format, holdout_every=args.holdout_every,
                       max_points=args.max_points)
    print(f"wrote {out}")
    return 0


def _run_make(args: argparse.Namespace) -> int:
    from pointfield.scenes.synthetic import make_scene

    out = make_scene(args.name, args.out, args.views, args.size, layout=args.layout, radius=args.radius,
                     supersampling=args.supersampling, overwrite=args.overwrite)
    print(f"wrote {out}: {args.views} views of {args.size}x{args.size} ({args.name})")
    return 0

