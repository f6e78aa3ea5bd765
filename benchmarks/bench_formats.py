"""Read speed and memory of pointfield's readers against open3d and laspy, in the same run.

The claim (issue 2): on a 2-million-point cloud with colours, pointfield reads binary PLY and
binary PCD in at most 0.25x open3d's time, ascii PLY in at most 0.6x, binary_compressed PCD in at
most 1.0x; LAS / LAZ within 1.2x of laspy alone; and a binary read holds at most about twice its
output arrays in memory.

The PLY and PCD files are written by open3d itself, so each reader reads the peer's own output.
Times are the median of several interleaved runs with a warm page cache.

Run: ``make bench-formats`` (or ``python benchmarks/bench_formats.py --points 2000000``); the
record goes to ``benchmarks/records/formats.json``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import tracemalloc
from pathlib import Path

import laspy
import numpy as np
import open3d as o3d

import pointfield

from harness import Record, interleaved

TARGETS = {  # file -> (peer, the most pointfield may take relative to the peer)
    "binary.ply": ("open3d", 0.25),
    "ascii.ply": ("open3d", 0.6),
    "binary.pcd": ("open3d", 0.25),
    "compressed.pcd": ("open3d", 1.0),
    "cloud.las": ("laspy", 1.2),
    "cloud.laz": ("laspy", 1.2),
}


def make_files(folder: Path, n: int) -> None:
    rng = np.random.default_rng(0)
    xyz = rng.normal(size=(n, 3)).astype(np.float32)
    rgb = rng.integers(0, 256, (n, 3), dtype=np.uint8)
    cloud = o3d.geometry.PointCloud()
    cloud.points = o3d.utility.Vector3dVector(xyz.astype(np.float64))
    cloud.colors = o3d.utility.Vector3dVector(rgb / 255.0)
    o3d.io.write_point_cloud(str(folder / "binary.ply"), cloud)
    o3d.io.write_point_cloud(str(folder / "ascii.ply"), cloud, write_ascii=True)
    o3d.io.write_point_cloud(str(folder / "binary.pcd"), cloud)
    o3d.io.write_point_cloud(str(folder / "compressed.pcd"), cloud, compressed=True)

    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array([500000.0, 4000000.0, 0.0])
    las = laspy.LasData(header)
    las.x = 500000.0 + xyz[:, 0] * 100
    las.y = 4000000.0 + xyz[:, 1] * 100
    las.z = xyz[:, 2] * 10
    las.red, las.green, las.blue = (rgb[:, i].astype(np.uint16) * 257 for i in range(3))
    las.intensity = rng.integers(0, 65535, n, dtype=np.uint16)
    las.write(folder / "cloud.las")
    las.write(folder / "cloud.laz")


def read_open3d(path: Path) -> int:
    return len(o3d.io.read_point_cloud(str(path)).points)


def read_laspy(path: Path) -> int:
    las = laspy.read(path)
    xyz = np.stack([las.x, las.y, las.z], axis=1)
    return len(xyz)


def read_pointfield(path: Path) -> int:
    return len(pointfield.read(path))


def peak_memory_ratio(path: Path) -> float:
    """Peak traced allocation during the read, over the bytes of the arrays it returns."""
    tracemalloc.start()
    cloud = pointfield.read(path)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    output = cloud.points.nbytes + sum(v.nbytes for v in cloud.fields.values())
    return peak / output


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=2_000_000)
    parser.add_argument("--repeats", type=int, default=5, help="interleaved reads per reader (median)")
    args = parser.parse_args()

    record = Record(
        "formats", "Point-cloud reading against open3d and laspy", issue="2",
        about=f"{args.points:,} points with colours; the PLY and PCD files written by open3d {o3d.__version__}, "
              f"LAS and LAZ by laspy {laspy.__version__}, so each reader reads the peer's own output. Reads of "
              "pointfield and the peer alternate (median of the interleaved runs, warm page cache). The laspy "
              "peer is `laspy.read(path)` plus the x, y, z arrays; pointfield also hands out every dimension as "
              "its own contiguous field. `memory` is the peak allocation traced by tracemalloc during "
              "`pointfield.read`, over the bytes of the arrays it returns.")
    rows, results = [], []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        print(f"writing {args.points:,} coloured points with open3d and laspy ...", flush=True)
        make_files(folder, args.points)
        for name, (peer, target) in TARGETS.items():
            path = folder / name
            peer_reader = read_open3d if peer == "open3d" else read_laspy
            assert peer_reader(path) == read_pointfield(path) == args.points
            timings = interleaved({peer: lambda read=peer_reader, path=path: read(path),
                                  "pointfield": lambda path=path: read_pointfield(path)}, args.repeats)
            ratio = timings["pointfield"].median / timings[peer].median
            memory = peak_memory_ratio(path)
            size_mb = path.stat().st_size / 1e6
            print(f"{name}: ratio {ratio:.2f}", flush=True)
            rows.append([name, f"{size_mb:.1f}", peer, f"{timings[peer].median:.3f}",
                         f"{timings['pointfield'].median:.3f}", f"{timings['pointfield'].spread:.0%}",
                         f"{ratio:.2f}", f"{target:.2f}", f"{memory:.2f}x"])
            results.append({"file": name, "megabytes": size_mb, "peer": peer, "ratio": ratio, "target": target,
                            "peer_timing": timings[peer].as_dict(), "pointfield_timing": timings["pointfield"].as_dict(),
                            "peak_memory_over_output": memory})
    record.figures.update({"points": args.points, "results": results})
    record.table(["file", "MB", "peer", "peer s", "ours s", "ours spread", "ratio", "target", "memory"], rows,
                 title=f"median of {args.repeats} interleaved reads")
    for result in results:
        record.verdict(f"{result['file']} reads in at most {result['target']:.2f}x {result['peer']}'s time",
                       result["ratio"] <= result["target"], f"{result['ratio']:.2f}x")
    return record.finish()


if __name__ == "__main__":
    sys.exit(main())
