"""Streaming downsample of clouds bigger than memory, and the same verbs on Dask (issue 17).

The claims:

1. ``cloud downsample --voxel`` on a generated 200-million-point LAZ (xyz, intensity,
   classification, rgb) runs end to end with a peak resident memory of at most 2 GB, and gives
   the in-memory path's output on a subset that fits in memory (byte for byte).
2. Its throughput, points per second end to end, is at least 1.0x that of laspy's chunk
   iterator plus numpy doing the same voxel reduction, and at least 1.0x that of open3d's
   ``voxel_down_sample`` on the largest cloud it holds here, in the same run.
3. Two Dask workers convert a folder of 200 KITTI-sized scans at least 1.6x faster than one on
   this 2-core machine, and the Dask result is byte-identical to the single-process one.
4. Peak resident memory stays flat as the input grows: 20 M, 50 M and 200 M points within 10 %.

The memory sweep runs ``cloud downsample`` with ``--memory 1G``: below what the voxel state of
even the 20 M input needs, so the budget binds at every size (state beyond it waits on disk).
The throughput runs use ``--memory 2G``, the claim's limit, under which the voxel state of these
inputs stays in memory. Every run of pointfield and of a peer is a child process, whose peak resident set size the
kernel reports when it exits (``wait4``'s ``ru_maxrss``); wall times are end to end (start-up,
reading, reducing, writing). The LAZ files are generated once, in chunks, and cached in the
output folder (default ``../bench-output/streaming``, outside the repository).

Run: ``make bench-streaming`` (``python benchmarks/bench_streaming.py``); smaller:
``python benchmarks/bench_streaming.py --sizes 2000000,5000000 --scans 40``. The record goes to
``benchmarks/records/streaming.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import laspy
import numpy as np

from harness import ROOT, Record

EXTENT = 2000.0  # metres: the generated area is EXTENT x EXTENT whatever the point count
BLOCK = 2_000_000  # points generated and written per laspy call


# -- data ------------------------------------------------------------------------------------------


def make_laz(path: Path, count: int, seed: int = 0) -> None:
    """A lidar-like LAZ of ``count`` points in flight-line order (point format 2: xyz,
    intensity, classification, rgb): terrain with vegetation and buildings over the same
    EXTENT whatever the count, so that denser inputs reduce to a similar number of voxels."""
    header = laspy.LasHeader(point_format=2, version="1.2")
    header.scales = np.array([0.01, 0.01, 0.01])
    header.offsets = np.array([400_000.0, 4_500_000.0, 0.0])
    rng = np.random.default_rng(seed)
    blocks = -(-count // BLOCK)
    temporary = path.with_name(path.name + ".part")
    with laspy.open(temporary, mode="w", header=header, do_compress=True) as writer:
        for block in range(blocks):
            n = min(BLOCK, count - block * BLOCK)
            strip = EXTENT / blocks
            x = block * strip + rng.random(n) * strip
            y = rng.random(n) * EXTENT
            ground = 30 * np.sin(x / 170) + 20 * np.cos(y / 230)
            classes = rng.choice(np.array([2, 3, 6], np.uint8), n, p=[0.8, 0.15, 0.05])
            height = np.where(classes == 2, rng.normal(0, 0.1, n), rng.random(n) * 1.5)
            record = laspy.ScaleAwarePointRecord.zeros(n, header=header)
            record.x = header.offsets[0] + x
            record.y = header.offsets[1] + y
            record.z = 100 + ground + height
            record.intensity = rng.integers(0, 4096, n).astype(np.uint16)
            record.classification = classes
            shade = ((ground + 50) * 600).astype(np.uint16)
            record.red = shade
            record.green = (shade // 2 + classes.astype(np.uint16) * 5000).astype(np.uint16)
            record.blue = rng.integers(0, 65535, n).astype(np.uint16)
            writer.write_points(record)
    os.replace(temporary, path)


def make_scans(folder: Path, count: int, points: int) -> None:
    """``count`` KITTI-sized scans (``points`` x float32 x y z intensity), a lidar's rings."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(1)
    for number in range(count):
        path = folder / f"{number:06d}.bin"
        if path.exists():
            continue
        rings = rng.integers(0, 64, points)
        azimuth = rng.random(points) * 2 * np.pi
        distance = 5 + rng.gamma(2.0, 8.0, points)
        elevation = np.radians(-24.8 + rings * (26.8 / 63))
        scan = np.stack([
            distance * np.cos(elevation) * np.cos(azimuth),
            distance * np.cos(elevation) * np.sin(azimuth),
            distance * np.sin(elevation) + 1.7,
            rng.random(points),
        ], axis=1).astype(np.float32)
        scan.tofile(path)


