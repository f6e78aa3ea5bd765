"""``pointfield cloud occupancy`` and ``occupancy-query``: an OctoMap-style map from scans, and questions to it.

===================================  ==============================================================
``pointfield cloud occupancy``       scans with their sensor origins (files and ``--origin``, ``cloud
                                     align``'s ``--poses``, or a ``--scene``'s depth frames,
                                     :mod:`pointfield.volumes.scans`) into
                                     :class:`pointfield.volumes.OccupancyMap`, written as OctoMap
                                     ``.bt`` and / or the occupied cells as a voxel file
``cloud occupancy-query``            :func:`~pointfield.volumes.occupancy.read_octomap`, then
                                     ``state`` and ``distance_to_obstacle`` at given points
===================================  ==============================================================
"""

from __future__ import annotations

import argparse
import contextlib
import math
import time
from pathlib import Path

import numpy as np

from pointfield.cli.cloud_align import matrix_rows_json
from pointfield.errors import PointfieldError
from pointfield.streaming.memory import DEFAULT_MEMORY, parse_memory

MAP_SUFFIXES = (".bt", ".npz", ".binvox", ".vox")
STATES = {1: "occupied", 0: "free", -1: "unknown"}


def add_commands(commands: argparse._SubParsersAction) -> None:
    """Add ``occupancy`` and ``occupancy-query`` to the ``cloud`` subcommands."""
    occupancy = commands.add_parser(
        "occupancy",
        help="an occupancy map (OctoMap .bt, or voxels) from scans and their sensor origins",
        description="Cast a ray from the sensor to every point of every scan, as OctoMap's insertPointCloud does: "
        "the cells a ray crosses are free, the cell it ends in occupied, updated scan by scan in log-odds (hit 0.7, "
        "miss 0.4, clamped); cells no ray reached stay unknown. The scans are SCANS in one frame seen from "
        "--origin, SCANS moved by the poses `cloud align` wrote (each scan's sensor at its own origin, moved with "
        "it), or a scene's depth frames seen from its cameras. Writes each --out: .bt (OctoMap's binary tree, "
        "which octovis, ROS and pyoctomap read) or .npz / .binvox / .vox (the occupied cells, with their "
        "probability in .npz).",
    )
    occupancy.add_argument("scans", type=Path, nargs="*", metavar="SCANS",
                           help="point-cloud files (default with --poses: the scans it names)")
    occupancy.add_argument("--out", type=Path, action="append", required=True, metavar="FILE",
                           help="map to write: .bt, .npz, .binvox or .vox (repeat for several)")
    source = occupancy.add_mutually_exclusive_group()
    source.add_argument("--poses", type=Path, metavar="POSES.json",
                        help="cloud align's poses: scan i's points and sensor moved by its 4 x 4 pose")
    source.add_argument("--scene", type=Path, metavar="SCENE",
                        help="a scene whose frames carry depth (scene from-rgbd's output): each frame a scan from "
                        "its camera")
    occupancy.add_argument("--origin", metavar="X,Y,Z",
                           help="the sensor's position in each scan's own frame (default 0,0,0: a scan in its "
                           "sensor's frame, as a lidar's)")
    occupancy.add_argument("--voxel", type=float, required=True, metavar="S", help="cell side, in the scans' units")
    occupancy.add_argument("--max-range", type=float, metavar="R",
                           help="rays longer than R mark free space up to R and no hit (OctoMap's maxrange)")
    occupancy.add_argument("--stride", type=int, metavar="N",
                           help="--scene: every N-th depth pixel across and down (default 4)")
    occupancy.add_argument("--depth-max", type=float, metavar="M", help="--scene: drop depth farther than M")
    occupancy.add_argument("--memory", metavar="SIZE", default=DEFAULT_MEMORY,
                           help=f"memory the map may take, e.g. 2G (default {DEFAULT_MEMORY}); a voxel too small for it "
                           "is refused, naming the voxel that fits")
    occupancy.add_argument("--json", action="store_true", help="print the summary as JSON")
    occupancy.set_defaults(run=run_occupancy)

    query = commands.add_parser(
        "occupancy-query",
        help="is a point occupied, free or unknown in an OctoMap .bt, and how far is the nearest obstacle",
        description="Read MAP (an OctoMap .bt, ours or OctoMap's) and print, for each point, its cell's state -- "
        "occupied, free or unknown (never seen: not free, a planner must not go there) -- and the distance to "
        "the nearest occupied cell's centre.",
    )
    query.add_argument("map", type=Path, metavar="MAP", help="an OctoMap binary tree (.bt)")
    query.add_argument("--points", nargs="+", action="extend", default=[], metavar="X,Y,Z",
                       help="points to ask about, in the map's units (one starting with a minus as --points=-1,2,3)")
    query.add_argument("--points-file", type=Path, metavar="FILE", help="also every point of a point-cloud file")
    query.add_argument("--memory", metavar="SIZE", default=DEFAULT_MEMORY,
                       help=f"memory reading the map may take (default {DEFAULT_MEMORY})")
    query.add_argument("--json", action="store_true", help="print the answers as JSON")
    query.set_defaults(run=run_query)


