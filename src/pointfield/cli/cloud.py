"""``pointfield cloud info|convert|render``: look inside, convert and draw point-cloud files.

Each subcommand is a thin layer over a Python function:

=============================  ===================================================
``pointfield cloud info``      :func:`pointfield.clouds.summary.describe`
``pointfield cloud convert``   :func:`pointfield.read` then :func:`pointfield.write`
``pointfield cloud render``    :func:`pointfield.viz.render_file`
=============================  ===================================================

The streaming verbs (downsample, crop, tile, merge, ``info --stats``, and ``convert`` of a
folder or with a scale option) are in :mod:`pointfield.cli.cloud_streaming`; ``register`` is in
:mod:`pointfield.cli.cloud_registration`, ``align`` in :mod:`pointfield.cli.cloud_align`; ``planes``, ``clusters`` and ``ground`` in
:mod:`pointfield.cli.cloud_segmentation`.
"""

from __future__ import annotations

import argparse
import inspect
import json
from pathlib import Path
from typing import Any

import pointfield.cli.cloud_occupancy as cloud_occupancy
from pointfield.cli import cloud_align, cloud_registration, cloud_segmentation, cloud_streaming, cloud_volumes
from pointfield.errors import PointfieldError
from pointfield.volumes.files import is_voxel_file

