"""Gaussian splats on lego at 100 x 100: time to 25 and 28 dB held-out PSNR, and render speed.

The claim (issue 7): on the NeRF-synthetic lego scene at 100 x 100 (``--downscale 8
--holdout-every 10``), splats trained on this CPU reach at least 28 dB held-out PSNR, and a
trained model renders a 100 x 100 view at 20 frames per second or more.

The run is ``pointfield.splats.train.train`` -- exactly what ``pointfield splat train`` runs --
scoring all ten held-out views every ``--eval-every`` steps; the times to 25 and 28 dB are read
from its ``metrics.jsonl`` (training seconds, evaluations included). Rendering is timed on the
trained model: the median of ``--frames`` renders of a held-out camera, without gradients.

Run: ``python benchmarks/bench_splat.py --out runs/bench-splat`` (``--threads 1`` on a busy
machine: with more threads than free cores, PyTorch's thread pool spins and every step slows
down many times over).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import torch

LEGO = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "nerf" / "lego_blender"
THRESHOLDS = (25.0, 28.0)


def first_time_at(records: list[dict], psnr: float) -> dict | None:
    for record in records:
        if record.get("psnr", 0.0) >= psnr:
            return {"step": record["step"], "seconds": record["seconds"], "psnr": record["psnr"]}
    return None


def render_fps(run: Path, frames: int) -> dict:
    from pointfield.fields.train import open_scene_of, training_and_heldout
    from pointfield.splats.train import camera_matrices, load_run, render_views

    config, gaussians, device = load_run(run, "cpu")
    scene = open_scene_of(config)
    _, heldout = training_and_heldout(scene)
    viewmats, Ks = camera_matrices(scene.cameras[heldout[:1]], device)
    background = torch.as_tensor(scene.background, dtype=torch.float32)
    width, height = int(scene.cameras.width[0]), int(scene.cameras.height[0])
    times = []
    with torch.no_grad():
        for _ in range(frames + 1):
            start = time.perf_counter()
            render_views(gaussians, viewmats, Ks, width, height, background)
            times.append(time.perf_counter() - start)
    median = statistics.median(times[1:])  # the first render warms caches up
    return {"splats": len(gaussians), "width": width, "height": height,
            "median_seconds": median, "fps": 1 / median}


def main() -> None:
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

    from pointfield.splats.train import train
    from pointfield.training import RunDirectory

    metrics = train(
        args.scene, out=args.out, steps=args.steps, max_time=args.max_time, downscale=8,
        holdout_every=10, eval_every=args.eval_every, eval_views=10,
        initial_splats=args.initial_splats, max_splats=args.max_splats, resume=args.resume,
        progress=False,
    )
    records = RunDirectory(args.out).read_metrics_log()
    result = {
        "final": metrics,
        "time_to": {f"{t:g} dB": first_time_at(records, t) for t in THRESHOLDS},
        "render": render_fps(args.out, args.frames),
        "threads": torch.get_num_threads(),
        "settings": {k: str(v) for k, v in vars(args).items()},
    }
    print(json.dumps(result, indent=2))
    (args.out / "bench_splat.json").write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
