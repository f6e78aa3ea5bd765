"""Read speed and memory of pointfield's readers against open3d and laspy, in the same run.

The claim (issue 2): on a 2-million-point cloud with colours, pointfield reads binary PLY and
binary PCD in at most 0.25x open3d's time, ascii PLY in at most 0.6x, binary_compressed PCD in at
most 1.0x; LAS / LAZ within 1.2x of laspy alone; and a binary read holds at most about twice its
output arrays in memory.

The PLY and PCD files are written by open3d itself, so each reader reads the peer's own output.
Times are the median of several interleaved runs with a warm page cache.

Run: ``make bench-formats`` (or ``python benchmarks/bench_formats.py --points 2000000``).
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
import tracemalloc
from pathlib import Path

import laspy
import numpy as np
import open3d as o3d

import pointfield

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


def median_times(path: Path, readers: dict, repeats: int) -> dict[str, float]:
    samples: dict[str, list[float]] = {name: [] for name in readers}
    for _ in range(repeats):
        for name, reader in readers.items():  # interleaved, so drift hits both alike
            start = time.perf_counter()
            reader(path)
            samples[name].append(time.perf_counter() - start)
    return {name: statistics.median(times) for name, times in samples.items()}


def peak_memory_ratio(path: Path) -> float:
    """Peak traced allocation during the read, over the bytes of the arrays it returns."""
    tracemalloc.start()
    cloud = pointfield.read(path)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    output = cloud.points.nbytes + sum(v.nbytes for v in cloud.fields.values())
    return peak / output


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=2_000_000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", type=Path, default=Path("bench-output/formats.json"))
    args = parser.parse_args()

    results = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        print(f"writing {args.points:,} coloured points with open3d and laspy ...", flush=True)
        make_files(folder, args.points)
        print(f"{'file':<16}{'MB':>8}{'peer':>8}{'peer s':>9}{'ours s':>9}{'ratio':>8}"
              f"{'target':>8}{'memory':>8}  verdict")
        for name, (peer, target) in TARGETS.items():
            path = folder / name
            peer_reader = read_open3d if peer == "open3d" else read_laspy
            assert peer_reader(path) == read_pointfield(path) == args.points
            times = median_times(path, {peer: peer_reader, "pointfield": read_pointfield}, args.repeats)
            ratio = times["pointfield"] / times[peer]
            memory = peak_memory_ratio(path)
            verdict = "ok" if ratio <= target else "SLOWER THAN TARGET"
            size_mb = path.stat().st_size / 1e6
            print(f"{name:<16}{size_mb:>8.1f}{peer:>8}{times[peer]:>9.3f}{times['pointfield']:>9.3f}"
                  f"{ratio:>8.2f}{target:>8.2f}{memory:>7.2f}x  {verdict}", flush=True)
            results.append({"file": name, "megabytes": size_mb, "peer": peer,
                            "peer_seconds": times[peer], "pointfield_seconds": times["pointfield"],
                            "ratio": ratio, "target": target, "peak_memory_over_output": memory})
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"points": args.points, "results": results}, indent=2))
    print(f"memory = peak traced allocation during pointfield.read / bytes of the arrays returned")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