COLUMNS_HELP = (
    "float32 values per point of a raw .bin scan: 4 (KITTI x y z intensity), 5 (nuScenes), "
    "6 (ScanNet x y z r g b), ... (default: 4 or 5, as the file's size, values and name say)"
)


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Add ``cloud`` and its subcommands to the ``pointfield`` parser."""
    group = subparsers.add_parser(
        "cloud",
        help="inspect, convert and render point-cloud files",
        description="Inspect, convert and render point-cloud and mesh files in any supported "
        "format (PLY, PCD, XYZ/TXT/PTS, PTX, NPY/NPZ, OFF, OBJ, STL, GLB/glTF, LAS/LAZ, velodyne .bin, E57).",
    )
    commands = group.add_subparsers(dest="command", metavar="SUBCOMMAND", required=True)

    info = commands.add_parser(
        "info",
        help="format, points, NaN points, fields, bounds",
        description="Print what a file holds: format and encoding, number of points stored "
        "(NaN points included) and how many are NaN, fields and dtypes, bounds, faces.",
    )
    info.add_argument("file", type=Path, help="a point-cloud or mesh file")
    info.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    info.add_argument("--columns", type=int, metavar="N", help=COLUMNS_HELP)
    info.add_argument(
        "--stats",
        action="store_true",
        help="bounds, counts per class and field ranges, computed in one streaming pass",
    )
    cloud_streaming.add_scale_options(info, outputs=False)
    info.set_defaults(run=run_info)

    convert = commands.add_parser(
        "convert",
        help="convert between formats, fields preserved",
        description="Read IN and write OUT in the format its suffix names, keeping every field "
        "the output format can hold (those it cannot are named in a warning).",
    )
    convert.add_argument("source", type=Path, metavar="IN", help="file (or folder of files) to read")
    convert.add_argument("destination", type=Path, metavar="OUT", help="file (or folder) to write")
    encoding = convert.add_mutually_exclusive_group()
    for word in ("ascii", "binary", "compressed"):
        encoding.add_argument(
            f"--{word}",
            dest="encoding",
            action="store_const",
            const=word,
            help=f"write the format's {word} encoding",
        )
    encoding.add_argument(
        "--encoding",
        metavar="NAME",
        help="a format's own encoding name, e.g. binary_big_endian (default: the format's first)",
    )
    convert.add_argument("--columns", type=int, metavar="N", help=COLUMNS_HELP)
    convert.add_argument(
        "--to", metavar="SUFFIX", help="for a folder IN: the outputs' format, e.g. .laz (default: each input's)"
    )
    convert.add_argument(
        "--pattern", metavar="GLOB", help="for a folder IN: which files, e.g. '*.bin' (default: every cloud suffix)"
    )
    cloud_streaming.add_scale_options(convert)
    convert.set_defaults(run=run_convert)

    render = commands.add_parser(
        "render",
        help="draw a cloud to a PNG",
        description="Draw a cloud or mesh from an oblique viewpoint, coloured by its colours, "
        "else its intensity, else its height, and save it as PNG.",
    )
    render.add_argument("file", type=Path,
                        help="a point-cloud, mesh or voxel file (.binvox, .vox, voxel .npz, OctoMap .bt)")
    render.add_argument(
        "--out", type=Path, help="PNG to write (default: FILE's name with .png, here)"
    )
    render.add_argument(
        "--width", type=int, default=800, help="image width in pixels (default 800)"
    )
    render.add_argument(
        "--height", type=int, default=600, help="image height in pixels (default 600)"
    )
    render.add_argument(
        "--up",
        choices=("x", "y", "z", "-x", "-y", "-z"),
        help="axis pointing up, e.g. --up z or --up=-y (default: guessed; z for lidar, terrain "
        "and LAS, -y for camera frames)",
    )
    render.add_argument(
        "--color-by",
        metavar="FIELD",
        help="colors, intensity, height, normals or any scalar field (default: colors, else "
        "intensity, else height)",
    )
    render.add_argument(
        "--point-size",
        type=float,
        metavar="PX",
        help="disc diameter in pixels (default: automatic)",
    )
    render.add_argument("--columns", type=int, metavar="N", help=COLUMNS_HELP)
    render.set_defaults(run=run_render)

    cloud_streaming.add_commands(commands)
    cloud_registration.add_commands(commands)
    cloud_align.add_commands(commands)
    cloud_segmentation.add_commands(commands)
    cloud_volumes.add_commands(commands)
    cloud_occupancy.add_commands(commands)


def read_options(path: Path, columns: int | None) -> dict[str, Any]:
    """Reader options from the command line, refused for formats whose reader has no such option."""
    if columns is None:
        return {}
    from pointfield.clouds.formats import format_of

    fmt = format_of(path)
    if "columns" not in inspect.signature(fmt.read).parameters:
        raise PointfieldError(f"{path}: --columns applies to raw .bin scans, not {fmt.name} files")
    if columns < 3:
        raise PointfieldError(f"--columns must be at least 3 (x y z), got {columns}")
    return {"columns": columns}


def run_info(args: argparse.Namespace) -> int:
    from pointfield.clouds.summary import describe, format_description

    if args.stats:
        return cloud_streaming.run_stats(args)

    info = describe(args.file, **read_options(args.file, args.columns))
    print(json.dumps(info, indent=2) if args.json else format_description(info))
    return 0


def run_convert(args: argparse.Namespace) -> int:
    import pointfield
    from pointfield.clouds.summary import describe, format_and_encoding

    if args.source.is_dir() or cloud_streaming.wants_streaming(args):
        return cloud_streaming.run_streaming_convert(args)

    cloud = pointfield.read(args.source, **read_options(args.source, args.columns))
    pointfield.write(args.destination, cloud, encoding=args.encoding)
    written = describe(args.destination)
    fields = ", ".join(written["fields"]) or "none"
    faces = f", {written['faces']:,} faces" if written["faces"] else ""
    print(
        f"wrote {args.destination}: {format_and_encoding(written['format'], written['encoding'])}, "
        f"{written['points']:,} points{faces}, fields: {fields} ({written['bytes']:,} bytes)"
    )
    return 0


def run_render(args: argparse.Namespace) -> int:
    from pointfield.viz import render_file

    if is_voxel_file(args.file):
        return cloud_volumes.run_render_voxels(args)
    out = args.out or Path(args.file.with_suffix(".png").name)
    render_file(
        args.file,
        out,
        width=args.width,
        height=args.height,
        up=args.up,
        color_by=args.color_by,
        point_size=args.point_size,
        **read_options(args.file, args.columns),
    )
    print(f"wrote {out} ({args.width}x{args.height})")
    return 0
