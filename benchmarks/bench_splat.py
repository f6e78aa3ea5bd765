"""Gaussian splats on lego at 100 x 100: time to 25 and 28 dB held-out PSNR, and render speed.

The claim (issue 7): on the NeRF-synthetic lego scene at 100 x 100 (``--downscale 8
--holdout-every 10``), splats trained on this CPU reach at least 28 dB held-out PSNR, and a
trained model renders a 100 x 100 view at 20 frames per second or more.

The run is ``pointfield.splats.train.train`` -- exactly what ``pointfield splat train`` runs --
scoring all ten held-out views every ``--eval-every`` steps (held-out PSNR: the mean of per-view
PSNR). The times to 25 and 28 dB are read from its ``metrics.jsonl`` as every benchmark reads
them (:func:`harness.training_curve`): training seconds, evaluations excluded; what the training
clock leaves out (start-up, the final evaluation) is reported beside them. Rendering is timed
on the trained model: the median of ``--frames`` renders of a held-out camera, without
gradients.

Run: ``python benchmarks/bench_splat.py --out runs/bench-splat`` (``--threads 1`` on a busy
machine: with more threads than free cores, PyTorch's thread pool spins and every step slows
down many times over); the record goes to ``benchmarks/records/splat.json``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch

from harness import Record, device_name, interleaved, time_to, training_curve

LEGO = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "nerf" / "lego_blender"
THRESHOLDS = (25.0, 28.0)


def render_fps(run_folder: Path, frames: int) -> dict:
    """Frames per second of ``run.render`` (what a user calls) on the run's first held-out view."""
    import pointfield
    from pointfield.scenes.heldout import training_and_heldout

    run = pointfield.load_run(run_folder, "cpu")
    _, heldout = training_and_heldout(run.scene)
    cameras = run.scene.cameras[heldout[:1]]
    timing = interleaved({"render": lambda: run.render(cameras)}, frames)["render"]
    width, height = int(cameras.width[0]), int(cameras.height[0])
    return {"splats": len(run.gaussians), "width": width, "height": height, **timing.as_dict(), "fps": 1 / timing.median}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", type=Path, default=LEGO, help="lego (Blender format)")
    parser.add_argument("--out", type=Path, default=Path("runs/bench-splat"), help="run folder")
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--max-time", type=float, default=1800.0, help="seconds of training at most")
    parser.add_argument("--eval-every", type=int, default=100)
    parser.add_argument("--initial-splats", type=int, default=5000)
    parser.add_argument("--max-splats", type=int, default=50_000)
    parser.add_argument("--frames", type=int, default=20, help="renders to time")
    parser.add_argument("--threads", type=int, help="torch.set_num_threads (default: PyTorch's)")
    parser.add_argument("--resume", action="store_true", help="continue the run in --out")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)

    from pointfield.compiling import compiler_available
    from pointfield.devices import pick_device
    from pointfield.splats.rasterizer import _FUSED_BANDS, _FUSED_PROJECT, _FUSED_TILE_SPANS
    from pointfield.splats.train import train
    from pointfield.training import RunDirectory

    record = Record(
        "splat", "Gaussian splats on lego", issue="7", device=device_name(pick_device(None)),
        about="NeRF-synthetic lego at 100 x 100 (`--downscale 8 --holdout-every 10`), trained by "
              "`pointfield.splats.train.train` and scored on all ten held-out views every `--eval-every` steps; "
              "times to a PSNR are training seconds, evaluations excluded. The render is the trained model's "
              "view of a held-out camera without gradients.")
    started = time.perf_counter()
    metrics = train(
        args.scene, out=args.out, steps=args.steps, max_training_time=args.max_time, downscale=8,
        holdout_every=10, eval_every=args.eval_every, eval_views=10,
        initial_splats=args.initial_splats, max_splats=args.max_splats, resume=args.resume,
        progress=False,
    )
    wall = time.perf_counter() - started
    curve = training_curve(RunDirectory(args.out).read_metrics_log(), metrics)
    reached = {f"{t:g} dB": time_to(curve, t) for t in THRESHOLDS}
    render = render_fps(args.out, args.frames)
    if compiler_available(torch.device("cpu")):
        record.require_compiled(_FUSED_PROJECT, _FUSED_BANDS, _FUSED_TILE_SPANS)
    record.figures.update({"final": metrics, "time_to": reached, "curve": curve, "render": render,
                           "outside_clock_seconds": wall - metrics["seconds"], "run": str(args.out)})
    record.table(
        ["splats", *(f"time to {t:g} dB" for t in THRESHOLDS), "final (held-out)", "training s",
         "outside the clock s", "one render"],
        [[f"{render['splats']:,}",
          *("-" if p is None else f"{p['training_seconds']:.1f} s (step {p['step']:,})" for p in reached.values()),
          f"{metrics['psnr']:.2f} dB, SSIM {metrics['ssim']:.3f}, {metrics['steps']:,} steps",
          f"{curve[-1]['training_seconds']:.1f}", f"{wall - metrics['seconds']:.1f}",
          f"{render['median_seconds']:.4f} s ({render['fps']:.1f} fps)"]],
        title=f"{render['width']} x {render['height']}, median of {args.frames} renders",
    )
    record.verdict("splats reach 28 dB held-out", metrics["psnr"] >= 28, f"final {metrics['psnr']:.2f} dB")
    record.verdict(f"a trained model renders {render['width']}x{render['height']} at >= 20 fps", render["fps"] >= 20,
                   f"{render['fps']:.1f} fps")
    return record.finish()


if __name__ == "__main__":
    sys.exit(main())
