"""``downsample``: fewer points, streamed with bounded memory, the in-memory result exactly.

Three rules, one per keyword:

- ``voxel=S``: one point per occupied cube of side S — the centroid (``mode="centroid"``,
  :func:`pointfield.clouds.ops.voxel_downsample`'s definition: floating-point fields averaged,
  others from the voxel's first point) or the point nearest the cube's centre
  (``mode="nearest"``, every field of that point). See :mod:`pointfield.streaming.voxels` for
  why the chunked result equals the in-memory one bit for bit.
- ``random=N``: N points drawn uniformly without replacement (seeded), kept in file order
  (:func:`random_sample` is the in-memory reference); N above the file's count keeps every point,
  with a warning.
- ``every=K``: points 0, K, 2K, ... of the file.

Memory: ``memory`` (``"2G"``) bounds the resident size of the job; chunks and the voxel state
share it, and voxel state beyond its share waits on disk (:func:`~.voxels.reduce_voxels`).
"""

from __future__ import annotations

import itertools
import os
import tempfile
import warnings
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from pointfield.clouds.arrays import corners, finite_corners
from pointfield.clouds.cloud import PointCloud
from pointfield.errors import PointfieldError
from pointfield.streaming import distributed
from pointfield.streaming.chunks import open_source
from pointfield.streaming.jobs import (
    Job,
    finite_bounds,
    indexed_chunks,
    output_done,
    progress_bar,
    scratch_folder,
    streaming_job,
    summary,
)
from pointfield.streaming.memory import DEFAULT_MEMORY
from pointfield.streaming.select import select_to_file, writer_bounds
from pointfield.streaming.spill import Spill
from pointfield.streaming.voxels import (
    KEY_END,
    MODES,
    VoxelGrid,
    drop_nonfinite,
    reduce_voxels,
)
from pointfield.streaming.writers import open_writer


def downsample(
    source: str | os.PathLike[str],
    out: str | os.PathLike[str],
    voxel: float | None = None,
    *,
    mode: str = "centroid",
    random: int | None = None,
    every: int | None = None,
    seed: int = 0,
    encoding: str | None = None,
    memory: str | int = DEFAULT_MEMORY,
    points: int | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    client: Any = None,
    scratch: str | os.PathLike[str] | None = None,
    overwrite: bool = False,
    progress: bool = False,
    columns: int | None = None,
) -> dict[str, Any]:
    """Downsample ``source`` into ``out`` by exactly one of ``voxel``, ``random``, ``every``.

    ``points`` fixes the chunk size (default: from ``memory``); ``workers`` / ``scheduler`` /
    ``client`` run it on Dask (:mod:`~pointfield.streaming.distributed`). Returns a summary
    (points in and out); an ``out`` that exists is skipped unless ``overwrite``.
    """
    rules = [name for name, value in (("voxel", voxel), ("random", random), ("every", every)) if value is not None]
    if len(rules) != 1:
        raise PointfieldError(f"give exactly one of voxel, random and every (got {rules or 'none'})")
    if mode not in MODES:
        raise PointfieldError(f"mode must be one of {MODES}, got {mode!r}")
    if output_done(out, overwrite):
        return summary(source=source, out=out, skipped=True)
    with streaming_job([source], columns=columns, memory=memory, points=points, workers=workers,
                       scheduler=scheduler, client=client, scratch=scratch, progress=progress) as job:
        if voxel is not None:
            if not voxel > 0:
                raise PointfieldError(f"voxel must be positive, got {voxel}")
            written = _voxel(job, Path(out), float(voxel), mode, encoding)
        else:
            if random is not None and random > job.source.count:
                warnings.warn(f"{source}: random={random:,} is more than its {job.source.count:,} points; "
                              f"all of them are kept", stacklevel=2)
            select = _every_rule(every) if every is not None else _random_rule(job.source.count, random, seed)
            written = select_to_file(job, Path(out), select, encoding, "downsample")
    return summary(source=source, out=out, input_points=job.source.count, output_points=written, skipped=False)


# ---------------------------------------------------------------------------------------------
# random and every: a rule per chunk


def keep_every(every: int, cloud: PointCloud, index: np.ndarray) -> PointCloud:
    return cloud.select(index % every == 0)


def keep_chosen(chosen: np.ndarray, cloud: PointCloud, index: np.ndarray) -> PointCloud:
    if len(index) == 0:
        return cloud
    low, high = np.searchsorted(chosen, [index[0], index[-1] + 1])
    return cloud.select(chosen[low:high] - index[0])


def random_sample(count: int, size: int, seed: int = 0) -> np.ndarray:
    """Sorted indices of ``size`` of ``count`` points, uniform without replacement (seeded).

    In memory, ``cloud.select(random_sample(len(cloud), n, seed))`` is ``random=n``'s result.
    """
    if size < 0:
        raise PointfieldError(f"random must be at least 0, got {size}")
    return np.sort(np.random.default_rng(seed).choice(count, size=min(size, count), replace=False))


def _every_rule(every: int) -> partial:
    if every < 1:
        raise PointfieldError(f"every must be at least 1, got {every}")
    return partial(keep_every, int(every))


def _random_rule(count: int, size: int, seed: int) -> partial:
    return partial(keep_chosen, random_sample(count, int(size), seed))


# ---------------------------------------------------------------------------------------------
# voxel


class _GridMismatch(Exception):
    """The header's bounds were not the points' own: the grid must start from the true minimum."""


