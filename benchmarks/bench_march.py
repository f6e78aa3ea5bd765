"""Ray marching through an occupancy grid: the compiled occupancy test against the same test run eagerly.

The claim (issue 6's render time): :func:`pointfield.fields.sampling.occupancy.march_rays` tests every fixed
step of every ray against the occupancy grid -- about 1.4 million candidates for a 100 x 100
lego view -- as one dense expression (:func:`~pointfield.fields.sampling.occupancy.occupied_candidates`) that
``torch.compile`` fuses into one loop where a compiler exists (:mod:`pointfield.compiling`).
The peer, measured in the same run, is the same function run eagerly; both must keep exactly
the same samples.

The scene is lego's: its 64^3 grid over the box [-1.5, 1.5]^3 (steps of |box| / 256), with
lego-like occupancy (a ball of radius 0.8 on a floor slab, 11 % of the cells), seen by
lego's first camera at 100 x 100 (``--downscale 8``).

Run: ``python benchmarks/bench_march.py`` (``make bench-march``).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import torch

LEGO = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "nerf" / "lego_blender"
BOX = ((-1.5, -1.5, -1.5), (1.5, 1.5, 1.5))


def lego_like_grid():
    from pointfield.fields.sampling.occupancy import OccupancyGrid

    grid = OccupancyGrid(torch.tensor(BOX), resolution=64)
    index = torch.arange(grid.resolution**3)
    cells = torch.stack([index // grid.resolution**2, index // grid.resolution % grid.resolution,
                         index % grid.resolution], dim=-1)
    centres = grid.box[0] + (cells + 0.5) / grid.cells_per_unit
    ball = centres.norm(dim=-1) < 0.8
    floor = (centres[:, 2] > -0.95) & (centres[:, 2] < -0.8) & (centres[:, :2].abs() < 1.2).all(dim=-1)
    grid.occupied.copy_(ball | floor)
    return grid


def lego_rays():
    from pointfield.fields.train import scene_rays
    from pointfield.scenes import read_scene

    scene = read_scene(LEGO).downscaled(8)
    return scene_rays(scene, [0], torch.device("cpu"))


def median_seconds(function, count: int) -> float:
    function()  # warm-up: compilation, caches
    times = []
    for _ in range(count):
        started = time.perf_counter()
        function()
        times.append(time.perf_counter() - started)
    return statistics.median(times)


def main() -> None:
    from pointfield.fields.rays import RayBundle
    from pointfield.fields.sampling.occupancy import march_rays

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=15, help="marches timed per backend (median)")
    parser.add_argument("--threads", type=int, help="torch.set_num_threads (default: PyTorch's)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    if not (LEGO / "transforms_train.json").is_file():
        raise SystemExit(f"lego scene not found at {LEGO}")
    grid, rays = lego_like_grid(), lego_rays()
    step = float(torch.linalg.norm(grid.box[1] - grid.box[0])) / 256

    def march(backend: str):
        return march_rays(RayBundle(rays.origins, rays.directions, rays.near, rays.far), grid, step, backend=backend)

    compiled, eager = march("compiled"), march("eager")
    same = torch.equal(compiled.ray_indices, eager.ray_indices) and torch.equal(compiled.t_starts, eager.t_starts)
    seconds = {backend: median_seconds(lambda: march(backend), args.repeats) for backend in ("eager", "compiled")}
    print(json.dumps({
        "threads": torch.get_num_threads(), "rays": len(rays.origins), "occupancy": round(grid.occupancy, 4),
        "samples_kept": len(compiled), "same_samples": same,
        "eager_seconds": round(seconds["eager"], 4), "compiled_seconds": round(seconds["compiled"], 4),
        "compiled_speedup": round(seconds["eager"] / seconds["compiled"], 2),
    }, indent=2))


if __name__ == "__main__":
    main()
