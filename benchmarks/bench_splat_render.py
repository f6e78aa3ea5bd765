"""Gaussian splats: how fast a 100 x 100 view renders, against the dense reference rasterizer.

The claim (issue 7): a trained lego model (about 20,000 splats) renders a 100 x 100 view at 20
frames per second or more on this CPU. This benchmark needs no training run; it renders, in
one run and from the same cameras:

- ``lego-box``: 20,000 splats spread through lego's box [-1.5, 1.5]^3, scales 0.01-0.05,
  random rotations, opacities and SH colours (degree 3) -- a translucent fog in which almost no
  pixel saturates, the worst case for early termination;
- ``lego-surfaces``: 20,000 flat, mostly opaque splats on a sphere and a floor, closer to what
  training makes of lego;
- ``3dgs-ply``: the real 3D-Gaussian-splatting file in ../shared/data (9,080 splats, SH degree 3),
  from a camera at its world origin looking down +z (75 px focal length).

The lego scenes are seen from lego's first camera at 100 x 100 (``--downscale 8``). For each
scene it reports the render speed of :func:`pointfield.splats.rasterizer.rasterization` without
gradients (what ``pointfield splat render`` and held-out evaluation run) -- the median wall time
and the median CPU time of ``--frames`` renders after a warm-up, and the same render with
nothing compiled (``backend="eager"``, the peer of :mod:`pointfield.compiling`'s kernels) -- the
time of one training step
(the same render with gradients, then ``backward``), and the dense, per-splat reference
rasterizer's time for ``--reference-frames`` renders: the peer the ratio is taken against. The
largest difference between the fast image and the reference's shows they draw the same thing.

Run: ``python benchmarks/bench_splat_render.py --threads 1`` (on a busy machine, more threads
than free cores make PyTorch's thread pool spin and every render many times slower); the record
goes to ``benchmarks/records/splat-render.json``.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import torch

from harness import Record, interleaved

SHARED = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
LEGO = SHARED / "nerf" / "lego_blender"
SPLAT_FILE = SHARED / "gaussians" / "3dgs_point_cloud_iter7000.ply"
SIZE = 100


def lego_camera() -> tuple[torch.Tensor, torch.Tensor]:
    from pointfield.scenes import read_scene
    from pointfield.splats.run import camera_matrices

    cameras = read_scene(LEGO).downscaled(8).cameras[[0]]  # 800 x 800 -> 100 x 100
    assert int(cameras.width[0]) == int(cameras.height[0]) == SIZE
    return camera_matrices(cameras, torch.device("cpu"))


def random_sh(count: int, generator: torch.Generator) -> torch.Tensor:
    return torch.randn(count, 16, 3, generator=generator) * torch.tensor([1.0] + [0.15] * 15)[:, None]


def lego_box(count: int = 20_000, seed: int = 0) -> list[torch.Tensor]:
    generator = torch.Generator().manual_seed(seed)
    means = torch.rand(count, 3, generator=generator) * 3 - 1.5
    quats = torch.randn(count, 4, generator=generator)
    scales = torch.exp(torch.empty(count, 3).uniform_(math.log(0.01), math.log(0.05), generator=generator))
    opacities = torch.rand(count, generator=generator) * 0.95 + 0.02
    return [means, quats, scales, opacities, random_sh(count, generator)]


def lego_surfaces(count: int = 20_000, seed: int = 0) -> list[torch.Tensor]:
    generator = torch.Generator().manual_seed(seed)
    on_sphere = count // 2
    normals = torch.randn(on_sphere, 3, generator=generator)
    normals = normals / normals.norm(dim=1, keepdim=True)
    floor = torch.cat([torch.rand(count - on_sphere, 2, generator=generator) * 3 - 1.5,
                       torch.full((count - on_sphere, 1), -0.9)], dim=1)
    means = torch.cat([0.8 * normals, floor])
    normals = torch.cat([normals, torch.tensor([[0.0, 0.0, 1.0]]).expand(count - on_sphere, 3)])
    # The quaternion (wxyz) turning +z onto the normal: axis z x n, w = 1 + z . n.
    quats = torch.stack([1 + normals[:, 2], -normals[:, 1], normals[:, 0], torch.zeros(count)], dim=1)
    size = torch.exp(torch.empty(count).uniform_(math.log(0.02), math.log(0.05), generator=generator))
    scales = torch.stack([size, size, 0.05 * size], dim=1)
    opacities = torch.rand(count, generator=generator) * 0.5 + 0.5
    return [means, quats, scales, opacities, random_sh(count, generator)]


def splat_file() -> list[torch.Tensor]:
    from pointfield.splats.ply import read_splats

    gaussians = read_splats(SPLAT_FILE)
    with torch.no_grad():
        return [gaussians.means.detach(), gaussians.quats.detach(), gaussians.scales.detach(),
                gaussians.opacities.detach(), gaussians.sh_coefficients.detach()]


def origin_camera() -> tuple[torch.Tensor, torch.Tensor]:
    K = torch.tensor([[[75.0, 0, SIZE / 2], [0, 75.0, SIZE / 2], [0, 0, 1]]])
    return torch.eye(4)[None], K


def measure(splats: list[torch.Tensor], viewmats: torch.Tensor, Ks: torch.Tensor, args) -> dict:
    from pointfield.splats.rasterizer import rasterization
    from pointfield.splats.reference import rasterization_reference

    background = torch.ones(3)
    arguments = (viewmats, Ks, SIZE, SIZE)
    options = dict(sh_degree=3, backgrounds=background)

    def render():
        with torch.no_grad():
            return rasterization(*splats, *arguments, **options)

    def render_eager():  # the peer of the compiled kernels: the same render, nothing compiled
        with torch.no_grad():
            return rasterization(*splats, *arguments, **options, backend="eager")

    def train_step():
        parameters = [tensor.clone().requires_grad_() for tensor in splats]
        colors, _, alphas, _ = rasterization(*parameters, *arguments, **options)
        (colors.sum() + alphas.sum()).backward()

    renders = interleaved({"compiled": render, "eager": render_eager}, args.frames)
    cpu = interleaved({"compiled": render}, args.frames, warmup=0, clock=time.process_time)["compiled"]
    step = interleaved({"train step": train_step}, args.train_steps)["train step"]
    result = {
        "splats": len(splats[0]),
        "render": {**renders["compiled"].as_dict(), "fps": 1 / renders["compiled"].median,
                   "median_cpu_seconds": cpu.median, "cpu_fps": 1 / cpu.median},
        "render_eager": renders["eager"].as_dict(),
        "compiled_speedup": renders["eager"].median / renders["compiled"].median,
        "train_step": step.as_dict(),
    }
    if args.reference_frames:
        reference_timing = interleaved({"reference": lambda: rasterization_reference(*splats, *arguments, **options)},
                                       args.reference_frames, warmup=0)["reference"]
        fast, reference = render(), rasterization_reference(*splats, *arguments, **options)
        result["reference"] = {
            **reference_timing.as_dict(), "speedup": reference_timing.median / renders["compiled"].median,
            "max_abs_difference": {name: float((a - b).abs().max())
                                   for name, a, b in zip(("colors", "depths", "alphas"), fast[:3], reference)},
        }
    return result


def main() -> int:
    from pointfield.splats.rasterizer import _FUSED_BANDS, _FUSED_PROJECT, _FUSED_TILE_SPANS

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20, help="renders timed per scene and backend, interleaved")
    parser.add_argument("--train-steps", type=int, default=5, help="training steps to time per scene")
    parser.add_argument("--reference-frames", type=int, default=1,
                        help="renders of the dense reference per scene (0: skip it; one takes seconds)")
    parser.add_argument("--scenes", nargs="+", default=["lego-box", "lego-surfaces", "3dgs-ply"],
                        choices=["lego-box", "lego-surfaces", "3dgs-ply"])
    parser.add_argument("--threads", type=int, help="torch.set_num_threads (default: PyTorch's)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)

    record = Record(
        "splat-render", "Splat rendering at 100 x 100, compiled against eager and the dense reference", issue="7",
        about="A 100 x 100 view rendered by `splats.rasterizer.rasterization` without gradients (what "
              "`pointfield splat render` and held-out evaluation run), interleaved with the same render with "
              "nothing compiled (`backend=\"eager\"`); one training step (render with gradients, then backward); "
              "and the dense, per-splat reference rasterizer, whose image the fast one must reproduce. Scenes: "
              "`lego-box`, 20,000 splats spread through lego's box as a translucent fog (the worst case for early "
              "termination); `lego-surfaces`, 20,000 flat, mostly opaque splats on a sphere and a floor; "
              "`3dgs-ply`, the real 3D-Gaussian-splatting file in ../shared/data (9,080 splats, SH degree 3). "
              "The issue's 20 fps claim is about a trained lego model, measured by `bench_lego.py`.")
    scenes = {
        "lego-box": lambda: (lego_box(), *lego_camera()),
        "lego-surfaces": lambda: (lego_surfaces(), *lego_camera()),
        "3dgs-ply": lambda: (splat_file(), *origin_camera()),
    }
    results = {}
    for name in args.scenes:
        splats, viewmats, Ks = scenes[name]()
        results[name] = measure(splats, viewmats, Ks, args)
        print(f"{name}: measured", flush=True)
    record.require_compiled(_FUSED_PROJECT, _FUSED_BANDS, _FUSED_TILE_SPANS)
    record.figures.update({"size": f"{SIZE}x{SIZE}", "scenes": results})
    rows = []
    for name, result in results.items():
        render, reference = result["render"], result.get("reference")
        rows.append([
            name, f"{result['splats']:,}", f"{render['fps']:.1f}", f"{render['median_seconds'] * 1e3:.1f}",
            f"{render['spread']:.0%}", f"{result['render_eager']['median_seconds'] * 1e3:.1f}",
            f"{result['compiled_speedup']:.2f}x", f"{result['train_step']['median_seconds'] * 1e3:.0f}",
            "-" if reference is None else f"{reference['median_seconds']:.2f}",
            "-" if reference is None else f"{reference['speedup']:.0f}x",
            "-" if reference is None else f"{reference['max_abs_difference']['colors']:.1e}",
        ])
    record.table(["scene", "splats", "fps", "render ms", "spread", "eager ms", "x eager", "train step ms",
                  "reference s", "x reference", "max colour difference"], rows,
                 title=f"median of {args.frames} interleaved renders per backend, {args.train_steps} training steps, "
                       f"{args.reference_frames} reference render(s) per scene")
    for name, result in results.items():
        record.verdict(f"{name}: the compiled render is faster than the eager one", result["compiled_speedup"] > 1,
                       f"{result['compiled_speedup']:.2f}x")
    return record.finish()


if __name__ == "__main__":
    sys.exit(main())
