"""The streaming verbs of ``pointfield cloud``: downsample, crop, tile, merge, and the bounded-memory
and Dask options they share with ``info --stats`` and ``convert``.

Each is a thin layer over a function of :mod:`pointfield.streaming`:

===============================  ==================================================
``pointfield cloud downsample``  :func:`pointfield.streaming.downsample`
``pointfield cloud crop``        :func:`pointfield.streaming.crop`
``pointfield cloud tile``        :func:`pointfield.streaming.tile`
``pointfield cloud merge``       :func:`pointfield.streaming.merge`
``cloud info --stats``           :func:`pointfield.streaming.stats`
``cloud convert`` (streamed)     :func:`pointfield.streaming.convert`, ``convert_folder``
===============================  ==================================================
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from pointfield import streaming
from pointfield.errors import PointfieldError
from pointfield.streaming.statistics import format_stats

COLUMNS_HELP = "float32 values per point of a raw .bin scan (default 4: KITTI x y z intensity)"


def add_scale_options(parser: argparse.ArgumentParser, outputs: bool = True) -> None:
    """``--memory``, ``--points``, ``--workers``, ``--scheduler`` (and for verbs that write,
    ``--scratch``, ``--overwrite``), and ``--no-progress``."""
    scale = parser.add_argument_group("memory and scale")
    scale.add_argument(
        "--memory",
        metavar="SIZE",
        help="resident memory the job may use, e.g. 2G or 512M (default 1G); holds whatever the input size",
    )
    scale.add_argument("--points", type=int, metavar="N", help="points per chunk (default: from --memory)")
    where = scale.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, metavar="N", help="run on a local Dask cluster of N worker processes")
    where.add_argument("--scheduler", metavar="ADDRESS", help="run on an existing Dask cluster, e.g. tcp://host:8786")
    if outputs:
        scale.add_argument(
            "--scratch",
            type=Path,
            metavar="DIR",
            help="folder for temporary spills (default: beside the output; shared storage for remote workers)",
        )
        scale.add_argument("--overwrite", action="store_true", help="redo outputs that already exist")
    scale.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bars")


def scale_options(args: argparse.Namespace, outputs: bool = True) -> dict[str, Any]:
    options: dict[str, Any] = {
        "points": args.points,
        "workers": args.workers,
        "scheduler": args.scheduler,
        "progress": args.progress,
    }
    if args.memory is not None:
        options["memory"] = args.memory
    if outputs:
        options["scratch"] = args.scratch
        options["overwrite"] = args.overwrite
    return options


def wants_streaming(args: argparse.Namespace) -> bool:
    """True when a scale option was given: ``convert`` then streams instead of reading whole."""
    return any(getattr(args, name, None) is not None for name in ("memory", "points", "workers", "scheduler"))


def add_commands(commands: argparse._SubParsersAction) -> None:
    """Add downsample, crop, tile and merge to the ``cloud`` subcommands."""
    downsample = commands.add_parser(
        "downsample",
        help="fewer points: per voxel, at random, or every K-th (streamed)",
        description="Downsample IN into OUT chunk by chunk with bounded memory. --voxel keeps one "
        "point per occupied cube (the centroid, floating-point fields averaged and others from "
        "the voxel's first point, or with --nearest the point nearest the cube's centre); the "
        "result is the in-memory one exactly.",
    )
    downsample.add_argument("source", type=Path, metavar="IN")
    downsample.add_argument("destination", type=Path, metavar="OUT")
    rule = downsample.add_mutually_exclusive_group(required=True)
    rule.add_argument("--voxel", type=float, metavar="S", help="voxel side, in the cloud's units")
    rule.add_argument("--random", type=int, metavar="N", help="keep N points drawn at random (seeded)")
    rule.add_argument("--every", type=int, metavar="K", help="keep points 0, K, 2K, ...")
    downsample.add_argument("--nearest", action="store_true", help="with --voxel: the point nearest each voxel's centre")
    downsample.add_argument("--seed", type=int, default=0, help="seed of --random (default 0)")
    _add_output_options(downsample)
    downsample.set_defaults(run=run_downsample)

    crop = commands.add_parser(
        "crop",
        help="the points inside a box or polygon (streamed)",
        description="Keep the points of IN inside a box (bounds included) or an x y polygon "
        "(even-odd rule), chunk by chunk with bounded memory.",
    )
    crop.add_argument("source", type=Path, metavar="IN")
    crop.add_argument("destination", type=Path, metavar="OUT")
    area = crop.add_mutually_exclusive_group(required=True)
    area.add_argument(
        "--box", type=float, nargs="+", metavar="V",
        help="xmin ymin xmax ymax, or xmin ymin zmin xmax ymax zmax",
    )
    area.add_argument("--polygon", type=Path, metavar="FILE", help="x y vertices, one per line, or GeoJSON")
    _add_output_options(crop)
    crop.set_defaults(run=run_crop)

    tile = commands.add_parser(
        "tile",
        help="square tiles in x y, like PDAL's splitter (streamed)",
        description="Cut IN into square tiles of side --size in x y (tile i, j covers "
        "[origin + i*size, origin + (i+1)*size)), each with the points within --buffer of it "
        "too, written to OUTDIR/<stem>_<i>_<j><suffix> with a tiles.json listing them.",
    )
    tile.add_argument("source", type=Path, metavar="IN")
    tile.add_argument("destination", type=Path, metavar="OUTDIR")
    tile.add_argument("--size", type=float, required=True, metavar="S", help="tile side")
    tile.add_argument("--buffer", type=float, default=0.0, metavar="B", help="overlap added around each tile (default 0)")
    tile.add_argument("--origin", type=float, nargs=2, default=(0.0, 0.0), metavar=("X", "Y"), help="grid origin (default 0 0)")
    tile.add_argument("--to", metavar="SUFFIX", help="tiles' format, e.g. .laz (default: IN's)")
    _add_output_options(tile)
    tile.set_defaults(run=run_tile)

    merge = commands.add_parser(
        "merge",
        help="concatenate clouds into one file (streamed)",
        description="Concatenate the inputs, in order, into OUT chunk by chunk: the fields every "
        "input has, in promoted dtypes; metadata of the first input.",
    )
    merge.add_argument("sources", type=Path, nargs="+", metavar="IN")
    merge.add_argument("destination", type=Path, metavar="OUT")
    merge.add_argument("--drop-buffers", action="store_true",
                       help="the inputs are tiles of `cloud tile --buffer`: keep each tile's own square only, "
                       "so that every point comes once (default: the buffers' points once per tile)")
    _add_output_options(merge)
    merge.set_defaults(run=run_merge)


def _add_output_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--encoding", metavar="NAME", help="output encoding: ascii, binary, compressed or the format's own name")
    parser.add_argument("--columns", type=int, metavar="N", help=COLUMNS_HELP)
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    add_scale_options(parser)


def _report(args: argparse.Namespace, result: dict[str, Any], text: str) -> int:
    if args.json:
        print(json.dumps(result, indent=2, default=str))
    elif not result.get("skipped"):
        print(text)
    return 0


def _kept(args: argparse.Namespace, result: dict[str, Any]) -> str:
    return f"wrote {args.destination}: {result.get('output_points', 0):,} of {result.get('input_points', 0):,} points"


def run_downsample(args: argparse.Namespace) -> int:
    if args.nearest and args.voxel is None:
        raise PointfieldError("--nearest applies to --voxel")
    result = streaming.downsample(
        args.source, args.destination, args.voxel,
        mode="nearest" if args.nearest else "centroid", random=args.random, every=args.every,
        seed=args.seed, encoding=args.encoding, columns=args.columns, **scale_options(args),
    )
    return _report(args, result, _kept(args, result))


def run_crop(args: argparse.Namespace) -> int:
    result = streaming.crop(
        args.source, args.destination, box=args.box, polygon=args.polygon,
        encoding=args.encoding, columns=args.columns, **scale_options(args),
    )
    return _report(args, result, _kept(args, result))


def run_tile(args: argparse.Namespace) -> int:
    result = streaming.tile(
        args.source, args.destination, args.size, buffer=args.buffer, origin=args.origin,
        suffix=args.to, encoding=args.encoding, columns=args.columns, **scale_options(args),
    )
    tiles = result.get("tiles", [])
    return _report(args, result, f"wrote {len(tiles)} tiles to {args.destination} "
                   f"({sum(t['points'] for t in tiles):,} points with buffers)")


def run_merge(args: argparse.Namespace) -> int:
    result = streaming.merge(args.sources, args.destination, encoding=args.encoding, columns=args.columns,
                             drop_buffers=args.drop_buffers, **scale_options(args))
    return _report(args, result, f"wrote {args.destination}: {result.get('output_points', 0):,} points "
                   f"from {len(args.sources)} files")


def run_stats(args: argparse.Namespace) -> int:
    """``cloud info FILE --stats``."""
    info = streaming.stats(args.file, columns=args.columns, **scale_options(args, outputs=False))
    print(json.dumps(info, indent=2) if args.json else format_stats(info))
    return 0


def run_streaming_convert(args: argparse.Namespace) -> int:
    """``cloud convert`` with a folder or a scale option: streamed, per file on Dask."""
    options = scale_options(args)
    if args.source.is_dir():
        options.pop("scratch")
        result = streaming.convert_folder(args.source, args.destination, args.to, pattern=args.pattern,
                                          encoding=args.encoding, columns=args.columns, **options)
        print(f"converted {result['converted']} of {result['files']} files into {args.destination} "
              f"({result['skipped']} already there; {result['points']:,} points)")
        return 0
    if args.to is not None or args.pattern is not None:
        raise PointfieldError("--to and --pattern apply to a folder IN; name OUT with its suffix instead")
    result = streaming.convert(args.source, args.destination, encoding=args.encoding, columns=args.columns,
                               **options)
    if not result.get("skipped"):
        print(f"wrote {args.destination}: {result['output_points']:,} points (streamed)")
    return 0
