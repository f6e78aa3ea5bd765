"""What ``nerf train`` and ``splat train`` share about time: ``--max-time`` and the closing line's clock.

``--max-time`` is the wall clock of the whole command, from the moment :func:`pointfield.cli.main`
starts (importing torch, reading the scene, compiling kernels, training, evaluating) to its
closing line: the Python function's ``max_time`` is given what the command has left of it.

On a CPU, a training given neither ``--steps`` nor ``--max-time`` gets ``--max-time``
:data:`CPU_DEFAULT_MAX_TIME`: a user's photos trained with no options are scored and done
within ten minutes on a laptop, where the default step count would take about 17 minutes (3,000
splat steps of the fox's photos at 135 x 240 px, 0.33 s each on 2 quiet cores in bench_photos). It
is printed at the start; ``--steps N`` trains to N steps whatever it takes.
"""

from __future__ import annotations

import argparse
import time

from pointfield.errors import PointfieldError

CPU_DEFAULT_MAX_TIME = 540.0
"""``--max-time`` of a CPU training given neither ``--steps`` nor ``--max-time``: nine minutes, so that
the command is over within ten with its start-up and final evaluation (benchmarks/bench_photos.py
measures the fox's)."""


def add_max_time_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--max-time", type=float, metavar="SECONDS",
        help="the whole command returns within SECONDS of wall clock: start-up, training, evaluations and "
        "the final score (scored on fewer held-out views if all of them would not fit; metrics.json says how many). "
        f"Default: no limit; {CPU_DEFAULT_MAX_TIME:.0f} on a CPU when --steps is not given either",
    )


def max_time_left(args: argparse.Namespace) -> float | None:
    """What the command has left of ``--max-time`` (None: no limit), at least a millisecond."""
    if args.max_time is None:
        return None
    if not args.max_time > 0:
        raise PointfieldError(f"--max-time must be a positive number of seconds, got {args.max_time:g}")
    return max(args.max_time - command_seconds(args), 1e-3)


def training_budget(args: argparse.Namespace) -> float | None:
    """:func:`max_time_left` for ``nerf train`` and ``splat train``, with the CPU's default budget.

    Without ``--steps`` and ``--max-time``, on a CPU (``--device`` as :func:`~pointfield.devices.pick_device`
    reads it), ``args.max_time`` becomes :data:`CPU_DEFAULT_MAX_TIME` and one line says so.
    """
    if args.max_time is None and args.steps is None:
        from pointfield.devices import pick_device

        if pick_device(args.device).type == "cpu":
            args.max_time = CPU_DEFAULT_MAX_TIME
            print(f"pointfield: --max-time {CPU_DEFAULT_MAX_TIME:.0f}: no --steps or --max-time on a CPU, so the "
                  "run stops within ten minutes (--steps N trains to N steps)", flush=True)
    return max_time_left(args)


def command_seconds(args: argparse.Namespace) -> float:
    """Seconds since the command started (since :func:`pointfield.cli.main` was called)."""
    return time.perf_counter() - getattr(args, "started", time.perf_counter())


def clock_text(metrics: dict, args: argparse.Namespace) -> str:
    """``"1,234 steps in 29 s"``: the steps trained and the command's wall clock so far."""
    steps = metrics["steps"]
    return f"{steps:,} step{'' if steps == 1 else 's'} in {command_seconds(args):.0f} s"


def views_text(metrics: dict) -> str:
    """``" on 3 of 10 held-out views at 1/2 size (all would not fit --max-time)"`` when the final evaluation
    was cut short or shrunk to fit."""
    views, heldout = metrics.get("views"), metrics.get("heldout_views")
    downscale = metrics.get("evaluation_downscale", 1)
    if views is None or heldout is None or (views >= heldout and downscale == 1):
        return ""
    size = f" at 1/{downscale} size" if downscale > 1 else ""
    return f" on {views} of {heldout} held-out views{size} (all would not fit --max-time)"


def scores_text(metrics: dict) -> str:
    """``"held-out PSNR 30.12 dB, SSIM 0.9500"`` (with :func:`views_text`), or for a run trained on every
    view (``--holdout-every 0``) ``"training PSNR 28.40 dB (no held-out views)"``."""
    if metrics.get("psnr") is None:
        training = metrics.get("train_psnr")
        return "no held-out views" if training is None else f"training PSNR {training:.2f} dB (no held-out views)"
    return f"held-out PSNR {metrics['psnr']:.2f} dB{views_text(metrics)}, SSIM {metrics['ssim']:.4f}"
