"""``cloud info --stats``: what a file holds, computed in one streaming pass.

Counts (points stored, finite, with a NaN or infinite coordinate), the bounds of the finite
points, the number of points per class (the ``classification`` field, else ``label`` /
``labels`` / ``semantic``), and the range ``[min, max]`` of every numeric field (per component
for fields with several; NaN values ignored). Every figure is a count, a min or a max, so
partial results of pieces (Dask) combine exactly, in any order.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pointfield.clouds.arrays import finite_corners
from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.summary import format_and_encoding
from pointfield.streaming import distributed
from pointfield.streaming.chunks import open_source
from pointfield.streaming.jobs import indexed_chunks, progress_bar, streaming_job
from pointfield.streaming.memory import DEFAULT_MEMORY

CLASS_FIELDS = ("classification", "label", "labels", "semantic")


@dataclass
class Stats:
    """Running statistics of a stream of chunks; ``+`` combines two (see the module docstring)."""

    points: int = 0
    finite: int = 0
    low: np.ndarray = field(default_factory=lambda: np.full(3, np.inf))
    high: np.ndarray = field(default_factory=lambda: np.full(3, -np.inf))
    classes: dict[int, int] = field(default_factory=dict)
    ranges: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)

    def add(self, cloud: PointCloud) -> None:
        self.points += len(cloud)
        low, high, finite = finite_corners(cloud.points)
        self.finite += finite
        self.low, self.high = np.minimum(self.low, low), np.maximum(self.high, high)
        name = class_field(cloud)
        if name is not None:
            values, counts = np.unique(cloud.fields[name], return_counts=True)
            for value, count in zip(values.tolist(), counts.tolist(), strict=True):
                self.classes[int(value)] = self.classes.get(int(value), 0) + int(count)
        for name, values in cloud.fields.items():
            if values.dtype.kind not in "biuf" or len(values) == 0:
                continue
            flat = values.reshape(len(values), -1).astype(np.float64)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # an all-NaN column's range is NaN
                low, high = np.nanmin(flat, axis=0), np.nanmax(flat, axis=0)
            self._range(name, low, high)

    def _range(self, name: str, low: np.ndarray, high: np.ndarray) -> None:
        if name in self.ranges:
            old_low, old_high = self.ranges[name]
            low, high = np.fmin(old_low, low), np.fmax(old_high, high)
        self.ranges[name] = (low, high)

    def __add__(self, other: Stats) -> Stats:
        total = Stats(self.points + other.points, self.finite + other.finite,
                      np.minimum(self.low, other.low), np.maximum(self.high, other.high),
                      dict(self.classes), dict(self.ranges))
        for value, count in other.classes.items():
            total.classes[value] = total.classes.get(value, 0) + count
        for name, (low, high) in other.ranges.items():
            total._range(name, low, high)
        return total

    def as_dict(self) -> dict[str, Any]:
        def number(v: float) -> float | None:
            return float(v) if np.isfinite(v) else None

        def numbers(values: np.ndarray) -> float | None | list[float | None]:
            listed = [number(v) for v in values]
            return listed[0] if len(listed) == 1 else listed

        return {
            "points": self.points,
            "finite_points": self.finite,
            "nonfinite_points": self.points - self.finite,
            "bounds": {"min": self.low.tolist(), "max": self.high.tolist()} if self.finite else None,
            "classes": {str(k): v for k, v in sorted(self.classes.items())},
            "field_ranges": {n: {"min": numbers(lo), "max": numbers(hi)} for n, (lo, hi) in self.ranges.items()},
        }


def class_field(cloud: PointCloud) -> str | None:
    for name in CLASS_FIELDS:
        values = cloud.fields.get(name)
        if values is not None and values.ndim == 1 and values.dtype.kind in "biu":
            return name
    return None


def stats_task(path: str, options: dict[str, Any], start: int, stop: int, points: int) -> Stats:
    """The statistics of one piece of a file."""
    stats = Stats()
    for chunk, _ in indexed_chunks(open_source(path, **options), points, start, stop):
        stats.add(chunk)
    return stats


def stats(
    path: str | os.PathLike[str],
    *,
    memory: str | int = DEFAULT_MEMORY,
    points: int | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    client: Any = None,
    progress: bool = False,
    columns: int | None = None,
) -> dict[str, Any]:
    """Statistics of ``path`` in one streaming pass (module docstring), as a JSON-ready dict.

    Also ``path``, ``format``, ``encoding``, ``fields`` (name -> dtype), ``field_components``
    and ``class_field``, as ``cloud info`` reports them.
    """
    with streaming_job([path], columns=columns, memory=memory, points=points, workers=workers,
                       scheduler=scheduler, client=client, progress=progress) as job:
        source, template = job.source, job.template
        if job.client is None:
            total = Stats()
            with progress_bar(source.count, f"stats {source.path.name}", progress) as bar:
                for chunk, _ in indexed_chunks(source, job.points, bar=bar):
                    total.add(chunk)
        else:
            calls = [(str(source.path), job.options, a, b, job.points) for a, b in job.pieces(source)]
            with progress_bar(len(calls), f"stats {source.path.name}", progress, "piece") as bar:
                parts = distributed.run_tasks(job.client, stats_task, calls, bar)
            total = sum(parts, Stats())
    return {
        "path": str(path),
        "format": source.metadata.get("format"),
        "encoding": source.metadata.get("encoding"),
        "streamed": source.streams,
        "fields": {n: str(v.dtype) for n, v in template.fields.items()},
        "field_components": {n: int(np.prod(v.shape[1:], dtype=np.int64)) for n, v in template.fields.items()},
        "class_field": class_field(template),
        **total.as_dict(),
    }


def format_stats(info: dict[str, Any]) -> str:
    """``stats``' dict as aligned text, the way ``cloud info --stats`` prints it."""
    lines = [
        f"file        {info['path']}",
        f"format      {format_and_encoding(info['format'], info['encoding'])}",
        f"points      {info['points']:,} ({info['nonfinite_points']:,} with NaN or infinite coordinates)",
    ]
    bounds = info["bounds"]
    if bounds:
        lines.append("bounds      " + "  ".join(
            f"{axis} [{lo:.6g}, {hi:.6g}]" for axis, lo, hi in zip("xyz", bounds["min"], bounds["max"], strict=True)))
    if info["classes"]:
        lines.append(f"classes     ({info['class_field']})")
        lines += [f"  {value:>8}  {count:,}" for value, count in info["classes"].items()]
    if info["field_ranges"]:
        lines.append("fields      min .. max")
        width = max(len(name) for name in info["field_ranges"])
        for name, span in info["field_ranges"].items():
            lines.append(f"  {name:<{width}}  {info['fields'][name]:<8} {_span(span['min'])} .. {_span(span['max'])}")
    return "\n".join(lines)


def _span(value: Any) -> str:
    if isinstance(value, list):
        return "[" + ", ".join(_span(v) for v in value) + "]"
    return "nan" if value is None else f"{value:.6g}"
