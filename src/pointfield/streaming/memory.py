"""The memory budget of a streaming job: parsing ``--memory 2G``, and what it buys.

A budget is the resident memory a job may use, the interpreter and its libraries included.
:func:`plan` divides it: the interpreter's own footprint (measured, at least
``BASELINE_BYTES``), the chunks in flight (the one read ahead, the one read, converted and
reduced: ``CHUNK_COPIES`` copies of a chunk), and what remains for a verb's running state (the voxel accumulators of
``downsample``), which spills to disk when it outgrows its share. While a job runs, glibc's mmap
threshold is fixed (:func:`returning_freed_arrays`, entered by :func:`~.jobs.streaming_job`),
without which freed chunks stay resident and memory grows with the input rather than staying at
the budget.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import re
import threading
from collections.abc import Iterator
from dataclasses import dataclass

import psutil

from pointfield.errors import OptionError

DEFAULT_MEMORY = "1G"
MIN_MEMORY = 256 << 20
# numpy, laspy, pointfield: the resident size of an interpreter before it reads anything.
BASELINE_BYTES = 200 << 20
# Bytes a point costs while its chunk is in flight, per byte of its record: the raw record,
# its fields as arrays, float64 coordinates and voxel keys, numpy's temporaries, and the next
# chunk read ahead (streaming/readahead.py).
CHUNK_COPIES = 8
MIN_CHUNK_POINTS = 1 << 12
MAX_CHUNK_POINTS = 1 << 22

_UNITS = {"": 1, "k": 1 << 10, "m": 1 << 20, "g": 1 << 30, "t": 1 << 40}


def parse_memory(text: str | int) -> int:
    """Bytes of ``"2G"``, ``"512M"``, ``"1.5GB"``, ``"800MiB"`` or a plain number of bytes.

    >>> parse_memory("1.5G")
    1610612736
    """
    if isinstance(text, int):
        return text
    match = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*([kKmMgGtT]?)(?:i?[bB])?\s*", str(text))
    if match is None:
        raise OptionError(f"--memory {text!r}: expected a size such as 2G, 512M or 1.5GB")
    return int(float(match.group(1)) * _UNITS[match.group(2).lower()])


@dataclass(frozen=True)
class MemoryPlan:
    """How a budget is spent: ``chunk_points`` per chunk, ``state_bytes`` for running state."""

    budget: int
    chunk_points: int
    state_bytes: int


def plan(budget: int | str, bytes_per_point: int, chunk_points: int | None = None) -> MemoryPlan:
    """Split ``budget`` between chunks of points of ``bytes_per_point`` and running state.

    A quarter of what is left after the interpreter goes to chunks (unless ``chunk_points`` is
    given), the rest to state. Budgets below ``MIN_MEMORY`` are refused: they would not hold
    the interpreter.
    """
    budget = parse_memory(budget)
    if budget < MIN_MEMORY:
        raise OptionError(f"--memory {budget >> 20} MiB is too small to hold the interpreter; give at least 256M")
    usable = usable_bytes(budget)
    if chunk_points is None:
        chunk_points = usable // 4 // max(1, CHUNK_COPIES * bytes_per_point)
        chunk_points = int(min(MAX_CHUNK_POINTS, max(MIN_CHUNK_POINTS, chunk_points)))
    chunk_bytes = chunk_points * CHUNK_COPIES * bytes_per_point
    return MemoryPlan(budget, int(chunk_points), int(max(usable - chunk_bytes, usable // 4)))


@contextlib.contextmanager
def returning_freed_arrays() -> Iterator[None]:
    """Inside, glibc gives every freed array of 1 MiB or more straight back to the system.

    By default glibc raises its mmap threshold each time a large block is freed, up to 32 MiB,
    after which chunk-sized arrays come from heap arenas (one per thread: the reading thread
    allocates, the main one frees) that keep what was freed: resident memory creeps up with
    every chunk, and with the input's size. A fixed 1 MiB threshold keeps it at the budget.

    The setting is the whole process's, and costly outside a job: every tensor of a megabyte is
    then mapped and faulted in afresh (a hash-grid field trained 1.4 to 1.8 times slower after a
    downsample in the same process). glibc cannot go back to its dynamic thresholds, so on the
    way out they are fixed where the dynamic ones end after large frees (mmap 32 MiB, trim 64
    MiB). Nested jobs restore once, when the outermost ends. Only glibc has ``mallopt``;
    elsewhere this does nothing.
    """
    global _JOBS_INSIDE
    with _JOBS_LOCK:  # a library user may run jobs in several threads at once
        _JOBS_INSIDE += 1
        if _JOBS_INSIDE == 1:
            _mallopt(_M_MMAP_THRESHOLD, 1 << 20)
    try:
        yield
    finally:
        with _JOBS_LOCK:
            _JOBS_INSIDE -= 1
            if _JOBS_INSIDE == 0:
                _mallopt(_M_MMAP_THRESHOLD, GLIBC_MMAP_THRESHOLD_MAX)
                _mallopt(_M_TRIM_THRESHOLD, 2 * GLIBC_MMAP_THRESHOLD_MAX)


def _mallopt(parameter: int, value: int) -> None:
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        libc.mallopt(parameter, value)
    except (OSError, AttributeError):
        pass


_JOBS_INSIDE = 0
_JOBS_LOCK = threading.Lock()
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # glibc's malloc.h
GLIBC_MMAP_THRESHOLD_MAX = 32 << 20
"""Where glibc's dynamic mmap threshold stops rising on 64-bit systems (its trim threshold: twice that)."""


def usable_bytes(budget: int) -> int:
    """What ``budget`` bytes leave for data beside the interpreter: the budget less this process's
    resident size now (at least ``BASELINE_BYTES``), and never less than a quarter of the budget,
    so that a process already holding more than the budget (a notebook, a test runner's worker)
    still works, within that quarter, rather than refusing everything."""
    return max(budget - max(BASELINE_BYTES, resident_bytes()), budget // 4)


def resident_bytes() -> int:
    """This process's resident set size now."""
    return int(psutil.Process().memory_info().rss)
