"""The memory budget: sizes as people write them, and how a budget is shared."""

from __future__ import annotations

import platform
import resource
import subprocess
import sys

import pytest

from pointfield.streaming.memory import (
    CHUNK_COPIES,
    MIN_MEMORY,
    parse_memory,
    plan,
    usable_bytes,
)


@pytest.mark.parametrize(("text", "size"), [("2G", 2 << 30), ("512M", 512 << 20), ("1.5GB", 3 << 29), ("800MiB", 800 << 20), ("4096", 4096)])
def test_sizes_read_the_way_people_write_them(text, size):
    assert parse_memory(text) == size


def test_a_size_that_is_not_one_is_refused():
    with pytest.raises(ValueError, match="expected a size"):
        parse_memory("lots")


def test_a_larger_budget_buys_larger_chunks_and_more_state_never_past_the_budget():
    small, large = plan("512M", 100), plan("4G", 100)
    assert small.chunk_points < large.chunk_points and small.state_bytes < large.state_bytes
    for budget in (small, large):
        assert budget.chunk_points * 100 * CHUNK_COPIES + budget.state_bytes < budget.budget


def test_a_budget_too_small_for_the_interpreter_is_refused():
    with pytest.raises(ValueError, match="too small"):
        plan(MIN_MEMORY - 1, 100)


def test_what_a_budget_leaves_is_the_budget_less_the_process_but_never_under_a_quarter(monkeypatch):
    """A fresh command keeps all but its interpreter; a process already bigger than the budget (a
    notebook, a test runner's worker) still gets a quarter, as streaming and registration both plan."""
    from pointfield.streaming import memory

    monkeypatch.setattr(memory, "resident_bytes", lambda: 300 << 20)
    assert usable_bytes(1 << 30) == (1 << 30) - (300 << 20)
    monkeypatch.setattr(memory, "resident_bytes", lambda: 3 << 30)
    assert usable_bytes(1 << 30) == 1 << 28


FAULTS_OF_REUSING_AN_ARRAY = """
import resource, sys
import numpy as np
from pointfield.streaming.memory import returning_freed_arrays

def faults(size=2 << 20, times=20):  # under numpy's 4 MiB hugepage advice
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(times):
        array = np.ones(size, dtype=np.uint8)  # every page written: it faults if newly mapped
        del array
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before

with returning_freed_arrays():
    with returning_freed_arrays():  # a nested job does not end the outer one's setting
        pass
    inside = faults()
print(inside, faults())
"""


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="mmap thresholds are glibc's")
def test_freed_arrays_go_back_to_the_system_only_while_a_job_runs():
    # A fresh process: what an earlier test left in this one's heap would change the counts.
    result = subprocess.run([sys.executable, "-c", FAULTS_OF_REUSING_AN_ARRAY], capture_output=True, text=True,
                            check=True)
    inside, outside = map(int, result.stdout.split())
    pages = (2 << 20) // resource.getpagesize()
    assert inside > 10 * pages, (inside, outside)  # 20 arrays mapped and faulted in afresh
    assert outside < 3 * pages, (inside, outside)  # reused from the heap: what torch's tensors need afterwards
