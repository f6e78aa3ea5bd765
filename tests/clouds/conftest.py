"""Fixtures shared by the scene-segmentation tests of this folder and of models/."""

from __future__ import annotations

from pathlib import Path

import pytest
from scene_rooms import TINY, make_rooms

from pointfield.cli import main


@pytest.fixture(scope="session")
def rooms(tmp_path_factory) -> Path:
    """:func:`scene_rooms.make_rooms`, made once; tests only read them."""
    return make_rooms(tmp_path_factory.mktemp("rooms") / "rooms")


@pytest.fixture(scope="session")
def rooms_run(rooms, tmp_path_factory) -> Path:
    """A PointNet++ scene run trained for 3 epochs on :func:`rooms` with the TINY settings; tests
    only read it (predictions go elsewhere)."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        out = tmp_path_factory.mktemp("runs") / "rooms"
        assert main(["segment", "train", str(rooms), "--out", str(out), "--epochs", "3", "--lr", "0.002", *TINY]) == 0
    finally:
        torch.set_num_threads(threads)
    return out
