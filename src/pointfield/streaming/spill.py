"""Spills: chunks of points parked on disk in the order they came, read back a window at a time.

A spill is one file of fixed-size records, ``points`` (3,) then every field (its dtype and
per-point shape) then, when asked for, ``index``: the point's position in the input it came
from. The record layout comes from a template chunk; every later chunk must have the same
fields. Appending is a plain write at the end of the file, so a spill costs disk bandwidth
only, and reading it back in windows bounds the memory of whatever consumes it.

Spills carry the points of one tile or one voxel range from the pass that sorts a stream into
tiles to the pass that reduces each tile, within one process or between Dask workers that
share a filesystem.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.errors import PointfieldError

INDEX = "__index__"


def spill_dtype(template: PointCloud, with_index: bool = False) -> np.dtype:
    """The record of one point of ``template``'s layout (see the module docstring)."""
    layout: list[tuple[Any, ...]] = [("__points__", template.points.dtype, (3,))]
    for name, values in template.fields.items():
        if values.dtype.hasobject:
            raise PointfieldError(
                f"field {name!r} holds Python objects (lists of varying length): it cannot be "
                "streamed; read the file whole instead"
            )
        layout.append((name, values.dtype.newbyteorder("="), values.shape[1:]))
    if with_index:
        layout.append((INDEX, np.int64))
    return np.dtype(layout)


def to_records(cloud: PointCloud, dtype: np.dtype, index: np.ndarray | None = None) -> np.ndarray:
    """``cloud`` (and ``index``) as records of ``dtype``."""
    records = np.empty(len(cloud), dtype)
    records["__points__"] = cloud.points
    for name in dtype.names[1:]:
        if name == INDEX:
            records[INDEX] = index
        else:
            records[name] = cloud.fields[name]
    return records


def from_records(
    records: np.ndarray, metadata: dict[str, Any]
) -> tuple[PointCloud, np.ndarray | None]:
    """The cloud (and its index, when the records carry one) in ``records``; arrays are copies."""
    names = records.dtype.names
    fields = {name: np.ascontiguousarray(records[name]) for name in names[1:] if name != INDEX}
    index = np.ascontiguousarray(records[INDEX]) if INDEX in names else None
    cloud = PointCloud(np.ascontiguousarray(records["__points__"]), fields, None, dict(metadata))
    return cloud, index


class Spill:
    """Chunks of one layout appended to one file; read back in order (module docstring).

    Example::

        spill = Spill(folder / "tile-3.spill", template, with_index=True)
        spill.append(chunk, index)
        for cloud, index in spill.chunks(1 << 20):
            ...
        spill.remove()
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        template: PointCloud,
        with_index: bool = False,
        dtype: np.dtype | None = None,
    ):
        self.path = Path(path)
        self.metadata = dict(template.metadata)
        self.dtype = dtype if dtype is not None else spill_dtype(template, with_index)
        self.count = self.path.stat().st_size // self.dtype.itemsize if self.path.exists() else 0

    def __len__(self) -> int:
        return self.count

    def append(self, cloud: PointCloud, index: np.ndarray | None = None) -> None:
        if len(cloud) == 0:
            return
        self.append_records(to_records(cloud, self.dtype, index))

    def append_records(self, records: np.ndarray) -> None:
        with open(self.path, "ab") as file:
            records.tofile(file)
        self.count += len(records)

    def records(self, points: int) -> Iterator[np.ndarray]:
        """The records in windows of at most ``points``."""
        size = self.dtype.itemsize
        if not self.path.exists():
            return
        with open(self.path, "rb") as file:
            while True:
                data = file.read(points * size)
                if not data:
                    return
                yield np.frombuffer(data, self.dtype)

    def chunks(self, points: int) -> Iterator[tuple[PointCloud, np.ndarray | None]]:
        """``(cloud, index)`` windows of at most ``points``, in the order they were appended."""
        for records in self.records(points):
            yield from_records(records, self.metadata)

    def remove(self) -> None:
        self.path.unlink(missing_ok=True)
