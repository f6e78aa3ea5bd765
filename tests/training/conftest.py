"""Tests here run tiny models: one torch thread is faster than several, and steady on busy cores."""

from __future__ import annotations

import pytest


@pytest.fixture(autouse=True, scope="module")
def _one_thread_here(one_torch_thread):
    """Every module here runs with :func:`one_torch_thread` (tests/conftest.py)."""
