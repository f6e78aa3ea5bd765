"""Whole-scan prediction within a memory budget: PointNet++ and PTv3 label a generated LAZ scan with
``segment predict --memory 2GB``, its peak resident memory measured from outside.

Claim checked (issue 45): a 10-million-point LAZ is predicted within a 2 GB ``--memory`` budget,
with its throughput in points per second reported for both models.

- The data: synthetic streets (:func:`pointfield.clouds.synthetic_scenes.make_scenes`, fixed
  seeds) to train on, and one scanned street laid out copy after copy on a grid, 100 m x 60 m apart, until
  the scan holds ``--points`` points, written as LAZ (point format 2: x y z, intensity,
  classification, rgb) in blocks, so that generating it holds one block.
- The runs: each model trained by ``pointfield segment train --max-time`` (default 30 s) with tiny
  settings (the point is throughput and memory, not accuracy), then ``pointfield segment predict
  RUN scan.laz --out labelled.laz --memory 2GB`` in a child process, whose peak resident set size
  the kernel reports when it exits (``wait4``'s ``ru_maxrss``, as ``bench_streaming.py`` measures);
  seconds are end to end (start-up, the three passes over the file, the tiles, writing).
- Verdicts: the labelled file has every point, and the peak stays within the budget (2 GiB, what
  ``--memory 2GB`` means).

Usage::

    python benchmarks/bench_predict.py                       # 10 M points
    python benchmarks/bench_predict.py --points 1000000      # shorter
    python benchmarks/bench_predict.py --models pointnet2 --max-time 20

The record goes to ``benchmarks/records/predict.json``; the generated files to ``--output``
(default ``../bench-output/predict``, outside the repository), the LAZ kept between runs.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import laspy
import numpy as np
from bench_streaming import gb, run_child

from harness import ROOT, Record

MODELS = {"pointnet2": "PointNet++ SSG", "ptv3": "Point Transformer V3"}
# Tiny training: a coarse grid, small crops, few per epoch; 4 m crops as bench_scenes' streets.
TRAIN = ["--grid", "0.2", "--radius", "4", "--points", "512", "--crops", "16", "--batch-size", "4",
         "--features", "colour,intensity,height", "--no-progress", "--device", "cpu"]
SPACING = np.array([100.0, 60.0, 0.0])  # metres between copies: one street spans about 98 m x 58 m
BLOCK = 1_000_000


def street() -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """One scanned street (seed 7): float64 points and the LAS fields of its points."""
    from pointfield.clouds.synthetic_scenes import street_scene

    cloud = street_scene(7, density=1.0).cloud
    points = cloud.points.astype(np.float64)
    points[:, :2] -= points[:, :2].min(axis=0)
    fields = {
        "intensity": np.round(np.clip(cloud.fields["intensity"], 0, 1) * 65535).astype(np.uint16),
        "classification": cloud.fields["label"].astype(np.uint8) + 1,
        "colors": cloud.fields["colors"].astype(np.uint16) * 257,
    }
    return points, fields


def make_scan(path: Path, count: int) -> None:
    """``count`` points of copies of :func:`street` on a square grid of ``SPACING``, as LAZ."""
    points, fields = street()
    per_row = max(1, int(np.ceil(np.sqrt(count / len(points)))))
    header = laspy.LasHeader(point_format=2, version="1.2")
    header.scales = np.array([0.01, 0.01, 0.01])
    header.offsets = np.array([500_000.0, 4_000_000.0, 0.0])
    temporary = path.with_name(path.name + ".part")
    written, copy = 0, 0
    with laspy.open(temporary, mode="w", header=header, do_compress=True) as writer:
        pending: list[laspy.ScaleAwarePointRecord] = []
        held = 0
        while written < count:
            n = min(len(points), count - written)
            shift = np.array([copy % per_row, copy // per_row, 0]) * SPACING + header.offsets
            record = laspy.ScaleAwarePointRecord.zeros(n, header=header)
            record.x, record.y, record.z = (points[:n] + shift).T
            record.intensity = fields["intensity"][:n]
            record.classification = fields["classification"][:n]
            record.red, record.green, record.blue = fields["colors"][:n].T
            pending.append(record)
            held += n
            written += n
            copy += 1
            if held >= BLOCK or written >= count:
                for part in pending:
                    writer.write_points(part)
                pending, held = [], 0
    temporary.rename(path)


def train(model: str, data: Path, out: Path, max_time: float) -> dict:
    if not (out / "metrics.json").is_file():
        run_child([sys.executable, "-m", "pointfield", "segment", "train", str(data), "--out", str(out),
                   "--model", model, "--max-time", str(max_time), *TRAIN], env={"PYTHONPATH": str(ROOT / "src")})
    return json.loads((out / "metrics.json").read_text())


def predict(run: Path, scan: Path, out: Path, memory: str) -> dict:
    result = run_child([sys.executable, "-m", "pointfield", "segment", "predict", str(run), str(scan), "--out",
                        str(out), "--memory", memory, "--device", "cpu", "--no-progress", "--json"],
                       env={"PYTHONPATH": str(ROOT / "src"), "OMP_NUM_THREADS": "2"})
    (answer,) = json.loads(result["stdout"])
    return {**result, **answer}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--points", type=int, default=10_000_000, help="points of the generated scan")
    parser.add_argument("--memory", default="2GB", help="--memory of segment predict (the claim: 2GB)")
    parser.add_argument("--max-time", type=float, default=30.0, help="training seconds per model")
    parser.add_argument("--models", default=",".join(MODELS), help="comma-separated models")
    parser.add_argument("--output", type=Path, default=ROOT.parent / "bench-output" / "predict")
    args = parser.parse_args()
    models = [m.strip() for m in args.models.split(",") if m.strip()]
    if not models or any(m not in MODELS for m in models):
        parser.error(f"models are {', '.join(MODELS)}")
    from pointfield.streaming.memory import parse_memory

    budget = parse_memory(args.memory)
    record = Record("predict", "Whole-scan prediction within a memory budget", issue="45", about=(
        f"`pointfield segment predict RUN scan.laz --memory {args.memory}` on a generated LAZ of synthetic streets "
        f"({args.points:,} points), by {' and '.join(MODELS[m] for m in models)} runs trained for "
        f"{args.max_time:g} s with tiny settings; each prediction a child process whose peak resident memory the "
        "kernel reports. Throughput is points of the file per second, end to end."))
    args.output.mkdir(parents=True, exist_ok=True)
    data = args.output / "streets"
    if not (data / "classes.json").is_file():
        from pointfield.clouds.synthetic_scenes import make_scenes

        make_scenes(data, "street", 4, seed=100, density=0.3)
    scan = args.output / f"scan-{args.points}.laz"
    if not scan.is_file():
        started = time.perf_counter()
        make_scan(scan, args.points)
        record.note(f"generated {scan.name} ({scan.stat().st_size / 1e6:.0f} MB) in "
                    f"{time.perf_counter() - started:.0f} s")
    rows = []
    for model in models:
        metrics = train(model, data, args.output / f"run-{model}", args.max_time)
        out = args.output / f"labelled-{model}.laz"
        result = predict(args.output / f"run-{model}", scan, out, args.memory)
        written = laspy.open(out).header.point_count
        rows.append([model, f"{metrics['miou']:.2f}", f"{result['points']:,}", result.get("tiles", "whole"),
                     f"{result.get('tile_size', 0):g}", f"{result['seconds']:.0f}",
                     f"{result['points'] / result['seconds']:,.0f}", gb(result["peak_bytes"])])
        record.figures[model] = {"points": result["points"], "seconds": result["seconds"],
                                 "points_per_second": result["points"] / result["seconds"],
                                 "peak_bytes": result["peak_bytes"], "tiles": result.get("tiles"),
                                 "tile_size": result.get("tile_size"), "halo": result.get("halo"),
                                 "training_miou": metrics["miou"], "written_points": written}
        record.verdict(f"{model}: every point labelled", written == args.points == result["points"],
                       f"{written:,} of {args.points:,}")
        record.verdict(f"{model}: peak memory within the {args.memory} budget", result["peak_bytes"] <= budget,
                       f"{gb(result['peak_bytes'])} GB of {gb(budget)} GB")
    record.table(["model", "mIoU (tiny run)", "points", "tiles", "tile m", "seconds", "points/s", "peak GB"], rows)
    record.note("The machine was shared (2 cores, other jobs running): seconds are upper bounds.")
    return record.finish()


if __name__ == "__main__":
    sys.exit(main())
