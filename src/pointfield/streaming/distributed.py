"""Beyond one machine: the streaming verbs on a Dask cluster (``dask.distributed``).

``workers=N`` starts a local cluster of N worker processes, one thread each (libraries inside
a worker run single-threaded, as Dask sets for BLAS: one core per worker);
``scheduler="tcp://host:8786"`` joins an existing one; ``client=`` takes a Client the caller
already has. Work is split two ways, and never further:

- **by file**: a folder of scans is one task per file (``convert``, ``merge`` of many files);
- **by piece and tile**: one big file is cut into pieces of consecutive points (aligned to
  LAZ chunks, so each worker seeks straight to its piece); each piece task sorts its points
  into tiles (``tile``) or voxel-aligned slabs (``downsample --voxel``) as spills on disk;
  then one task per tile or slab reads its spills in piece order, which is file order, and
  reduces it. No voxel straddles two slabs, and each voxel's points reach one worker in file
  order, so the result is the one a single process computes, bit for bit.

Spills live in a scratch folder beside the output (``scratch=`` to choose it); with workers
on other machines it must be storage they all see. The driver writes the final file from the
tasks' results in order, through the same chunk writers as a single process.
"""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Callable, Iterator
from typing import Any

# Environment of every local worker: one thread for every library that would start its own.
WORKER_ENVIRONMENT = {
    "OMP_NUM_THREADS": 1,
    "MKL_NUM_THREADS": 1,
    "OPENBLAS_NUM_THREADS": 1,
    "RAYON_NUM_THREADS": 1,  # lazrs (LAZ) compresses and decompresses on a rayon pool
    "MALLOC_TRIM_THRESHOLD_": 65536,
    "MALLOC_MMAP_THRESHOLD_": 1 << 20,  # freed chunk-sized arrays go back to the system (memory.py)
}
# Pieces per worker for one big file: enough to balance uneven pieces, few enough to keep
# per-task overhead small.
PIECES_PER_WORKER = 4


@contextlib.contextmanager
def cluster(
    workers: int | None = None, scheduler: str | None = None, client: Any = None
) -> Iterator[Any]:
    """A dask.distributed Client for the job, or None to run in this process.

    ``client`` is used as it is (and left open); ``scheduler`` joins a running cluster;
    ``workers`` starts a local one for the job and shuts it down after.
    """
    if client is not None:
        yield client
        return
    if workers is None and scheduler is None:
        yield None
        return
    import dask
    from distributed import Client, LocalCluster

    if scheduler is not None:
        with Client(scheduler) as joined:
            yield joined
        return
    if workers < 1:
        raise ValueError(f"workers must be at least 1, got {workers}")
    # The nanny writes pre-spawn-environ into this process's os.environ too: put it back after.
    saved = {name: os.environ.get(name) for name in WORKER_ENVIRONMENT}
    with dask.config.set({"distributed.nanny.pre-spawn-environ": WORKER_ENVIRONMENT}):
        local = LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            # Workers log their lost heartbeat when the cluster shuts down; task errors reach
            # the caller through the futures anyway.
            silence_logs=logging.CRITICAL,
        )
    for name, value in saved.items():
        if value is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = value
    try:
        with Client(local) as started:
            yield started
    finally:
        local.close()


def worker_count(client: Any) -> int:
    return max(1, len(client.scheduler_info(n_workers=-1)["workers"]))


def piece_ranges(count: int, pieces: int, aligned: int = 1) -> list[tuple[int, int]]:
    """``pieces`` ranges of consecutive points covering ``count``, starts multiples of ``aligned``."""
    if count == 0:
        return []
    step = max(aligned, -(-count // max(pieces, 1)))
    step = -(-step // aligned) * aligned
    return [(low, min(low + step, count)) for low in range(0, count, step)]


def run_tasks(client: Any, function: Callable[..., Any], calls: list[tuple[Any, ...]], bar: Any = None) -> list[Any]:
    """Run ``function(*args)`` for each of ``calls`` on the cluster, or here, one after another,
    when ``client`` is None; results in call order.

    A task's exception (a FormatError naming a file) is raised here as it was raised there.
    Tasks are module-level functions, so that workers import them by name.
    """
    if client is None:
        results = []
        for args in calls:
            results.append(function(*args))
            if bar is not None:
                bar.update(1)
        return results
    from distributed import as_completed

    futures = [client.submit(function, *args, pure=False) for args in calls]
    try:
        for future in as_completed(futures):
            if future.status == "error":
                future.result()
            if bar is not None:
                bar.update(1)
        return client.gather(futures)
    finally:
        client.cancel(futures)
