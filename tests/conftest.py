"""Shared fixtures: the real files in ../shared/data (skipped with a reason when absent), one torch
thread for tiny models, and the best score a flat colour can reach on the synthetic cube.

And how the suite shares the machine when pytest-xdist runs it in several workers (``make test``
runs ``-n auto``): each folder's tests run on one worker, so that the trained runs a folder's
conftest shares (session fixtures) are trained once; each worker gets its share of the cores as
torch threads. On a 2-core machine like CI's, in one checkout at 98ea1ab: 10 min 25 s in one
process, 7 min 59 s in two workers.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch

from pointfield.metrics import psnr
from pointfield.scenes import synthetic_scene

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
SOURCE = Path(__file__).resolve().parents[1] / "src"


def pytest_configure(config):
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    if workers > 1:  # oversubscribed OpenMP threads spin against each other's workers
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
        torch.set_num_threads(max(1, cores // workers))


LONGEST_FOLDERS = ("tests/guides",)
"""Folders handed out first. xdist orders the folders by their number of tests, and tests/guides
has seven that take over two minutes together (the README's and the guides' commands): handed out
among the last, one worker can still be on them long after the other has finished (longest first
balances best)."""


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """pytest-xdist hands out each folder's tests to one worker (module doc).

    A scheduler of our own rather than ``--dist loadgroup`` with marks: xdist 3.8 tags a group
    onto ``item._nodeid``, which pytest 9 no longer reads, so the groups were silently ignored.
    """
    from xdist.scheduler import LoadScopeScheduling

    class ByFolder(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return nodeid.split("::", 1)[0].rpartition("/")[0]

        def _assign_work_unit(self, node) -> None:
            for scope in [scope for scope in self.workqueue if scope.endswith(LONGEST_FOLDERS)]:
                self.workqueue.move_to_end(scope, last=False)
            super()._assign_work_unit(node)

    return ByFolder(config, log)


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The ../shared/data folder of real files; tests that need it skip when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real data not available: {SHARED_DATA} does not exist")
    return SHARED_DATA


@pytest.fixture(scope="module")
def one_torch_thread():
    """Torch on one thread for a module: tiny models run faster so, and steadily on busy cores."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="session")
def checkout_environment() -> dict[str, str]:
    """The environment for a child Python process that imports this checkout's pointfield (its
    ``src`` first on ``PYTHONPATH``), not another installed one."""
    return {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(SOURCE), os.environ.get("PYTHONPATH")]))}


@pytest.fixture(scope="session")
def best_flat_colour_psnr() -> Callable[[int, int], float]:
    """``(views, size) -> dB``: the highest PSNR any one-colour image scores on a held-out cube view.

    For each view that colour is the view's own mean colour (it minimises the squared error),
    so no scene model that ignores where its rays go can score more.
    """

    def best(views: int, size: int) -> float:
        scene = synthetic_scene("cube", views=views, size=size)
        held_out = [int(i) for name in ("test", "val") for i in scene.splits.get(name, [])]
        scores = []
        for index in held_out:
            image = scene.image(index)
            flat = np.broadcast_to(image.reshape(-1, 3).mean(axis=0), image.shape)
            scores.append(psnr(flat, image))
        return max(scores)

    return best
