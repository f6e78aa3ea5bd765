"""``downsample``: fewer points, streamed with bounded memory, the in-memory result exactly.

Three rules, one per keyword:

- ``voxel=S``: one point per occupied cube of side S — the centroid (``mode="centroid"``,
  :func:`pointfield.clouds.ops.voxel_downsample`'s definition: floating-point fields averaged,
  others from the voxel's first point) or the point nearest the cube's centre
  (``mode="nearest"``, every field of that point). See :mod:`pointfield.streaming.voxels` for
  why the chunked result equals the in-memory one bit for bit.
- ``random=N``: N points drawn uniformly without replacement (seeded), kept in file order
  (:func:`random_sample` is the in-memory reference).
- ``every=K``: points 0, K, 2K, ... of the file.

Memory: ``memory`` (``"2G"``) bounds the resident size of the job; chunks and the voxel state
share it, and voxel state beyond its share waits on disk (:func:`~.voxels.reduce_voxels`).
"""

from __future__ import annotations

import itertools
import os
import tempfile
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.errors import PointfieldError
from pointfield.streaming import distributed
from pointfield.streaming.arrays import finite_corners
from pointfield.streaming.chunks import ChunkSource, open_source
from pointfield.streaming.jobs import (
    bytes_per_point,
    finite_bounds,
    indexed_chunks,
    output_done,
    progress_bar,
    scratch_folder,
    summary,
    template_of,
)
from pointfield.streaming.memory import DEFAULT_MEMORY, plan
from pointfield.streaming.select import select_to_file, writer_bounds
from pointfield.streaming.spill import Spill
from pointfield.streaming.voxels import MODES, VoxelGrid, reduce_voxels
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
    options = {"columns": columns} if columns is not None else {}
    src = open_source(source, **options)
    template = template_of(src)
    budget = plan(memory, bytes_per_point(template), points)
    with distributed.cluster(workers, scheduler, client) as dask_client:
        if voxel is not None:
            if not voxel > 0:
                raise PointfieldError(f"voxel must be positive, got {voxel}")
            written = _voxel(src, options, template, Path(out), float(voxel), mode, encoding, budget,
                             dask_client, scratch, progress)
        else:
            select = _every_rule(every) if every is not None else _random_rule(src.count, random, seed)
            written = select_to_file([(src, options)], Path(out), select, encoding, budget.chunk_points,
                                     dask_client, scratch, progress, "downsample")
    return summary(source=source, out=out, input_points=src.count, output_points=written, skipped=False)


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


def _voxel(
    src: ChunkSource,
    options: dict[str, Any],
    template: PointCloud,
    out: Path,
    size: float,
    mode: str,
    encoding: str | None,
    budget: Any,
    client: Any,
    scratch: Any,
    progress: bool,
) -> int:
    name = src.path.name
    if client is not None:
        return _voxel_on_dask(src, options, template, out, size, mode, encoding, budget, client, scratch, progress)
    with scratch_folder(out, scratch) as folder:
        hint = src.bounds_hint()
        if hint is not None and np.all(np.isfinite(hint)) and np.all(hint[0] <= hint[1]):
            # One pass with the header's bounds as the grid, checked against the points as they
            # stream; a stale header costs a second pass, never a wrong result.
            try:
                return _voxel_pass(src, VoxelGrid.covering(*hint, size), hint[1], template, out, mode,
                                   encoding, budget, folder, progress)
            except _GridMismatch:
                pass
        with progress_bar(src.count, f"bounds {name}", progress) as bar:
            low, high, finite = finite_bounds(src, budget.chunk_points, bar)
        if finite == 0:
            raise PointfieldError(f"{src.path}: no finite points to downsample")
        return _voxel_pass(src, VoxelGrid.covering(low, high, size), None, template, out, mode,
                           encoding, budget, folder, progress)


def _voxel_pass(src, grid, box_high, template, out, mode, encoding, budget, folder, progress) -> int:
    """One pass. With ``box_high``, the grid is provisional, built on the header's box
    ``[grid.origin, box_high]``: every point must lie in that box (then every cell lies in the
    grid), and the smallest must turn out to be the origin itself; else _GridMismatch."""
    provisional = box_high is not None

    def stream():
        low = np.full(3, np.inf)
        with progress_bar(src.count, f"downsample {src.path.name}", progress) as bar:
            for chunk, index in indexed_chunks(src, budget.chunk_points, bar=bar):
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
    voxels = reduce_voxels(stream(), grid, template, mode, budget.state_bytes, work, budget.chunk_points,
                           expected_points=src.count)
    first = next(voxels, None)  # the whole input is read before the first voxel comes out
    with open_writer(out, encoding, bounds=writer_bounds([src])) as writer:
        writer.write(first if first is not None else template)
        for cloud in voxels:
            writer.write(cloud)
        return writer.count


def _voxel_on_dask(src, options, template, out, size, mode, encoding, budget, client, scratch, progress) -> int:
    pieces = distributed.piece_ranges(src.count, distributed.PIECES_PER_WORKER * distributed.worker_count(client), src.aligned)
    path = str(src.path)
    points = budget.chunk_points
    with progress_bar(len(pieces), f"bounds {src.path.name}", progress, "piece") as bar:
        results = distributed.run_tasks(client, distributed.bounds_task, [(path, options, a, b, points) for a, b in pieces], bar)
    low = np.min([r[0] for r in results], axis=0) if results else np.full(3, np.inf)
    high = np.max([r[1] for r in results], axis=0) if results else np.full(3, -np.inf)
    if sum(r[2] for r in results) == 0:
        raise PointfieldError(f"{src.path}: no finite points to downsample")
    grid = VoxelGrid.covering(low, high, size)
    slabs = max(1, min(grid.shape[0], len(pieces)))
    firsts = np.unique((np.arange(slabs) * grid.shape[0]) // slabs)
    edges = [*firsts.tolist(), grid.shape[0]]
    key_ranges = [grid.x_range(a, b) for a, b in itertools.pairwise(edges)]
    key_ranges[-1] = (key_ranges[-1][0], 2**62)
    cuts = np.array([r[0] for r in key_ranges], np.int64)
    with scratch_folder(out, scratch) as folder:
        calls = [(path, options, a, b, points, grid, cuts, str(folder), n) for n, (a, b) in enumerate(pieces)]
        with progress_bar(len(calls), f"tiles {src.path.name}", progress, "piece") as bar:
            distributed.run_tasks(client, distributed.scatter_task, calls, bar)
        calls = [(grid, template, mode, budget.state_bytes, str(folder), n, len(pieces), points, key_ranges[n])
                 for n in range(len(key_ranges))]
        with progress_bar(len(calls), f"voxels {src.path.name}", progress, "slab") as bar:
            reduced = distributed.run_tasks(client, distributed.reduce_task, calls, bar)
        bounds = writer_bounds([src])
        if bounds is None and any(r[0] for r in reduced):
            bounds = (np.min([r[1] for r in reduced if r[0]], axis=0), np.max([r[2] for r in reduced if r[0]], axis=0))
        with open_writer(out, encoding, bounds=bounds) as writer:
            writer.write(template)
            for n in range(len(key_ranges)):
                for cloud, _ in Spill(folder / f"voxels-{n:06d}.spill", template).chunks(points):
                    writer.write(cloud)
            return writer.count