# -- peers (run as child processes: python bench_streaming.py --peer NAME ...) ----------------------


def peer_laspy(source: Path, out: Path, voxel: float) -> dict:
    """laspy's chunk iterator + numpy: the same voxel reduction (centroids; intensity,
    classification and colour of each voxel's first point), in one pass on the header's origin.

    Per chunk: voxel keys, np.unique, sums and counts by bincount, first points; the partial
    results of all chunks are then combined the same way. It keeps every chunk's partial
    voxels, so its memory grows with the input.
    """
    started = time.perf_counter()
    with laspy.open(source) as reader:
        header = reader.header
        origin = np.array(header.mins)
        shape = np.floor((np.array(header.maxs) - origin) / voxel).astype(np.int64) + 1
        parts = []
        offset = 0
        for chunk in reader.chunk_iterator(2_000_000):
            xyz = np.stack([chunk.x, chunk.y, chunk.z], axis=1)
            cells = np.floor((xyz - origin) / voxel).astype(np.int64)
            keys = (cells[:, 0] * shape[1] + cells[:, 1]) * shape[2] + cells[:, 2]
            unique, first, inverse, counts = np.unique(keys, return_index=True, return_inverse=True, return_counts=True)
            sums = np.stack([np.bincount(inverse, xyz[:, a], len(unique)) for a in range(3)], axis=1)
            carried = np.stack([np.asarray(chunk[name])[first] for name in ("intensity", "classification", "red", "green", "blue")], axis=1)
            parts.append((unique, sums, counts, first + offset, carried))
            offset += len(chunk)
    keys = np.concatenate([p[0] for p in parts])
    unique, inverse = np.unique(keys, return_inverse=True)
    sums = np.stack([np.bincount(inverse, np.concatenate([p[1][:, a] for p in parts]), len(unique)) for a in range(3)], axis=1)
    counts = np.bincount(inverse, np.concatenate([p[2] for p in parts]), len(unique))
    first = np.concatenate([p[3] for p in parts])
    carried = np.concatenate([p[4] for p in parts])
    order = np.lexsort((first, inverse))
    leader = np.r_[True, inverse[order][1:] != inverse[order][:-1]]
    carried = carried[order[leader]]
    centroids = sums / counts[:, None]
    out_header = laspy.LasHeader(point_format=2, version="1.2")
    out_header.scales, out_header.offsets = header.scales, header.offsets
    las = laspy.LasData(out_header)
    las.x, las.y, las.z = centroids.T
    las.intensity, las.classification = carried[:, 0], carried[:, 1]
    las.red, las.green, las.blue = carried[:, 2], carried[:, 3], carried[:, 4]
    las.write(out)
    return {"seconds": time.perf_counter() - started, "voxels": len(unique)}


def peer_open3d(source: Path, out: Path, voxel: float) -> dict:
    """open3d: the whole LAZ read (laspy), an open3d cloud with colours, ``voxel_down_sample``,
    written as PLY. Reports the kernel's seconds and the end-to-end seconds."""
    import open3d as o3d

    started = time.perf_counter()
    las = laspy.read(source)
    cloud = o3d.geometry.PointCloud()
    cloud.points = o3d.utility.Vector3dVector(np.stack([las.x, las.y, las.z], axis=1))
    cloud.colors = o3d.utility.Vector3dVector(np.stack([las.red, las.green, las.blue], axis=1) / 65535.0)
    del las
    kernel_started = time.perf_counter()
    down = cloud.voxel_down_sample(voxel)
    kernel = time.perf_counter() - kernel_started
    o3d.io.write_point_cloud(str(out), down)
    return {"seconds": time.perf_counter() - started, "kernel_seconds": kernel, "voxels": len(down.points)}


PEERS = {"laspy": peer_laspy, "open3d": peer_open3d}


# -- measuring children ------------------------------------------------------------------------------


def run_child(command: list[str], env: dict | None = None) -> dict:
    """Run ``command``; its wall seconds, peak resident bytes (kernel's ru_maxrss) and stdout."""
    started = time.perf_counter()
    child = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT,
                             env={**os.environ, **(env or {})})
    output = child.stdout.read()
    errors = child.stderr.read()
    _, status, usage = os.wait4(child.pid, 0)
    seconds = time.perf_counter() - started
    child.returncode = os.waitstatus_to_exitcode(status)
    if child.returncode != 0:
        raise RuntimeError(f"{' '.join(map(str, command))} failed:\n{errors.decode()[-3000:]}")
    return {"seconds": seconds, "peak_bytes": usage.ru_maxrss * 1024, "stdout": output.decode()}


