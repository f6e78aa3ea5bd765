"""The options ``nerf train`` and ``splat train`` share about the scene they train on: image size and held-out views.

Their defaults are chosen from the scene and the device (:mod:`pointfield.scenes.training_defaults`).
"""

from __future__ import annotations

import argparse


def downscale_value(text: str) -> int | str:
    """``--downscale``: "auto" or a positive integer."""
    if text == "auto":
        return text
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected auto or a positive integer, got {text!r}")
    return value


def holdout_value(text: str) -> int:
    """``--holdout-every``: 0 (hold nothing out) or an integer of at least 2."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value != 0 and value < 2:
        raise argparse.ArgumentTypeError(f"expected 0 or an integer of at least 2, got {text!r}")
    return value


def add_scene_training_options(parser: argparse.ArgumentParser) -> None:
    """``--downscale`` (default auto) and ``--holdout-every`` (default: every 8th view without a test split)."""
    parser.add_argument("--downscale", type=downscale_value, default="auto", metavar="N|auto",
                        help="divide image sizes by N; auto (default): the power of two that brings the longest "
                             "side to at most 1600 px on a GPU, 480 px on a CPU (printed, and kept in the run's config)")
    parser.add_argument("--holdout-every", type=holdout_value, metavar="N",
                        help="hold every N-th training view out for evaluation (default: 8 for scenes without "
                             "test or val views); 0 trains on every view and reports training PSNR only")
