"""Keeping part of every chunk, in this process or on Dask: what ``downsample --every/--random``,
``crop``, ``merge`` and ``convert`` have in common.

A *rule* is a picklable callable ``rule(chunk, index) -> PointCloud`` (a ``functools.partial``
of a module-level function) that returns what to keep of a chunk; ``index`` holds the points'
positions in their file. :func:`select_to_file` applies it to every chunk of one or more
sources and writes the result, in order, to one file.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.formats.las.writer import _in_int32, _three_floats
from pointfield.streaming import distributed
from pointfield.streaming.chunks import ChunkSource
from pointfield.streaming.jobs import (
    indexed_chunks,
    progress_bar,
    scratch_folder,
    template_of,
)
from pointfield.streaming.spill import Spill
from pointfield.streaming.writers import open_writer

Rule = Callable[[PointCloud, np.ndarray], PointCloud]


def keep_all(cloud: PointCloud, index: np.ndarray) -> PointCloud:
    return cloud


def writer_bounds(sources: list[ChunkSource]) -> tuple[np.ndarray, np.ndarray] | None:
    """Bounds that let a LAS writer start at once without changing what it writes.

    The sources' header bounds, when the first source's LAS scales and offsets span them: any
    subset of those points then gets the same scales and offsets the LAS writer would choose
    from its own bounds. Otherwise None: the writer waits for the points' own bounds.
    """
    hints = [source.bounds_hint() for source in sources]
    metadata = sources[0].metadata
    scales, offsets = _three_floats(metadata.get("scales")), _three_floats(metadata.get("offsets"))
    if any(h is None for h in hints) or scales is None or offsets is None or not np.all(scales > 0):
        return None
    low = np.min([h[0] for h in hints], axis=0)
    high = np.max([h[1] for h in hints], axis=0)
    if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high))):
        return None
    return (low, high) if _in_int32(low, high, scales, offsets) else None


def select_to_file(
    sources: list[tuple[ChunkSource, dict[str, Any]]],
    out: Path,
    rule: Rule,
    encoding: str | None,
    points: int,
    client: Any,
    scratch: str | os.PathLike[str] | None,
    progress: bool,
    what: str,
) -> int:
    """Write what ``rule`` keeps of every chunk of ``sources`` (in order) to ``out``.

    ``sources`` pairs each source with the options it was opened with (for workers to open it
    again). In this process chunk by chunk; on Dask, pieces of the files in parallel into
    spills, then the spills in order into ``out``. Returns the points written.
    """
    bounds = writer_bounds([source for source, _ in sources])
    first = template_of(sources[0][0])
    if client is None:
        if bounds is None and len(sources) == 1 and sources[0][0].count <= points:
            # One chunk (a scan of a folder): its own bounds, rather than a spill, for LAS.
            whole = sources[0][0].read(0, sources[0][0].count)
            kept = rule(whole, np.arange(len(whole), dtype=np.int64))
            with open_writer(out, encoding, bounds=kept.bounds() if len(kept) else None) as writer:
                writer.write(kept)
                return writer.count
        with open_writer(out, encoding, bounds=bounds) as writer:
            writer.write(rule(first, np.zeros(0, np.int64)))
            for source, _ in sources:
                with progress_bar(source.count, f"{what} {source.path.name}", progress) as bar:
                    for chunk, index in indexed_chunks(source, points, bar=bar):
                        writer.write(rule(chunk, index))
            return writer.count
    per_file = distributed.PIECES_PER_WORKER * distributed.worker_count(client)
    with scratch_folder(out, scratch) as folder:
        calls = []
        for source, options in sources:
            for start, stop in distributed.piece_ranges(source.count, per_file if len(sources) == 1 else 1, source.aligned):
                spill = str(folder / f"piece-{len(calls):06d}.spill")
                calls.append((str(source.path), options, start, stop, points, rule, spill))
        with progress_bar(len(calls), f"{what} (pieces)", progress, "piece") as bar:
            distributed.run_tasks(client, distributed.select_task, calls, bar)
        template = rule(first, np.zeros(0, np.int64))
        with open_writer(out, encoding, bounds=bounds) as writer:
            writer.write(template)
            for call in calls:
                for chunk, _ in Spill(call[-1], template).chunks(points):
                    writer.write(chunk)
            return writer.count
