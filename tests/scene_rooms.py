"""The tiny synthetic rooms the scene-segmentation tests train on, and the command-line settings
that keep a training on them to seconds (tests/clouds/conftest.py's ``rooms`` fixture makes them)."""

from __future__ import annotations

from pathlib import Path

from pointfield.clouds.synthetic_scenes import make_scenes

TINY = ["--grid", "0.12", "--radius", "1.5", "--points", "192", "--crops", "24", "--batch-size", "8",
        "--no-progress", "--device", "cpu"]
"""``segment train`` options: a coarse grid, small crops, few of them."""


def make_rooms(root: Path) -> Path:
    """Three sparse synthetic rooms (seed 10) in ``root``, with their train/ and test/ split."""
    make_scenes(root, "room", 3, seed=10, density=0.04)
    return root