def pointfield_downsample(source: Path, out: Path, voxel: float, memory: str) -> dict:
    return run_child([sys.executable, "-m", "pointfield", "cloud", "downsample", str(source), str(out),
                      "--voxel", str(voxel), "--memory", memory, "--no-progress", "--overwrite"],
                     env={"PYTHONPATH": str(ROOT / "src")})


def peer(name: str, source: Path, out: Path, voxel: float) -> dict:
    result = run_child([sys.executable, __file__, "--peer", name, str(source), str(out), str(voxel)])
    return {**result, **json.loads(result["stdout"].strip().splitlines()[-1])}


# A LAS header's file creation day and year (bytes 90 to 93): two runs either side of midnight
# write different dates into files that are otherwise the same.
CREATION_DATE = slice(90, 94)


def same_las(a: Path, b: Path) -> bool:
    """Whether two LAS / LAZ files are byte for byte the same, their creation dates aside."""
    first, second = bytearray(a.read_bytes()), bytearray(b.read_bytes())
    first[CREATION_DATE] = second[CREATION_DATE] = bytes(4)
    return first == second


def gb(value: float) -> str:
    return f"{value / 1e9:.2f}"


def rate(points: int, seconds: float) -> str:
    return f"{points / seconds / 1e6:.2f}"


