"""Splat tests run torch on one thread.

Their renders are tiny and gain nothing from more threads, while on a busy CI machine an
oversubscribed thread pool makes them many times slower. The setting is restored afterwards.
"""

import pytest


@pytest.fixture(autouse=True, scope="module")
def _one_thread_here(one_torch_thread):
    """Every module here runs with :func:`one_torch_thread` (tests/conftest.py)."""
