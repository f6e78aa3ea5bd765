"""Occupancy maps from RGB-D frames: pointfield's OccupancyMap against OctoMap (pyoctomap), same run.

The claim (issue 46): :class:`pointfield.volumes.OccupancyMap` -- OctoMap's update rule, rays traversed
by a vectorised 3D DDA in numpy -- gives OctoMap's map, marks no free space where a surface was
measured more often than OctoMap does, and its time per scan is stated beside OctoMap's.

Data: shared/data's ICL-NUIM living room (60 depth frames of 640 x 480, Open3D's camera-to-world
trajectory, PrimeSense intrinsics), every ``--stride``-th pixel in each direction back-projected
(depth in millimetres, 0 = no reading), each frame one scan from its camera centre, ``--voxel``
cells, no range limit. Both insert the same points; OctoMap through pyoctomap's
``OcTree.insertPointCloud`` (its C++ ``insertPointCloud``). Scored on the final maps: the share of
the cells either knows where both say the same (occupied / free / unknown), and for each, the
share of its free cells in which some frame measured a surface point.

Reading a ``.bt`` (issue 46, later): a KITTI sweep (shared/data's SemanticKITTI scan 000000, 124,668
points, from the sensor at the origin) mapped by OctoMap at ``--read-voxel`` and written twice, pruned
by OctoMap's ``writeBinary`` and unpruned by our ``write_octomap``. Each is read by ``read_octomap``
(the tree parsed a level at a time), by the reader it replaced (``read_octomap_by_walk``: the tree
walked node by node) and by OctoMap's ``readBinary`` through pyoctomap,
interleaved in the same run. OctoMap only builds its tree; ours also expands pruned leaves into cells
and sorts the map's keys.

Run: ``python benchmarks/bench_occupancy.py`` (``make bench-occupancy``); the record goes to
``benchmarks/records/occupancy.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from harness import Record, interleaved

ROOM = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "rgbd" / "livingroom1_micro"
SWEEP = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "kitti" / "semantickitti_seq00" / "000000.bin"


def frames(stride: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """``(points (N, 3), camera centre (3,))`` per frame, in world coordinates."""
    from PIL import Image

    camera = json.loads((ROOM / "camera_primesense.json").read_text())
    k = np.asarray(camera["intrinsic_matrix"], np.float64).reshape(3, 3).T  # stored column by column
    rows = (ROOM / "open3d_trajectory.log").read_text().split("\n")
    poses = [np.array([[float(v) for v in rows[5 * i + j].split()] for j in range(1, 5)])
             for i in range(len(rows) // 5)]
    out = []
    for index, path in enumerate(sorted((ROOM / "depth").glob("*.png"))):
        depth = np.asarray(Image.open(path), np.float64)[::stride, ::stride] / 1000.0
        v, u = np.mgrid[0 : depth.shape[0] * stride : stride, 0 : depth.shape[1] * stride : stride]
        seen = depth > 0
        z = depth[seen]
        x = (u[seen] - k[0, 2]) * z / k[0, 0]
        y = (v[seen] - k[1, 2]) * z / k[1, 1]
        pose = poses[index]
        points = np.stack([x, y, z], axis=1) @ pose[:3, :3].T + pose[:3, 3]
        out.append((points, pose[:3, 3].copy()))
    return out


def read_section(record: Record, voxel: float, repeats: int) -> None:
    """Time reading the KITTI sweep's map as a pruned and an unpruned ``.bt`` (module docstring), same run."""
    import pyoctomap

    from pointfield.volumes.occupancy import read_octomap, read_octomap_by_walk, write_octomap

    points = np.fromfile(SWEEP, np.float32).reshape(-1, 4)[:, :3].astype(np.float64)
    tree = pyoctomap.OcTree(voxel)
    tree.insertPointCloud(points, np.zeros(3))
    rows, same = [], True
    with tempfile.TemporaryDirectory() as folder:
        pruned, unpruned = Path(folder) / "octomap.bt", Path(folder) / "pointfield.bt"
        tree.writeBinary(str(pruned))
        write_octomap(unpruned, read_octomap(pruned))
        for label, path in (("pruned, by OctoMap", pruned), ("unpruned, by pointfield", unpruned)):
            def octomap(path: Path = path) -> None:
                pyoctomap.OcTree(voxel).readBinary(str(path))

            fast, old = read_octomap(path), read_octomap_by_walk(path)
            same &= fast.keys.tobytes() == old.keys.tobytes() and fast.log_odds.tobytes() == old.log_odds.tobytes()
            timings = interleaved({"levels": lambda path=path: read_octomap(path), "octomap": octomap}, repeats)
            walked = interleaved({"walk": lambda path=path: read_octomap_by_walk(path)}, 1, warmup=0)["walk"]
            record.figures[f"read_{'pruned' if 'OctoMap' in label else 'unpruned'}"] = {
                "bytes": path.stat().st_size, "cells": len(fast.keys), "levels_seconds": timings["levels"].median,
                "walk_seconds": walked.median, "octomap_seconds": timings["octomap"].median}
            rows.append([label, f"{path.stat().st_size:,}", f"{len(fast.keys):,}", f"{timings['levels'].median:.2f}",
                         f"{walked.median:.2f}", f"{timings['octomap'].median:.2f}",
                         f"{walked.median / timings['levels'].median:.1f}x",
                         f"{timings['levels'].median / timings['octomap'].median:.1f}x"])
    record.table(["file", "bytes", "cells", "read_octomap s", "old walk s", "OctoMap readBinary s",
                  "walk / levels", "levels / OctoMap"], rows,
                 title=f"Reading a .bt: a KITTI sweep ({len(points):,} points) mapped by OctoMap at {voxel} m; "
                       f"median of {repeats} interleaved reads (the walk once)")
    record.verdict("the level-by-level read gives the walk's map byte for byte, pruned and unpruned", same)
    speedups = [float(row[6][:-1]) for row in rows]
    record.verdict("reading a .bt is at least 5x faster than the node-by-node walk", min(speedups) >= 5,
                   " and ".join(row[6] for row in rows))


