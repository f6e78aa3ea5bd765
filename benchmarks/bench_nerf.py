"""NeRF on the lego scene at 100 x 100: held-out PSNR, training time and render time of one view.

The claim (issue 5): on NeRF-synthetic lego downscaled to 100 x 100 (``--downscale 8
--holdout-every 10``, white background: 90 training views, views 0, 10, ..., 90 held out),
TinyNeRF reaches at least 20 dB held-out PSNR and NeRF at least 23 dB. The benchmark trains
each model with ``pointfield.fields.train.train`` (the code behind ``pointfield nerf train``)
and reports the held-out PSNR and SSIM, the training time, and the time to render one
100 x 100 view.

Run: ``python benchmarks/bench_nerf.py`` (the full recipe: hours on a CPU, minutes on a GPU),
or shorter with ``--steps-tiny 200 --steps-nerf 50 --max-time 600`` for a smoke run whose
numbers are reported as they are, without pretending to meet the targets.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import torch

from pointfield.fields.train import train

LEGO = Path(__file__).resolve().parents[2] / "shared" / "data" / "nerf" / "lego_blender"
TARGETS = {"tiny": 20.0, "nerf": 23.0}
RECIPES = {  # the classic settings: tiny-NeRF 1,000+ steps of a whole image; NeRF 4,096-ray steps
    "tiny": {"steps": 3000, "batch_rays": 4096, "learning_rate": 5e-4},
    "nerf": {"steps": 20000, "batch_rays": 1024, "learning_rate": 5e-4},
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", type=Path, default=LEGO, help=f"Blender-format lego folder (default {LEGO})")
    parser.add_argument("--models", nargs="+", choices=tuple(TARGETS), default=list(TARGETS))
    parser.add_argument("--steps-tiny", type=int, default=RECIPES["tiny"]["steps"])
    parser.add_argument("--steps-nerf", type=int, default=RECIPES["nerf"]["steps"])
    parser.add_argument("--max-time", type=float, help="seconds of training per model, at most")
    parser.add_argument("--batch-rays", type=int, help="rays per step (default: tiny 4096, nerf 1024)")
    parser.add_argument("--device", default=None, help="auto (default), cpu, cuda, ...")
    parser.add_argument("--out", type=Path, help="keep the run folders here (default: a temporary folder)")
    args = parser.parse_args()
    if not (args.scene / "transforms_train.json").is_file():
        raise SystemExit(f"lego scene not found at {args.scene}")
    steps = {"tiny": args.steps_tiny, "nerf": args.steps_nerf}
    results = {}
    with tempfile.TemporaryDirectory() as scratch:
        root = args.out or Path(scratch)
        for model in args.models:
            recipe = RECIPES[model]
            started = time.perf_counter()
            metrics = train(
                args.scene, model=model, out=root / f"lego-{model}", steps=steps[model],
                max_time=args.max_time, batch_rays=args.batch_rays or recipe["batch_rays"],
                downscale=8, holdout_every=10,
                background="white", device=args.device, learning_rate=recipe["learning_rate"],
                eval_every=max(steps[model] // 10, 1), progress=False,
            )
            results[model] = {
                "psnr": round(metrics["psnr"], 3),
                "ssim": round(metrics["ssim"], 4),
                "target_psnr": TARGETS[model],
                "meets_target": metrics["psnr"] >= TARGETS[model],
                "steps": metrics["steps"],
                "steps_asked": steps[model],
                "training_seconds": round(metrics["seconds"], 1),
                "wall_seconds": round(time.perf_counter() - started, 1),
                "render_seconds_per_view": round(metrics["render_seconds_per_view"], 3),
                "heldout_views": metrics["views"],
            }
            print(f"{model}: {json.dumps(results[model])}", flush=True)
    device = "cuda" if (args.device in (None, "auto") and torch.cuda.is_available()) else (args.device or "cpu")
    print(json.dumps({"device": device, "threads": torch.get_num_threads(), "results": results}, indent=2))


if __name__ == "__main__":
    main()