def parse_point(text: str, option: str) -> np.ndarray:
    """``"1,2.5,-3"`` -> ``array([1., 2.5, -3.])``; anything else is one line naming ``option``."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise PointfieldError(f"{option} {text!r}: expected three numbers X,Y,Z")
    return np.asarray(values)


def _scan_files(args: argparse.Namespace) -> tuple[list[Path], list[np.ndarray | None] | None]:
    """The scan files and, with ``--poses``, their poses; a count or name that does not match is refused."""
    from pointfield.volumes.scans import read_poses

    if args.poses is None:
        if not args.scans:
            raise PointfieldError("cloud occupancy needs SCANS, --poses or --scene")
        return list(args.scans), None
    entries = read_poses(args.poses)
    if not args.scans:  # the scans cloud align was given, as it recorded them (relative to here, else to the file)
        files = [Path(name) if Path(name).exists() else args.poses.parent / name for name, _ in entries]
        return files, [pose for _, pose in entries]
    if len(args.scans) != len(entries):
        raise PointfieldError(f"{args.poses}: holds {len(entries)} poses but {len(args.scans)} scans were given; "
                              "give the scans cloud align was given, in its order")
    for index, (scan, (name, _)) in enumerate(zip(args.scans, entries)):
        if scan.name != Path(name).name:
            raise PointfieldError(f"{args.poses}: pose {index} is {Path(name).name}'s but scan {index} is {scan.name}; "
                                  "give the scans in cloud align's order")
    return list(args.scans), [pose for _, pose in entries]


def fitting_voxel(scans, voxel: float, max_range: float | None, budget: int) -> float:
    """The smallest voxel (3 significant digits, rounded up) whose map of ``scans`` fits ``budget``."""
    from pointfield.volumes.occupancy import occupancy_bytes

    low, high = voxel, voxel
    while occupancy_bytes(scans, high, max_range) > budget:
        low, high = high, high * 2
    for _ in range(30):
        middle = math.sqrt(low * high)
        low, high = (middle, high) if occupancy_bytes(scans, middle, max_range) > budget else (low, middle)
    digits = 10 ** (math.floor(math.log10(high)) - 2)
    return math.ceil(high / digits) * digits


def _summary(occupancy, scans, seconds: float, outputs: list[Path], notes: list[str]) -> dict:
    occupied = int((occupancy.log_odds > 0).sum())
    known = len(occupancy.keys)
    summary = {"voxel": occupancy.size, "scans": len(scans), "points": int(sum(len(p) for p, _ in scans)),
               "occupied": occupied, "free": known - occupied, "seconds": round(seconds, 3),
               "outputs": [str(p) for p in outputs], "notes": notes}
    if known:
        cells = occupancy.to_grid("known")
        low, high = cells.origin, cells.origin + np.asarray(cells.shape) * occupancy.size
        summary["unknown"] = int(np.prod(np.asarray(cells.shape, np.int64))) - known  # within the known cells' box
        summary["bounds"] = [low.round(6).tolist(), high.round(6).tolist()]
    else:
        summary["unknown"], summary["bounds"] = 0, None
    return summary


def run_occupancy(args: argparse.Namespace) -> int:
    from pointfield.atomic import atomic_path
    from pointfield.volumes import OccupancyMap, write_voxels
    from pointfield.volumes.occupancy import occupancy_bytes, write_octomap
    from pointfield.volumes.scans import scans_from_files, scans_from_scene
    from pointfield.volumes.voxels import human_bytes

    budget = parse_memory(args.memory)  # a bad size is an OptionError, printed as one line
    if not args.voxel > 0:
        raise PointfieldError(f"--voxel must be positive, got {args.voxel}")
    if args.max_range is not None and not args.max_range > 0:
        raise PointfieldError(f"--max-range must be positive, got {args.max_range}")
    for out in args.out:
        if out.suffix.lower() not in MAP_SUFFIXES:
            raise PointfieldError(f"{out}: an occupancy map is written as {', '.join(MAP_SUFFIXES)}")
    if len({o.resolve() for o in args.out}) != len(args.out):
        raise PointfieldError("cloud occupancy: an --out is given twice")
    origin = parse_point(args.origin or "0,0,0", "--origin")
    notes = []
    if args.scene is not None:
        from pointfield.scenes import read_scene

        if args.scans:
            raise PointfieldError("cloud occupancy: give SCANS or --scene, not both")
        if args.origin is not None:
            raise PointfieldError("cloud occupancy: --origin is for scans; a scene's frames are seen from its cameras")
        stride = 4 if args.stride is None else args.stride
        scans = scans_from_scene(read_scene(args.scene, missing_images="keep"), stride, args.depth_max)
        notes.append(f"{len(scans)} depth frames, every {stride}th pixel, each seen from its camera")
    else:
        given = [name for name, value in (("--stride", args.stride), ("--depth-max", args.depth_max)) if value is not None]
        if given:  # options of depth frames: ignored on scans, they would say nothing was wrong
            raise PointfieldError(f"cloud occupancy: {' and '.join(given)} apply to --scene's depth frames, not to scans")
        files, poses = _scan_files(args)
        if {o.resolve() for o in args.out} & {f.resolve() for f in files}:
            raise PointfieldError("cloud occupancy: an --out is one of the scans")
        scans = scans_from_files(files, origin, poses)
        if poses is not None and len(scans) < len(files):
            notes.append(f"{len(files) - len(scans)} scans left out by cloud align, skipped")
    needed = occupancy_bytes(scans, args.voxel, args.max_range)
    if needed > budget:
        fits = fitting_voxel(scans, args.voxel, args.max_range, budget)
        raise PointfieldError(f"a voxel of {args.voxel:g} makes a map that may take {human_bytes(needed)} (the cells "
                              f"its rays cross), more than the {human_bytes(budget)} allowed: a voxel of {fits:g} or "
                              "larger fits (or give more --memory)")
    start = time.perf_counter()
    occupancy = OccupancyMap(args.voxel)
    for points, sensor in scans:
        occupancy.insert_scan(points, sensor, max_range=args.max_range)
    seconds = time.perf_counter() - start
    # Every output is written to a temporary file first and all are renamed at the end: one that cannot be
    # written (a grid too big for .vox, a cell beyond OctoMap's keys) leaves none behind.
    with contextlib.ExitStack() as stack:
        for out in args.out:
            tmp = stack.enter_context(atomic_path(out))
            if out.suffix.lower() == ".bt":
                write_octomap(tmp, occupancy)
            else:
                write_voxels(tmp, occupancy.to_grid("occupied"))
    summary = _summary(occupancy, scans, seconds, args.out, notes)
    if args.json:
        print(matrix_rows_json(summary))
        return 0
    for note in notes:
        print(f"  {note}")
    bounds = "" if summary["bounds"] is None else \
        " from ({}) to ({})".format(*(", ".join(f"{v:.4g}" for v in corner) for corner in summary["bounds"]))
    print(f"{summary['scans']} scans, {summary['points']:,} points, cells of {args.voxel:g}: {summary['occupied']:,} "
          f"occupied, {summary['free']:,} free, {summary['unknown']:,} unknown in the box{bounds} "
          f"({seconds:.2f} s)")
    for out in args.out:
        print(f"wrote {out}")
    return 0


def run_query(args: argparse.Namespace) -> int:
    from pointfield.volumes.occupancy import read_octomap

    budget = parse_memory(args.memory)
    points = [parse_point(text, "point") for text in args.points]
    if args.points_file is not None:
        import pointfield

        points.extend(np.asarray(pointfield.read(args.points_file).points, np.float64))
    if not points:
        raise PointfieldError("cloud occupancy-query: give --points X,Y,Z or --points-file")
    queries = np.asarray(points, np.float64).reshape(-1, 3)
    occupancy = read_octomap(args.map, max_bytes=budget)
    state = occupancy.state(queries)
    distance = occupancy.distance_to_obstacle(queries)
    if args.json:
        print(matrix_rows_json({"map": str(args.map), "voxel": occupancy.size, "points": [
            {"point": q.tolist(), "state": STATES[int(s)], "distance": None if math.isinf(d) else float(d)}
            for q, s, d in zip(queries, state, distance)]}))
        return 0
    for q, s, d in zip(queries, state, distance):
        print(f"{q[0]:g},{q[1]:g},{q[2]:g}: {STATES[int(s)]}, nearest obstacle "
              f"{'none' if math.isinf(d) else f'{d:.4g}'}")
    return 0
