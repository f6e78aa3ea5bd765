"""Fixtures shared by the scene-segmentation tests of this folder and of models/."""

from __future__ import annotations

from pathlib import Path

import pytest
from scene_rooms import make_rooms


@pytest.fixture(scope="session")
def rooms(tmp_path_factory) -> Path:
    """:func:`scene_rooms.make_rooms`, made once; tests only read them."""
    return make_rooms(tmp_path_factory.mktemp("rooms") / "rooms")
