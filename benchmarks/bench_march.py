"""Ray marching through an occupancy grid: the compiled occupancy test against the same test run eagerly.

The claim (issue 6's render time): :func:`pointfield.fields.ngp.march_rays` tests every fixed
step of every ray against the occupancy grid -- about 1.4 million candidates for a 100 x 100
lego view -- as one dense expression (:func:`~pointfield.fields.ngp.occupied_candidates`) that
``torch.compile`` fuses into one loop where a compiler exists (:mod:`pointfield.compiling`).
The peer, measured in the same run, is the same function run eagerly; both must keep exactly
the same samples.

The scene is lego's: its 64^3 grid over the box [-1.5, 1.5]^3 (steps of |box| / 256), with
lego-like occupancy (a ball of radius 0.8 on a floor slab, 11 % of the cells), seen by
lego's first camera at 100 x 100 (``--downscale 8``).

Run: ``python benchmarks/bench_march.py`` (``make bench-march``); the record goes to
``benchmarks/records/march.json``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

from harness import Record, interleaved

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


def lego_rays(box: torch.Tensor):
    from pointfield.fields.rays import SceneExtent
    from pointfield.fields.train import scene_rays
    from pointfield.scenes import read_scene

    scene = read_scene(LEGO).downscaled(8)
    rays, _ = scene_rays(scene, [0], SceneExtent(box.tolist()), torch.device("cpu"))
    return rays


def main() -> int:
    from pointfield.fields.sampling.occupancy import _FUSED_OCCUPIED_CANDIDATES, march_rays

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=15, help="marches timed per backend, interleaved (median)")
    parser.add_argument("--threads", type=int, help="torch.set_num_threads (default: PyTorch's)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    if not (LEGO / "transforms_train.json").is_file():
        raise SystemExit(f"lego scene not found at {LEGO}")
    grid = lego_like_grid()
    rays = lego_rays(grid.box)
    step = float(torch.linalg.norm(grid.box[1] - grid.box[0])) / 256

    def march(backend: str):
        return march_rays(rays, grid, step, backend=backend)

    record = Record(
        "march", "Ray marching through an occupancy grid, compiled against eager", issue="6",
        about="`fields.ngp.march_rays` tests every fixed step of every ray against the occupancy grid as one "
              "dense expression, which `torch.compile` fuses; the peer is the same function run eagerly, in the "
              "same run, and both must keep the same samples. Lego's first camera at 100 x 100, its 64^3 grid "
              "over [-1.5, 1.5]^3 (steps of |box| / 256) with lego-like occupancy: a ball of radius 0.8 on a "
              "floor slab.")
    compiled, eager = march("compiled"), march("eager")
    same = torch.equal(compiled.ray_indices, eager.ray_indices) and torch.equal(compiled.t_starts, eager.t_starts)
    timings = interleaved({"eager": lambda: march("eager"), "compiled": lambda: march("compiled")}, args.repeats)
    record.require_compiled(_FUSED_OCCUPIED_CANDIDATES)
    speedup = timings["eager"].median / timings["compiled"].median
    record.figures.update({
        "rays": len(rays.origins), "occupancy": grid.occupancy, "samples_kept": len(compiled), "same_samples": same,
        **{backend: timing.as_dict() for backend, timing in timings.items()}, "compiled_speedup": speedup,
    })
    record.table(
        ["backend", "median ms", "fastest ms", "slowest ms", "spread"],
        [[backend, f"{timing.median * 1e3:.1f}", f"{min(timing.seconds) * 1e3:.1f}",
          f"{max(timing.seconds) * 1e3:.1f}", f"{timing.spread:.0%}"] for backend, timing in timings.items()],
        title=f"{len(rays.origins):,} rays, {grid.occupancy:.1%} of the cells occupied, {len(compiled):,} samples "
              f"kept; median of {args.repeats} interleaved marches each",
    )
    record.verdict("both backends keep the same samples", same)
    record.verdict("the compiled march is faster than the eager one", speedup > 1, f"{speedup:.2f}x")
    return record.finish()


if __name__ == "__main__":
    sys.exit(main())