# -- the benchmark -------------------------------------------------------------------------------------


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", default="20000000,50000000,200000000", help="point counts of the LAZ inputs")
    parser.add_argument("--voxel", type=float, default=1.0)
    parser.add_argument("--memory", default="1G", help="--memory of cloud downsample: a budget below what the "
                        "voxels of the smallest input need, so that it binds at every size")
    parser.add_argument("--throughput-memory", default="2G", help="--memory of the throughput runs: the claim's 2 GB")
    parser.add_argument("--limit-gb", type=float, default=2.0, help="the peak memory the claim allows")
    parser.add_argument("--subset", type=int, default=2_000_000, help="points of the in-memory comparison")
    parser.add_argument("--peer-sizes", default="20000000,50000000", help="sizes the peers run on (laspy+numpy keeps every chunk's partial voxels)")
    parser.add_argument("--open3d-size", type=int, default=20_000_000, help="the largest cloud open3d holds here (read whole)")
    parser.add_argument("--scans", type=int, default=200)
    parser.add_argument("--scan-points", type=int, default=120_000)
    parser.add_argument("--repeats", type=int, default=2, help="runs of each Dask configuration")
    parser.add_argument("--size-repeats", type=int, default=2, help="runs of pointfield and the peer at each peer size")
    parser.add_argument("--output", type=Path, default=ROOT.parent / "bench-output" / "streaming")
    parser.add_argument("--peer", nargs=4, metavar=("NAME", "IN", "OUT", "VOXEL"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.peer:
        name, source, out, voxel = args.peer
        print(json.dumps(PEERS[name](Path(source), Path(out), float(voxel))))
        return 0

    sizes = [int(s) for s in args.sizes.split(",")]
    peer_sizes = {int(s) for s in args.peer_sizes.split(",")} & set(sizes)
    record = Record(
        "streaming",
        "Streaming downsample with bounded memory; Dask workers",
        issue="17",
        about="`cloud downsample --voxel` end to end on generated lidar LAZ files (point format 2: xyz, "
        "intensity, classification, rgb; the same 2 km x 2 km area at every size), each run a child process "
        "whose peak resident memory the kernel reports; peers: laspy's chunk iterator + numpy doing the same "
        "reduction, and open3d's voxel_down_sample on a cloud read whole. Then a folder of KITTI-sized .bin "
        "scans converted to LAZ by 1 and 2 Dask workers (LocalCluster, one thread each).",
    )
    args.output.mkdir(parents=True, exist_ok=True)
    for count in sorted({*sizes, args.subset, args.open3d_size}):
        path = args.output / f"lidar-{count}.laz"
        if not path.exists():
            started = time.perf_counter()
            make_laz(path, count)
            record.note(f"generated {path.name} ({path.stat().st_size / 1e9:.2f} GB) in {time.perf_counter() - started:.0f} s")

    # 1. the subset: streamed output == in-memory output, byte for byte
    subset = args.output / f"lidar-{args.subset}.laz"
    streamed = pointfield_downsample(subset, args.output / "subset-streamed.laz", args.voxel, args.memory)
    in_memory = run_child([sys.executable, "-c", (
        "import sys, pointfield; from pointfield.clouds.ops import voxel_downsample; "
        "pointfield.write(sys.argv[2], voxel_downsample(pointfield.read(sys.argv[1]), float(sys.argv[3])))"),
        str(subset), str(args.output / "subset-memory.laz"), str(args.voxel)], env={"PYTHONPATH": str(ROOT / "src")})
    same = same_las(args.output / "subset-streamed.laz", args.output / "subset-memory.laz")
    record.table(["path", "points", "seconds", "peak GB"], [
        ["streamed (cloud downsample)", f"{args.subset:,}", f"{streamed['seconds']:.1f}", gb(streamed["peak_bytes"])],
        ["in memory (read, voxel_downsample, write)", f"{args.subset:,}", f"{in_memory['seconds']:.1f}", gb(in_memory["peak_bytes"])],
    ], title="The subset that fits in memory")
    record.verdict("streamed output is byte-identical to the in-memory path on the subset (creation date aside)", same,
                   f"{args.subset:,} points, voxel {args.voxel}")

    # 2. peak memory as the input grows, under a budget that binds at every size
    rows, peaks = [], {}
    for count in sizes:
        run = pointfield_downsample(args.output / f"lidar-{count}.laz", args.output / f"down-{count}.laz", args.voxel, args.memory)
        peaks[count] = run["peak_bytes"]
        with laspy.open(args.output / f"down-{count}.laz") as written:
            voxels = written.header.point_count
        rows.append([f"{count:,}", f"{voxels:,}", f"{run['seconds']:.1f}", rate(count, run["seconds"]), gb(run["peak_bytes"])])
    record.table(["points", "voxels out", "seconds", "M points/s", "peak GB"], rows,
                 title=f"Memory: cloud downsample --voxel {args.voxel} --memory {args.memory}, end to end")
    biggest = max(sizes)
    record.verdict(f"peak resident memory at most {args.limit_gb:g} GB on {biggest:,} points",
                   peaks[biggest] <= args.limit_gb * 1e9, f"{gb(peaks[biggest])} GB")
    if len(peaks) > 1:
        spread = (max(peaks.values()) - min(peaks.values())) / min(peaks.values())
        record.verdict("peak memory flat as the input grows: all sizes within 10 %", spread <= 0.10,
                       ", ".join(f"{c / 1e6:g} M: {gb(p)} GB" for c, p in peaks.items()) + f"; spread {spread:.0%}")

    # 3. throughput against laspy + numpy, interleaved: ours, peer, peer, ours, ... so that a
    # machine speeding up or slowing down (it is shared) hits both alike
    rows, ours_rate, laspy_rate, runs = [], {}, {}, {}
    for count in sorted(peer_sizes):
        source = args.output / f"lidar-{count}.laz"
        ours_runs, peer_runs = [], []
        for repeat in range(args.size_repeats):
            for who in ("ours", "peer") if repeat % 2 == 0 else ("peer", "ours"):
                if who == "ours":
                    ours_runs.append(pointfield_downsample(source, args.output / f"fast-{count}.laz", args.voxel, args.throughput_memory))
                else:
                    peer_runs.append(peer("laspy", source, args.output / f"peer-{count}.laz", args.voxel))
        ours_seconds = float(np.median([r["seconds"] for r in ours_runs]))
        peer_seconds = float(np.median([r["seconds"] for r in peer_runs]))
        ours_rate[count], laspy_rate[count] = count / ours_seconds, count / peer_seconds
        runs[count] = {"seconds": ours_seconds, "peak_bytes": max(r["peak_bytes"] for r in ours_runs)}
        rows.append(["pointfield (streamed)", f"{count:,}", " ".join(f"{r['seconds']:.1f}" for r in ours_runs),
                     rate(count, ours_seconds), gb(runs[count]["peak_bytes"])])
        rows.append(["laspy chunks + numpy", f"{count:,}", " ".join(f"{r['seconds']:.1f}" for r in peer_runs),
                     rate(count, peer_seconds), gb(max(r["peak_bytes"] for r in peer_runs))])
    if rows:
        record.table(["run", "points", "seconds (each run)", "M points/s (median)", "peak GB"], rows,
                     title=f"Throughput: cloud downsample --voxel {args.voxel} --memory {args.throughput_memory}, "
                     "end to end, against laspy's chunk iterator + numpy (the same reduction, one pass)")
    record.figures.update({
        "peak_bytes": {str(c): p for c, p in peaks.items()},
        "points_per_second": {str(c): r for c, r in ours_rate.items()},
        "laspy_numpy_points_per_second": {str(c): r for c, r in laspy_rate.items()},
    })
    for count in sorted(laspy_rate):
        ratio = ours_rate[count] / laspy_rate[count]
        record.verdict(f"throughput at least 1.0x laspy chunk iterator + numpy ({count / 1e6:g} M points)", ratio >= 1.0, f"{ratio:.2f}x")

    # open3d on the largest cloud it holds here
    o3d_source = args.output / f"lidar-{args.open3d_size}.laz"
    theirs = peer("open3d", o3d_source, args.output / "open3d.ply", args.voxel)
    ours = runs.get(args.open3d_size) or pointfield_downsample(o3d_source, args.output / "o3d-ours.laz", args.voxel, args.throughput_memory)
    n = args.open3d_size
    record.table(["run", "points", "seconds", "M points/s", "peak GB"], [
        ["pointfield (streamed, end to end)", f"{n:,}", f"{ours['seconds']:.1f}", rate(n, ours["seconds"]), gb(ours["peak_bytes"])],
        ["open3d (read whole + voxel_down_sample + write)", f"{n:,}", f"{theirs['seconds']:.1f}", rate(n, theirs["seconds"]), gb(theirs["peak_bytes"])],
        ["open3d voxel_down_sample alone (in memory)", f"{n:,}", f"{theirs['kernel_seconds']:.1f}", rate(n, theirs["kernel_seconds"]), "-"],
    ], title="Against open3d on the largest cloud it holds here")
    ratio = theirs["seconds"] / ours["seconds"]
    record.verdict("throughput at least 1.0x open3d per point, file to file", ratio >= 1.0, f"{ratio:.2f}x")
    kernel_ratio = theirs["kernel_seconds"] / ours["seconds"]
    record.verdict("throughput at least 1.0x open3d's voxel_down_sample alone (our end to end vs its kernel)",
                   kernel_ratio >= 1.0, f"{kernel_ratio:.2f}x")

    # 4. Dask: a folder of scans, 1 worker against 2
    dask_scaling(record, args)
    return record.finish()


def dask_scaling(record: Record, args: argparse.Namespace) -> None:
    sys.path.insert(0, str(ROOT / "src"))
    from pointfield.streaming import convert_folder
    from pointfield.streaming.distributed import cluster

    scans = args.output / f"kitti-{args.scans}x{args.scan_points}"
    make_scans(scans, args.scans, args.scan_points)
    single = args.output / "kitti-single"
    started = time.perf_counter()
    convert_folder(scans, single, ".laz", overwrite=True)
    single_seconds = time.perf_counter() - started
    times: dict[int, list[float]] = {1: [], 2: []}
    identical = True
    for repeat in range(args.repeats):
        for workers in (1, 2) if repeat % 2 == 0 else (2, 1):
            with cluster(workers=workers) as client:
                client.wait_for_workers(workers)
                out = args.output / f"kitti-{workers}-workers"
                started = time.perf_counter()
                convert_folder(scans, out, ".laz", client=client, overwrite=True)
                times[workers].append(time.perf_counter() - started)
            identical &= all(same_las(out / p.name, p) for p in single.iterdir())
    median = {w: float(np.median(t)) for w, t in times.items()}
    points = args.scans * args.scan_points
    record.table(["run", "scans", "seconds (median)", "runs", "M points/s"], [
        ["one process, no Dask", f"{args.scans}", f"{single_seconds:.1f}", "1", rate(points, single_seconds)],
        *[[f"Dask, {w} worker{'s' if w > 1 else ''}", f"{args.scans}", f"{median[w]:.1f}",
           " ".join(f"{t:.1f}" for t in times[w]), rate(points, median[w])] for w in (1, 2)],
    ], title=f"cloud convert DIR OUT --to .laz --workers N: {args.scans} scans of {args.scan_points:,} points (cluster start-up not counted)")
    speedup = median[1] / median[2]
    record.verdict("2 Dask workers at least 1.6x faster than 1 on the folder conversion", speedup >= 1.6, f"{speedup:.2f}x")
    record.verdict("the Dask results are byte-identical to the single-process ones (creation date aside)", identical,
                   f"{args.scans} files, 1 and 2 workers")
    record.figures.update({"dask_speedup": speedup, "dask_seconds": median, "single_process_seconds": single_seconds})


if __name__ == "__main__":
    sys.exit(main())
