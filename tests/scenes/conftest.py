"""Fixtures for the scene tests: small synthetic datasets made once per session."""

from __future__ import annotations

import pytest

from pointfield.scenes import make_scene


@pytest.fixture(scope="session")
def cube_dataset(tmp_path_factory):
    """The lesson's cube as a Blender-format dataset: 12 views of 32 x 32 (train 10, val 1, test 1)."""
    return make_scene("cube", tmp_path_factory.mktemp("scenes") / "cube", views=12, size=32)