def _voxel(job: Job, out: Path, size: float, mode: str, encoding: str | None) -> int:
    if job.client is not None:
        return _voxel_on_dask(job, out, size, mode, encoding)
    src = job.source
    with scratch_folder(out, job.scratch) as folder:
        hint = src.bounds_hint()
        if hint is not None and np.all(np.isfinite(hint)) and np.all(hint[0] <= hint[1]):
            # One pass with the header's bounds as the grid, checked against the points as they
            # stream; a stale header costs a second pass, never a wrong result.
            try:
                return _voxel_pass(job, VoxelGrid.covering(*hint, size), hint[1], out, mode, encoding, folder)
            except _GridMismatch:
                pass
        with progress_bar(src.count, f"bounds {src.path.name}", job.progress) as bar:
            low, high, finite = finite_bounds(src, job.points, bar)
        if finite == 0:
            raise PointfieldError(f"{src.path}: no finite points to downsample")
        return _voxel_pass(job, VoxelGrid.covering(low, high, size), None, out, mode, encoding, folder)


def _voxel_pass(job: Job, grid: VoxelGrid, box_high: np.ndarray | None, out: Path, mode: str,
                encoding: str | None, folder: Path) -> int:
    """One pass. With ``box_high``, the grid is provisional, built on the header's box
    ``[grid.origin, box_high]``: every point must lie in that box (then every cell lies in the
    grid), and the smallest must turn out to be the origin itself; else _GridMismatch."""
    src = job.source
    provisional = box_high is not None

    def stream():
        low = np.full(3, np.inf)
        with progress_bar(src.count, f"downsample {src.path.name}", job.progress) as bar:
            for chunk, index in indexed_chunks(src, job.points, bar=bar):
                if provisional and len(chunk):
                    chunk_low, chunk_high, finite = finite_corners(chunk.points)
                    if finite:
                        # Inside [origin, header max], every cell is inside the grid.
                        if np.any(chunk_low < grid.origin) or np.any(chunk_high > box_high):
                            raise _GridMismatch
                        low = np.minimum(low, chunk_low)
                yield chunk, index
        if provisional and not np.array_equal(low, grid.origin):
            raise _GridMismatch

    work = Path(tempfile.mkdtemp(prefix="pass-", dir=folder))  # a stale first pass leaves nothing here
    voxels = reduce_voxels(stream(), grid, job.template, mode, job.budget.state_bytes, work, job.points,
                           expected_points=src.count)
    first = next(voxels, None)  # the whole input is read before the first voxel comes out
    with open_writer(out, encoding, bounds=writer_bounds([src])) as writer:
        writer.write(first if first is not None else job.template)
        for cloud in voxels:
            writer.write(cloud)
        return writer.count


# ---------------------------------------------------------------------------------------------
# voxel, on Dask: bounds by piece, points scattered by piece into slabs of the grid, each slab
# reduced by one worker (distributed.py's module docstring)


def _voxel_on_dask(job: Job, out: Path, size: float, mode: str, encoding: str | None) -> int:
    src, points, template = job.source, job.points, job.template
    pieces = job.pieces(src)
    path = str(src.path)
    with progress_bar(len(pieces), f"bounds {src.path.name}", job.progress, "piece") as bar:
        results = distributed.run_tasks(job.client, bounds_task, [(path, job.options, a, b, points) for a, b in pieces], bar)
    low = np.min([r[0] for r in results], axis=0) if results else np.full(3, np.inf)
    high = np.max([r[1] for r in results], axis=0) if results else np.full(3, -np.inf)
    if sum(r[2] for r in results) == 0:
        raise PointfieldError(f"{src.path}: no finite points to downsample")
    grid = VoxelGrid.covering(low, high, size)
    slabs = max(1, min(grid.shape[0], len(pieces)))
    firsts = np.unique((np.arange(slabs) * grid.shape[0]) // slabs)
    edges = [*firsts.tolist(), grid.shape[0]]
    key_ranges = [grid.x_range(a, b) for a, b in itertools.pairwise(edges)]
    key_ranges[-1] = (key_ranges[-1][0], KEY_END)
    cuts = np.array([r[0] for r in key_ranges], np.int64)
    with scratch_folder(out, job.scratch) as folder:
        calls = [(path, job.options, a, b, points, grid, cuts, str(folder), n) for n, (a, b) in enumerate(pieces)]
        with progress_bar(len(calls), f"tiles {src.path.name}", job.progress, "piece") as bar:
            distributed.run_tasks(job.client, scatter_task, calls, bar)
        calls = [(grid, template, mode, job.budget.state_bytes, str(folder), n, len(pieces), points, key_ranges[n])
                 for n in range(len(key_ranges))]
        with progress_bar(len(calls), f"voxels {src.path.name}", job.progress, "slab") as bar:
            reduced = distributed.run_tasks(job.client, reduce_task, calls, bar)
        bounds = writer_bounds([src])
        if bounds is None and any(r[0] for r in reduced):
            bounds = (np.min([r[1] for r in reduced if r[0]], axis=0), np.max([r[2] for r in reduced if r[0]], axis=0))
        with open_writer(out, encoding, bounds=bounds) as writer:
            writer.write(template)
            for n in range(len(key_ranges)):
                for cloud, _ in Spill(folder / f"voxels-{n:06d}.spill", template).chunks(points):
                    writer.write(cloud)
            return writer.count


def bounds_task(path: str, options: dict[str, Any], start: int, stop: int, points: int) -> tuple[np.ndarray, np.ndarray, int]:
    """``(min, max, finite count)`` of the finite points of a piece."""
    return finite_bounds(open_source(path, **options), points, start=start, stop=stop)


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
        chunk, index = drop_nonfinite(chunk, index)
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

    def stream():
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
