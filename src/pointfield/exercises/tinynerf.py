"""The lesson's third exercise as a report: TinyNeRF on the synthetic coloured cube.

``pointfield nerf exercise --out DIR`` trains :class:`~pointfield.fields.nerf.TinyNeRF` for 100
epochs (an epoch is one pass over all training rays) and writes ``DIR/REPORT.md`` with the
training loss and held-out PSNR at epochs 1, 10 and 100, a strip of held-out renders at those
epochs and a few between (``DIR/strip.png``), and the first epoch whose held-out PSNR reaches
20 dB -- the report's definition of "recognisable". The run folder is ``DIR/run``.

Scene size: 48 views of the cube at 20 x 20 pixels (40 training views, 16,000 training rays;
4 test views held out, 4 validation views unused), 32 samples per ray, 1,024 rays per step
(16 steps per epoch), Adam at 1e-3. Chosen so that 100 epochs take minutes on a 2-core CPU:
measured, an epoch (512,000 samples) with its one-view evaluation costs about 18 CPU-seconds,
so 100 epochs take about 20 minutes on a quiet 2-core laptop (docs/runs.md).
"""

from __future__ import annotations

import math
import os
import platform
from pathlib import Path
from typing import Any

import numpy as np

from pointfield.atomic import atomic_path
from pointfield.errors import PointfieldError
from pointfield.fields.train import train
from pointfield.scenes.synthetic import split_indices
from pointfield.training import RunDirectory
from pointfield.viz.render import image_grid, save_image
from pointfield.viz.views import to_uint8

EXERCISE_VIEWS = 48
EXERCISE_SIZE = 20
EXERCISE_SAMPLES = 32
EXERCISE_BATCH = 1024
EXERCISE_EPOCHS = 100
EXERCISE_LEARNING_RATE = 1e-3
RECOGNISABLE_PSNR = 20.0
STRIP_EPOCHS = (1, 2, 5, 10, 20, 50, 100)
REPORTED_EPOCHS = (1, 10, 100)


def exercise(
    out: str | os.PathLike[str] = "nerf-exercise",
    *,
    epochs: int = EXERCISE_EPOCHS,
    views: int = EXERCISE_VIEWS,
    size: int = EXERCISE_SIZE,
    device: str | None = None,
    seed: int = 0,
    progress: bool = True,
) -> dict[str, Any]:
    """Train TinyNeRF on the cube for ``epochs`` epochs and write ``out/REPORT.md``; returns its numbers."""
    out = Path(out)
    if (out / "run").exists():
        raise PointfieldError(f"{out} already holds an exercise run; choose another out",
                              command_line=f"{out} already holds an exercise run; choose another --out")
    if epochs < 1:
        raise PointfieldError(f"epochs must be at least 1, got {epochs}")
    rays_per_epoch = _training_rays(views, size)
    steps_per_epoch = math.ceil(rays_per_epoch / EXERCISE_BATCH)
    strip_epochs = [e for e in STRIP_EPOCHS if e <= epochs] or [epochs]
    strip: dict[int, np.ndarray] = {}
    truth_image: list[np.ndarray] = []

    def keep_strip(record: dict[str, float], renders) -> None:
        epoch = round(record["epochs"])
        if epoch in strip_epochs:
            _, rendered, truth = renders[0]
            strip[epoch] = rendered["rgb"]
            if not truth_image:
                truth_image.append(truth)

    metrics = train(
        None, model="tiny", out=out / "run", steps=epochs * steps_per_epoch, batch_rays=EXERCISE_BATCH,
        device=device, seed=seed, eval_every=steps_per_epoch, eval_views=1,
        learning_rate=EXERCISE_LEARNING_RATE, model_options={"samples": EXERCISE_SAMPLES},
        progress=progress, cube_views=views, cube_size=size, on_evaluate=keep_strip,
    )
    history = RunDirectory(out / "run").read_metrics_log()
    by_epoch = {round(record["epochs"]): record for record in history}
    recognisable = next((e for e, r in sorted(by_epoch.items()) if r["psnr"] >= RECOGNISABLE_PSNR), None)

    scale = max(1, 96 // size)  # enlarge the tiny views so the strip can be seen
    images = [np.kron(to_uint8(strip[e]), np.ones((scale, scale, 1), np.uint8)) for e in sorted(strip)]
    images.append(np.kron(to_uint8(truth_image[0]), np.ones((scale, scale, 1), np.uint8)))
    labels = [f"epoch {e}" for e in sorted(strip)] + ["ground truth"]
    save_image(out / "strip.png", image_grid(images, labels, columns=len(images)))
    rows = [
        {"epoch": e, "train_loss": by_epoch[e]["train_loss"], "psnr": by_epoch[e]["psnr"]}
        for e in REPORTED_EPOCHS if e in by_epoch
    ]
    result = {
        "epochs": rows,
        "recognisable_epoch": recognisable,
        "final": metrics,
        "views": views,
        "size": size,
        "training_rays": rays_per_epoch,
        "steps_per_epoch": steps_per_epoch,
    }
    _write_report(out, result, sorted(strip), epochs)
    return result


def _training_rays(views: int, size: int) -> int:
    return len(split_indices(views)["train"]) * size * size


def _write_report(out: Path, result: dict[str, Any], strip_epochs: list[int], epochs: int) -> None:
    final = result["final"]
    lines = [
        "# TinyNeRF on the synthetic coloured cube",
        "",
        "Regenerate with `pointfield nerf exercise --out DIR` (seed 0).",
        "",
        (f"Scene: the built-in cube, {result['views']} views of {result['size']} x {result['size']} pixels "
         f"on a sphere of cameras ({result['training_rays']:,} training rays; test views held out). "
         f"Model: TinyNeRF (4 x 128 trunk, density head, view-dependent colour head), "
         f"{EXERCISE_SAMPLES} stratified samples per ray, {EXERCISE_BATCH} rays per step, Adam at "
         f"{EXERCISE_LEARNING_RATE:g} decayed to a tenth. An **epoch** is one pass over all training rays "
         f"({result['steps_per_epoch']} steps)."),
        "",
        "| epoch | training loss (MSE, epoch mean) | held-out PSNR (dB, first test view) |",
        "|---:|---:|---:|",
    ]
    lines += [f"| {r['epoch']} | {r['train_loss']:.5f} | {r['psnr']:.2f} |" for r in result["epochs"]]
    recognisable = result["recognisable_epoch"]
    lines += [
        "",
        (f'**Recognisable** -- defined here as the first epoch whose held-out PSNR reaches '
         f"{RECOGNISABLE_PSNR:.0f} dB: "
         + (f"epoch {recognisable}." if recognisable is not None else f"not reached in {epochs} epochs.")),
        "",
        (f"After {final['steps']} steps ({final['seconds']:.0f} s of training on "
         f"{platform.machine()} with {os.cpu_count()} CPU core(s) visible): held-out PSNR "
         f"{final['psnr']:.2f} dB, SSIM {final['ssim']:.3f} over {final['views']} test view(s)."),
        "",
        f"Held-out view at epochs {', '.join(map(str, strip_epochs))}, then the ground truth:",
        "",
        "![held-out renders](strip.png)",
        "",
        ("Per-epoch numbers: `run/metrics.jsonl`; curves: `run/training_curves.png`; final renders "
         "beside the ground truth (colour, depth, opacity): `run/heldout/`."),
        "",
    ]
    with atomic_path(out / "REPORT.md") as tmp:
        tmp.write_text("\n".join(lines), encoding="utf-8")
