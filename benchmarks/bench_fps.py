"""Thinning a cloud by farthest points: bucketed FPS (QuickFPS) against exact FPS, both fpsample.

The claim (issue 14's ``--points``): :func:`pointfield.clouds.ops.farthest_point_subset`, which
``nerf export`` / ``splat export --points N`` use, thins a large cloud at least 10x faster than
exact farthest point sampling (:func:`~pointfield.clouds.ops.farthest_point_sample`,
``fpsample.fps_sampling``, what ``--points`` used before), with a covering radius -- the
distance from the worst-served point of the cloud to the subset -- within 1 % of the exact
sample's. Also reported: the mean distance of a point to the subset.

Clouds: a full 360-degree KITTI scan from ../shared/data (124,668 points; skipped with a note
when absent) and 200,000 points uniform in a cube, each thinned to a tenth. Times are the
median of interleaved runs.

Run: ``make bench-fps`` (= ``python benchmarks/bench_fps.py``); the record goes to
``benchmarks/records/fps.json``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

import pointfield
from pointfield.clouds.ops import farthest_point_sample, farthest_point_subset

from harness import Record, interleaved

KITTI = Path(__file__).resolve().parents[2] / "shared" / "data" / "kitti" / "semantickitti_seq00" / "000000.bin"
GOAL_SPEED = 10.0
GOAL_RADIUS = 1.01


def spread(points: np.ndarray, subset: np.ndarray) -> tuple[float, float]:
    """Covering radius and mean distance of ``points`` to ``points[subset]``."""
    distances, _ = cKDTree(points[subset]).query(points, workers=-1)
    return float(distances.max()), float(distances.mean())


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--uniform-points", type=int, default=200_000)
    parser.add_argument("--fraction", type=float, default=0.1, help="share of the points kept (default 0.1)")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    record = Record("fps", "Thinning by farthest points: bucketed against exact FPS", issue="14",
                    about=f"Each cloud thinned to {args.fraction:.0%} of its points by exact FPS "
                          "(`fpsample.fps_sampling`) and by pointfield's `farthest_point_subset` (fpsample's "
                          f"bucketed kd-line FPS); median of {args.repeats} interleaved runs; covering radius: "
                          "the largest distance from a point of the cloud to the subset.")
    clouds = {f"{args.uniform_points:,} uniform points in a cube":
              np.random.default_rng(0).random((args.uniform_points, 3)).astype(np.float32)}
    if KITTI.exists():
        clouds["KITTI scan (semantickitti 000000)"] = pointfield.read(KITTI).points.astype(np.float32)
    else:
        record.note(f"KITTI scan skipped: {KITTI} is absent")
    rows = []
    for name, points in clouds.items():
        size = int(len(points) * args.fraction)
        samples = {}
        timings = interleaved({
            "exact": lambda points=points, size=size, samples=samples: samples.__setitem__(
                "exact", farthest_point_sample(points, size)),
            "bucketed": lambda points=points, size=size, samples=samples: samples.__setitem__(
                "bucketed", farthest_point_subset(points, size)),
        }, args.repeats)
        (exact_radius, exact_mean), (bucketed_radius, bucketed_mean) = (
            spread(points, samples["exact"]), spread(points, samples["bucketed"]))
        speed = timings["exact"].median / timings["bucketed"].median
        rows.append([name, f"{len(points):,} -> {size:,}", f"{timings['exact'].median:.2f} s",
                     f"{timings['bucketed'].median:.3f} s", f"{speed:.1f}x",
                     f"{exact_radius:.4g} / {bucketed_radius:.4g}", f"{exact_mean:.4g} / {bucketed_mean:.4g}"])
        record.figures[name] = {"points": len(points), "size": size, "exact": timings["exact"].as_dict(),
                                "bucketed": timings["bucketed"].as_dict(), "speed": speed,
                                "covering_radius": [exact_radius, bucketed_radius], "mean_distance": [exact_mean, bucketed_mean]}
        record.verdict(f"{name}: bucketed at least {GOAL_SPEED:g}x faster than exact FPS", speed >= GOAL_SPEED,
                       f"{speed:.1f}x")
        record.verdict(f"{name}: covering radius within {GOAL_RADIUS - 1:.0%} of exact FPS's",
                       bucketed_radius <= GOAL_RADIUS * exact_radius, f"{bucketed_radius / exact_radius:.4f}x")
    record.table(["cloud", "thinned", "exact FPS", "bucketed", "speed", "covering radius exact / bucketed",
                  "mean distance exact / bucketed"], rows)
    return record.finish()


if __name__ == "__main__":
    sys.exit(main())
