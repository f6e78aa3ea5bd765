"""What every streaming verb shares: a :class:`Job` (its inputs opened, its memory planned, its
Dask client), outputs that are whole or absent, re-runs that skip them, a scratch folder that
disappears, progress bars, and walking a source with point indices.

Outputs are written through :func:`~pointfield.streaming.writers.open_writer` (a temporary
file renamed into place), so an output that exists is complete: a killed job leaves none
half-written, and a re-run skips the outputs already there (``overwrite=True`` redoes them).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import sys
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from pointfield.clouds.arrays import finite_corners
from pointfield.clouds.cloud import PointCloud
from pointfield.streaming import distributed
from pointfield.streaming.chunks import ChunkSource, open_source
from pointfield.streaming.memory import (
    DEFAULT_MEMORY,
    MemoryPlan,
    plan,
    returning_freed_arrays,
)
from pointfield.streaming.readahead import read_ahead


@dataclass(frozen=True)
class Job:
    """One run of a verb: its opened ``sources`` (with ``templates``, empty clouds of their
    layouts), the ``budget`` its chunks and state share, and ``client``, the Dask client it runs
    on (None: this process). ``options`` are those the sources were opened with, for workers
    to open them again."""

    sources: list[ChunkSource]
    templates: list[PointCloud]
    options: dict[str, Any]
    budget: MemoryPlan
    client: Any
    scratch: str | os.PathLike[str] | None
    progress: bool

    @property
    def source(self) -> ChunkSource:
        return self.sources[0]

    @property
    def template(self) -> PointCloud:
        return self.templates[0]

    @property
    def points(self) -> int:
        """Points per chunk."""
        return self.budget.chunk_points

    def pieces(self, source: ChunkSource) -> list[tuple[int, int]]:
        """``source`` cut into ranges of consecutive points, ``PIECES_PER_WORKER`` per worker."""
        pieces = distributed.PIECES_PER_WORKER * distributed.worker_count(self.client)
        return distributed.piece_ranges(source.count, pieces, source.aligned)


@contextlib.contextmanager
def streaming_job(
    paths: list[str | os.PathLike[str]],
    *,
    columns: int | None = None,
    memory: str | int = DEFAULT_MEMORY,
    points: int | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    client: Any = None,
    scratch: str | os.PathLike[str] | None = None,
    progress: bool = False,
) -> Iterator[Job]:
    """Open ``paths``, plan ``memory`` for the largest of their points, and run on the Dask
    cluster that ``workers`` / ``scheduler`` / ``client`` name (:func:`~.distributed.cluster`).

    A job holds its budget only if freed chunks leave the process, hence
    :func:`~.memory.returning_freed_arrays` around it.
    """
    with returning_freed_arrays():
        options = {"columns": columns} if columns is not None else {}
        sources = [open_source(path, **options) for path in paths]
        templates = [template_of(source) for source in sources]
        budget = plan(memory, max(bytes_per_point(t) for t in templates), points)
        with distributed.cluster(workers, scheduler, client) as dask_client:
            yield Job(sources, templates, options, budget, dask_client, scratch, progress)


def output_done(path: str | os.PathLike[str], overwrite: bool) -> bool:
    """True (and a note on stderr) when ``path`` exists and is not to be overwritten.

    Every output is renamed into place whole, so one that exists is complete.
    """
    path = Path(path)
    if overwrite or not path.exists():
        return False
    print(f"pointfield: {path} exists (complete); skipped — pass --overwrite to redo it", file=sys.stderr)
    return True


@contextlib.contextmanager
def scratch_folder(near: str | os.PathLike[str], scratch: str | os.PathLike[str] | None = None) -> Iterator[Path]:
    """A temporary folder for spills, removed afterwards whatever happens.

    Beside ``near`` (the output, on the same disk) unless ``scratch`` names a parent folder;
    with Dask workers on other machines it must be on storage they all see.
    """
    parent = Path(scratch) if scratch is not None else Path(near).resolve().parent
    parent.mkdir(parents=True, exist_ok=True)
    folder = Path(tempfile.mkdtemp(prefix=".pointfield-scratch-", dir=parent))
    try:
        yield folder
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def progress_bar(total: int | None, description: str, enabled: bool, unit: str = "pt") -> tqdm:
    """A tqdm bar on stderr (a no-op when ``enabled`` is False)."""
    return tqdm(
        total=total,
        desc=description,
        unit=unit,
        unit_scale=True,
        disable=not enabled,
        leave=False,
        file=sys.stderr,
        dynamic_ncols=True,
    )


def indexed_chunks(
    source: ChunkSource,
    points: int,
    start: int = 0,
    stop: int | None = None,
    bar: tqdm | None = None,
) -> Iterator[tuple[PointCloud, np.ndarray]]:
    """``(chunk, index)`` for each window of ``source``; ``index`` is each point's position in
    the file. The next window is read while the caller works on this one (:func:`read_ahead`)."""
    low = start
    for chunk in read_ahead(source.chunks(points, start, stop)):
        index = np.arange(low, low + len(chunk), dtype=np.int64)
        low += len(chunk)
        if bar is not None:
            bar.update(len(chunk))
        yield chunk, index


def template_of(source: ChunkSource) -> PointCloud:
    """An empty cloud with ``source``'s fields, dtypes and metadata."""
    return source.read(0, 0)


def bytes_per_point(template: PointCloud) -> int:
    """Bytes one point of ``template``'s layout takes in memory, with its file index."""
    size = template.points.dtype.itemsize * 3 + 8
    for values in template.fields.values():
        size += values.dtype.itemsize * int(np.prod(values.shape[1:], dtype=np.int64))
    return size


def finite_bounds(source: ChunkSource, points: int, bar: tqdm | None = None,
                  start: int = 0, stop: int | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """``(min, max, finite count)`` of the finite points of ``source`` in one pass."""
    low = np.full(3, np.inf)
    high = np.full(3, -np.inf)
    count = 0
    for chunk, _ in indexed_chunks(source, points, start, stop, bar):
        chunk_low, chunk_high, finite = finite_corners(chunk.points)
        low, high = np.minimum(low, chunk_low), np.maximum(high, chunk_high)
        count += finite
    return low, high, count


def summary(**values: Any) -> dict[str, Any]:
    """A verb's result: plain numbers and strings, printable as JSON."""
    return {k: (str(v) if isinstance(v, Path) else v) for k, v in values.items()}
