"""Keeping part of every chunk, in this process or on Dask: what ``downsample --every/--random``,
``crop``, ``merge`` and ``convert`` have in common.

A *rule* is a picklable callable ``rule(chunk, index) -> PointCloud`` (a ``functools.partial``
of a module-level function) that returns what to keep of a chunk; ``index`` holds the points'
positions in their file. :func:`select_to_file` applies it to every chunk of one or more
sources and writes the result, in order, to one file.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.formats.las import coordinates_fit
from pointfield.streaming import distributed
from pointfield.streaming.chunks import ChunkSource, open_source
from pointfield.streaming.jobs import Job, indexed_chunks, progress_bar, scratch_folder
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
    if any(h is None for h in hints):
        return None
    low = np.min([h[0] for h in hints], axis=0)
    high = np.max([h[1] for h in hints], axis=0)
    if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high))):
        return None
    return (low, high) if coordinates_fit(low, high, sources[0].metadata) else None


def select_to_file(job: Job, out: Path, rule: Rule | Sequence[Rule], encoding: str | None, what: str) -> int:
    """Write what ``rule`` keeps of every chunk of ``job``'s sources (in order) to ``out``.

    ``rule`` is one rule for every source, or a sequence of one per source. In this process chunk
    by chunk; on Dask, pieces of the files in parallel into spills, then the spills in order into
    ``out``. Returns the points written.
    """
    rules = list(rule) if isinstance(rule, (list, tuple)) else [rule] * len(job.sources)
    bounds = writer_bounds(job.sources)
    template = rules[0](job.template, np.zeros(0, np.int64))
    if job.client is None:
        if bounds is None and len(job.sources) == 1 and job.source.count <= job.points:
            # One chunk (a scan of a folder): its own bounds, rather than a spill, for LAS.
            whole = job.source.read(0, job.source.count)
            kept = rules[0](whole, np.arange(len(whole), dtype=np.int64))
            with open_writer(out, encoding, bounds=kept.bounds() if len(kept) else None) as writer:
                writer.write(kept)
                return writer.count
        with open_writer(out, encoding, bounds=bounds) as writer:
            writer.write(template)
            for source, source_rule in zip(job.sources, rules, strict=True):
                with progress_bar(source.count, f"{what} {source.path.name}", job.progress) as bar:
                    for chunk, index in indexed_chunks(source, job.points, bar=bar):
                        writer.write(source_rule(chunk, index))
            return writer.count
    with scratch_folder(out, job.scratch) as folder:
        calls = []
        for source, source_rule in zip(job.sources, rules, strict=True):
            # One file is cut into pieces for the workers; many files are a task each.
            ranges = job.pieces(source) if len(job.sources) == 1 else distributed.piece_ranges(source.count, 1)
            for start, stop in ranges:
                spill = str(folder / f"piece-{len(calls):06d}.spill")
                calls.append((str(source.path), job.options, start, stop, job.points, source_rule, spill))
        with progress_bar(len(calls), f"{what} (pieces)", job.progress, "piece") as bar:
            distributed.run_tasks(job.client, select_task, calls, bar)
        with open_writer(out, encoding, bounds=bounds) as writer:
            writer.write(template)
            for call in calls:
                for chunk, _ in Spill(call[-1], template).chunks(job.points):
                    writer.write(chunk)
            return writer.count


def select_task(path: str, options: dict[str, Any], start: int, stop: int, points: int, rule: Rule,
                spill_path: str) -> int:
    """Apply ``rule`` to each chunk of a piece, appending what it keeps to a spill."""
    source = open_source(path, **options)
    spill = None
    for chunk, index in indexed_chunks(source, points, start, stop):
        kept = rule(chunk, index)
        if spill is None:
            spill = Spill(spill_path, kept)
        spill.append(kept)
    return 0 if spill is None else len(spill)
