"""``pointfield cloud align``: many scans into one frame, and one merged cloud.

A thin layer over :func:`pointfield.registration.align` (every overlapping pair registered, a
pose graph with loop closures optimised); the scans are read within ``--memory``
(:func:`~pointfield.registration.streamed.read_scans`: whole, or thinned while streaming) and
the merged cloud is written chunk by chunk from the original files
(:func:`~pointfield.registration.streamed.write_moved`), every field kept. The poses go to a
JSON file beside it, written atomically.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

from pointfield.errors import PointfieldError
from pointfield.streaming.memory import DEFAULT_MEMORY


def add_commands(commands: argparse._SubParsersAction) -> None:
    """Add ``align`` to the ``cloud`` subcommands."""
    align = commands.add_parser(
        "align",
        help="register many scans into one frame and write them as one cloud, with their poses",
        description="Register every pair of SCANS, link the pairs that overlap (fitness at least --min-fitness), "
        "optimise the poses over a pose graph whose loop closures are checked against the rest (as open3d's "
        "multiway registration), then write every scan moved into one frame (the first scan's, unless it overlaps none) as one cloud (OUT, any "
        "format, streamed: any size, every field kept) and the poses beside it. A scan that overlaps none is "
        "left out, with a warning.",
    )
    align.add_argument("scans", type=Path, nargs="+", metavar="SCANS", help="two or more point-cloud files, in "
                       "acquisition order where there is one (consecutive scans are tried as odometry first)")
    align.add_argument("--out", type=Path, required=True, metavar="OUT", help="the merged cloud (format from its suffix)")
    align.add_argument("--poses", type=Path, metavar="POSES.json",
                       help="where the poses go: per scan a 4x4 into the reference frame, per pair fitness and RMSE "
                       "(default: OUT with .poses.json)")
    align.add_argument("--method", default="auto", choices=("auto", "icp", "plane", "gicp", "colored", "global"),
                       help="pairwise registration: auto (default: global, then the fine step chosen by what the "
                       "clouds carry), global (FPFH + RANSAC from any pose, then the fine step), or a fine method from "
                       "identity, for scans already roughly in one frame: icp (point-to-point), plane (point-to-plane), "
                       "gicp (generalized), colored (Park et al.; every scan needs colours)")
    align.add_argument("--voxel", type=float, metavar="S",
                       help="scale of the problem in the scans' units, for every pair (default: the first scan's "
                       "median point spacing)")
    align.add_argument("--max-distance", type=float, metavar="D", help="inlier distance (default: the voxel)")
    align.add_argument("--min-fitness", type=float, default=0.2, metavar="F",
                       help="a pair overlaps when this share of its source lies within the inlier distance (default 0.2)")
    align.add_argument("--kernel", choices=("huber", "tukey"), help="robust kernel against outliers (default none)")
    align.add_argument("--seed", type=int, default=0, help="seed of RANSAC (default 0)")
    align.add_argument("--memory", metavar="SIZE", default=DEFAULT_MEMORY,
                       help=f"memory registration may take, e.g. 2G (default {DEFAULT_MEMORY}); scans that do not fit "
                       "are thinned to the voxel while reading, and refused naming the voxel that fits if still too big")
    align.set_defaults(run=run_align)


def poses_path(out: Path) -> Path:
    """The default ``--poses``: ``merged.laz`` -> ``merged.poses.json``."""
    return out.with_name(out.name[: len(out.name) - len(out.suffix)] + ".poses.json")


def matrix_rows_json(document: dict) -> str:
    """``document`` as indented JSON with each row of a 4 x 4 matrix on one line, as a reader scans it."""
    text = json.dumps(document, indent=2)
    return re.sub(r"\[\s+([-+0-9.eE]+(?:,\s+[-+0-9.eE]+)*)\s+\]",
                  lambda m: "[" + ", ".join(v.strip() for v in m.group(1).split(",")) + "]", text)


def run_align(args: argparse.Namespace) -> int:
    from pointfield.atomic import atomic_path
    from pointfield.registration import align
    from pointfield.registration.streamed import read_scans, write_moved

    if len(args.scans) < 2:
        raise PointfieldError(f"cloud align needs at least two scans, got {len(args.scans)}")
    if len(set(map(str, args.scans))) != len(args.scans):
        raise PointfieldError("cloud align: a scan is given twice")
    poses_file = args.poses or poses_path(args.out)
    if poses_file.resolve() == args.out.resolve() or args.out.resolve() in {s.resolve() for s in args.scans}:
        raise PointfieldError(f"{args.out}: --out must differ from the scans and from --poses")
    clouds, notes = read_scans(args.scans, args.voxel, args.memory, "alignment", scratch=args.out.resolve().parent)
    names = [s.name if len({p.name for p in args.scans}) == len(args.scans) else str(s) for s in args.scans]
    result = align(clouds, method=args.method, voxel=args.voxel, max_distance=args.max_distance,
                   min_fitness=args.min_fitness, kernel=args.kernel, names=names, seed=args.seed)
    for note in notes + result.notes:
        print(f"  {note}", file=sys.stderr)
    for pair in result.pairs:
        what = pair.kind + (" (pruned)" if pair.kind == "loop closure" and pair.weight == 0 else "") if pair.linked \
            else (f"not linked ({pair.error})" if pair.error else "not linked")
        print(f"{names[pair.source]} -> {names[pair.target]}: fitness {pair.fitness:.3f}, RMSE {pair.rmse:.4g}: {what}")
    written = write_moved(args.scans, result.poses, args.out, memory=args.memory)
    document = result.as_dict([str(s) for s in args.scans])
    document["merged"] = {"file": str(args.out), "points": written}
    with atomic_path(poses_file) as tmp:
        tmp.write_text(matrix_rows_json(document) + "\n")
    kept = len(args.scans) - len(result.left_out)
    left = f"; left out: {', '.join(names[i] for i in result.left_out)}" if result.left_out else ""
    print(f"wrote {args.out}: {written:,} points from {kept} scans in {names[result.reference]}'s frame{left}")
    print(f"wrote {poses_file}: {kept} poses, {sum(p.linked for p in result.pairs)} linked pairs")
    return 0
