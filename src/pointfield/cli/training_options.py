"""What ``nerf train`` and ``splat train`` share about time: ``--max-time`` and the closing line's clock.

``--max-time`` is the wall clock of the whole command, from the moment :func:`pointfield.cli.main`
starts (importing torch, reading the scene, compiling kernels, training, evaluating) to its
closing line: the Python function's ``max_time`` is given what the command has left of it.
"""

from __future__ import annotations

import argparse
import time

from pointfield.errors import PointfieldError


def add_max_time_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--max-time", type=float, metavar="SECONDS",
        help="the whole command returns within SECONDS of wall clock: start-up, training, evaluations and "
        "the final score (scored on fewer held-out views if all of them would not fit; metrics.json says how many)",
    )


def max_time_left(args: argparse.Namespace) -> float | None:
    """What the command has left of ``--max-time`` (None: no limit), at least a millisecond."""
    if args.max_time is None:
        return None
    if not args.max_time > 0:
        raise PointfieldError(f"--max-time must be a positive number of seconds, got {args.max_time:g}")
    return max(args.max_time - command_seconds(args), 1e-3)


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
