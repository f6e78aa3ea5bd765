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
from pathlib import Path
from typing import Any

import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.streaming.arrays import corners, finite_rows
from pointfield.streaming.chunks import open_source
from pointfield.streaming.jobs import finite_bounds, indexed_chunks
from pointfield.streaming.spill import Spill
from pointfield.streaming.voxels import VoxelGrid, reduce_voxels

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
    """Run ``function(*args)`` for each of ``calls`` on the cluster; results in call order.

    A task's exception (a FormatError naming a file) is raised here as it was raised there.
    """
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


# ---------------------------------------------------------------------------------------------
# Tasks (module-level functions, so that workers import them by name)


def bounds_task(path: str, options: dict[str, Any], start: int, stop: int, points: int) -> tuple[np.ndarray, np.ndarray, int]:
    """``(min, max, finite count)`` of the finite points of a piece."""
    return finite_bounds(open_source(path, **options), points, start=start, stop=stop)


def select_task(
    path: str,
    options: dict[str, Any],
    start: int,
    stop: int,
    points: int,
    select: Callable[[PointCloud, np.ndarray], PointCloud],
    spill_path: str,
) -> int:
    """Apply ``select`` to each chunk of a piece, appending what it keeps to a spill."""
    source = open_source(path, **options)
    spill = None
    for chunk, index in indexed_chunks(source, points, start, stop):
        kept = select(chunk, index)
        if spill is None:
            spill = Spill(spill_path, kept)
        spill.append(kept)
    return 0 if spill is None else len(spill)


def scatter_task(
    path: str,
    options: dict[str, Any],
    start: int,
    stop: int,
    points: int,
    grid: VoxelGrid,
    cuts: np.ndarray,
    folder: str,
    piece: int,
) -> list[int]:
    """Sort a piece's finite points into the voxel slabs that ``cuts`` (key starts) delimit."""
    source = open_source(path, **options)
    spills: dict[int, Spill] = {}
    for chunk, index in indexed_chunks(source, points, start, stop):
        finite = finite_rows(chunk.points)
        if finite is not None:
            chunk, index = chunk.select(finite), index[finite]
        keys = grid.keys(grid.cells(chunk.points.astype(np.float64)))
        part = np.searchsorted(cuts, keys, side="right") - 1
        for number in np.unique(part):
            mine = part == number
            if number not in spills:
                os.makedirs(Path(folder) / f"slab-{number}", exist_ok=True)
                spills[number] = Spill(Path(folder) / f"slab-{number}" / f"piece-{piece:06d}.spill", chunk, with_index=True)
            spills[number].append(chunk.select(mine), index[mine])
    return [len(spills[n]) if n in spills else 0 for n in range(len(cuts))]


def reduce_task(
    grid: VoxelGrid,
    template: PointCloud,
    mode: str,
    state_bytes: int,
    folder: str,
    slab: int,
    pieces: int,
    points: int,
    key_range: tuple[int, int],
) -> tuple[int, np.ndarray, np.ndarray]:
    """Reduce one slab from its pieces' spills, in piece order; the voxels go to a spill.

    Returns ``(voxels, min, max)`` of the result.
    """
    slab_folder = Path(folder) / f"slab-{slab}"

    def stream() -> Iterator[tuple[PointCloud, np.ndarray]]:
        for piece in range(pieces):
            spill = Spill(slab_folder / f"piece-{piece:06d}.spill", template, with_index=True)
            yield from spill.chunks(points)
            spill.remove()

    out = Spill(Path(folder) / f"voxels-{slab:06d}.spill", template)
    low, high = np.full(3, np.inf), np.full(3, -np.inf)
    slab_folder.mkdir(parents=True, exist_ok=True)
    expected = sum(len(Spill(slab_folder / f"piece-{piece:06d}.spill", template, with_index=True)) for piece in range(pieces))
    for cloud in reduce_voxels(stream(), grid, template, mode, state_bytes, slab_folder, points, key_range,
                               expected_points=expected):
        if len(cloud):
            cloud_low, cloud_high = corners(cloud.points)
            low, high = np.minimum(low, cloud_low), np.maximum(high, cloud_high)
        out.append(cloud)
    return len(out), low, high
