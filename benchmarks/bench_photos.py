"""A new user's own photos, start to finish, with no options: pose them, train splats, train a field (issue 43).

The three commands a user types after taking photos, each run as they would run it (a fresh
``python -m pointfield`` process, no option but the folders), timed from outside with a wall
clock that includes Python's start and torch's import::

    pointfield scene from-images PHOTOS --out WORK/scene
    pointfield splat train WORK/scene --out WORK/runs/splat
    pointfield nerf train WORK/scene --out WORK/runs/nerf

Everything else is chosen by the commands: the image size (``--downscale auto``), the held-out
views (every 8th, as nerfstudio), the model (ngp) and, on a CPU, the time budget
(``--max-time`` 540 s when neither it nor ``--steps`` is given). The held-out PSNR is what the
run reports in its ``metrics.json`` (the mean of per-view PSNR over the views it held out).

The issue's claims, checked as verdicts: each training is over within 10 minutes on the
machine's cores, and scores at least 25 dB on the views it held out itself.

Run: ``make bench-photos`` (= ``python benchmarks/bench_photos.py``); the record goes to
``benchmarks/records/photos.json``, the scene and runs to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

from harness import ROOT, Record

PHOTOS = ROOT.parent / "shared" / "data" / "nerf" / "fox_instant_ngp" / "images"
WALL_LIMIT = 600.0
"""The issue's: each training with no options is over within 10 minutes on 2 cores."""
PSNR_FLOOR = 25.0
"""The issue's: and scores at least this on the views it held out itself (dB)."""


def pointfield(*arguments: str) -> tuple[float, str]:
    """Run ``pointfield ARGUMENTS`` as a fresh process; its wall clock in seconds and its output.

    A failing command stops the benchmark with its output: a record of a run that did not happen is no record.
    """
    command = [sys.executable, "-m", "pointfield", *arguments]
    started = time.perf_counter()
    done = subprocess.run(command, check=False, capture_output=True, text=True, cwd=ROOT)
    seconds = time.perf_counter() - started
    if done.returncode != 0:
        raise SystemExit(f"`pointfield {' '.join(arguments)}` failed ({done.returncode}):\n{done.stdout}\n{done.stderr}")
    return seconds, done.stdout


def chosen_lines(output: str) -> list[str]:
    """The lines in which a command says what it chose for the user (``pointfield: --downscale 4: ...``)."""
    return [line for line in output.splitlines() if line.startswith("pointfield: --")]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--photos", type=Path, default=PHOTOS,
                        help="a folder of photos (default: instant-ngp's fox, 50 phone photos in ../shared/data)")
    parser.add_argument("--models", nargs="+", choices=("splat", "nerf"), default=["splat", "nerf"],
                        help="which trainings to run after posing (default both)")
    parser.add_argument("--out", type=Path, default=Path("bench-output/photos"))
    args = parser.parse_args()
    args.out = args.out.resolve()  # the commands run in the repository's root
    if not args.photos.is_dir():
        print(f"the photos are absent ({args.photos}); nothing to run", file=sys.stderr)
        return 1
    shutil.rmtree(args.out, ignore_errors=True)  # an earlier run's: the commands refuse used folders
    args.out.mkdir(parents=True)
    scene, photos = args.out / "scene", sorted(p for p in args.photos.iterdir() if p.is_file())
    record = Record(
        "photos", "A user's own photos with no options: posed, then splats and a field trained", issue="43",
        about=f"{len(photos)} photos of `{args.photos.name}` ({args.photos.parent.name}). Each command is a fresh "
              "`python -m pointfield` process given only its folders, as a new user types it, timed from outside "
              "(Python's start and torch's import included); image size, held-out views, model and the CPU's time "
              "budget are the commands' own defaults. Held-out PSNR is the run's own (metrics.json: the mean of "
              "per-view PSNR over the views it held out).")

    rows = []
    seconds, output = pointfield("scene", "from-images", str(args.photos), "--out", str(scene))
    record.figures["from-images"] = {"seconds": seconds}
    rows.append([f"pointfield scene from-images {args.photos.name} --out scene", f"{seconds:.0f}", "", "", "", ""])
    for model in args.models:
        run = args.out / "runs" / model
        seconds, output = pointfield(model, "train", str(scene), "--out", str(run))
        metrics = json.loads((run / "metrics.json").read_text())
        config = json.loads((run / "config.json").read_text())
        figures = {"seconds": seconds, "chosen": chosen_lines(output), "downscale": config.get("downscale"),
                   **{key: metrics.get(key) for key in ("psnr", "ssim", "steps", "views", "heldout_views",
                                                        "evaluation_downscale", "wall_seconds")}}
        record.figures[model] = figures
        size = f"1/{figures['downscale']}" if figures["downscale"] else ""
        views = f"{metrics.get('views')} of {metrics.get('heldout_views')}"
        rows.append([f"pointfield {model} train scene --out runs/{model}", f"{seconds:.0f}", size,
                     f"{metrics['steps']:,}", views, f"{metrics['psnr']:.2f} dB"])
        for line in figures["chosen"]:
            record.note(f"{model} train: {line}")
    record.table(["command", "wall s", "image size", "steps", "held-out views scored", "held-out PSNR"], rows,
                 title=f"{args.photos.name}: posed and trained with no options")
    for model in args.models:
        figures = record.figures[model]
        record.verdict(f"{model} train with no options is over within {WALL_LIMIT / 60:.0f} minutes",
                       figures["seconds"] <= WALL_LIMIT, f"{figures['seconds']:.0f} s")
        record.verdict(f"{model} train with no options scores at least {PSNR_FLOOR:.0f} dB on its held-out views",
                       figures["psnr"] >= PSNR_FLOOR, f"{figures['psnr']:.2f} dB")
    return record.finish()


if __name__ == "__main__":
    sys.exit(main())