def main() -> int:
    import pyoctomap

    from pointfield.volumes.occupancy import OccupancyMap

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--voxel", type=float, default=0.05, help="cell side in metres (default 0.05)")
    parser.add_argument("--stride", type=int, default=4, help="every N-th pixel across and down (default 4)")
    parser.add_argument("--read-voxel", type=float, default=0.1,
                        help="cell side of the KITTI sweep's map whose .bt is read (default 0.1)")
    parser.add_argument("--read-repeats", type=int, default=3, help="interleaved reads timed (default 3)")
    args = parser.parse_args()
    if not (ROOM / "open3d_trajectory.log").is_file():
        raise SystemExit(f"no living room at {ROOM}")
    scans = frames(args.stride)
    record = Record(
        "occupancy", "Occupancy maps from RGB-D frames: OccupancyMap against OctoMap", issue="46",
        about="`volumes.OccupancyMap` (OctoMap's log-odds rule, exact DDA rays in numpy) against OctoMap's C++ "
              "insertPointCloud through pyoctomap, in the same run, on shared/data's ICL-NUIM living room: "
              f"{len(scans)} depth frames, every {args.stride}th pixel, cells of {args.voxel} m; and reading a .bt "
              "(read_octomap against the node-by-node walk it replaced and OctoMap's readBinary) of a KITTI sweep's "
              "map. The machine was shared with other jobs: times are noisy.")
    ours, tree = OccupancyMap(args.voxel), pyoctomap.OcTree(args.voxel)
    ours_seconds, theirs_seconds = [], []
    for points, origin in scans:  # alternate the two, scan by scan
        start = time.perf_counter()
        ours.insert_scan(points, origin)
        ours_seconds.append(time.perf_counter() - start)
        start = time.perf_counter()
        tree.insertPointCloud(points, origin)
        theirs_seconds.append(time.perf_counter() - start)
    centres = ours.to_grid("known").centres()
    theirs = np.array([-1 if (node := tree.search(c)) is None else int(tree.isNodeOccupied(node)) for c in centres])
    mine = ours.state(centres)
    agree = float(np.mean(mine == theirs))
    measured = np.unique(np.floor(np.concatenate([p for p, _ in scans]) / args.voxel).astype(np.int64), axis=0)
    measured_centres = (measured + 0.5) * args.voxel
    ours_free_on_surface = float(np.mean(ours.state(measured_centres) == 0))
    theirs_on_surface = np.array([-1 if (node := tree.search(c)) is None else int(tree.isNodeOccupied(node))
                                  for c in measured_centres])
    theirs_free_on_surface = float(np.mean(theirs_on_surface == 0))
    points = sum(len(p) for p, _ in scans)
    record.figures.update({
        "frames": len(scans), "points": points, "voxel": args.voxel, "known_cells": len(centres),
        "agreement": agree, "ours_seconds_per_scan": float(np.median(ours_seconds)),
        "octomap_seconds_per_scan": float(np.median(theirs_seconds)),
        "measured_cells": len(measured), "ours_free_where_measured": ours_free_on_surface,
        "octomap_free_where_measured": theirs_free_on_surface})
    record.table(["map", "median s per scan", "free cells where a surface was measured"], [
        ["pointfield", f"{np.median(ours_seconds):.3f}", f"{ours_free_on_surface:.2%}"],
        ["OctoMap", f"{np.median(theirs_seconds):.3f}", f"{theirs_free_on_surface:.2%}"]],
        title=f"{len(scans)} frames, {points:,} points, {args.voxel} m cells; {len(centres):,} cells known, "
              f"{len(measured):,} cells with a measured point")
    record.verdict("the two maps agree cell for cell (>= 99.9 % of known cells)", agree >= 0.999, f"{agree:.3%}")
    record.verdict("free space where a surface was measured no more often than OctoMap",
                   ours_free_on_surface <= theirs_free_on_surface,
                   f"{ours_free_on_surface:.2%} against {theirs_free_on_surface:.2%}")
    record.note(f"time per scan: pointfield {np.median(ours_seconds):.3f} s, OctoMap {np.median(theirs_seconds):.3f} s "
                f"({np.median(ours_seconds) / np.median(theirs_seconds):.1f}x)")
    if SWEEP.is_file():
        read_section(record, args.read_voxel, args.read_repeats)
    else:
        record.note(f"no KITTI sweep at {SWEEP}: reading a .bt not timed")
    return record.finish()


if __name__ == "__main__":
    sys.exit(main())
