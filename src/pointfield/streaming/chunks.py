"""Reading a cloud a window of points at a time: :func:`read_chunks` and the sources behind it.

A *source* is one file opened for windows of points: ``source.read(start, stop)`` is the cloud
of points ``start .. stop - 1``, with every field and the metadata :func:`pointfield.read`
gives, and ``source.chunks(points)`` walks the file in windows of ``points``. Concatenated,
the windows are exactly what :func:`pointfield.read` returns (organised clouds lose their grid
shape, as :meth:`PointCloud.select` does).

=================================  ==========================================================
format                             how it streams
=================================  ==========================================================
LAS, LAZ                           laspy's reader, window by window (LAZ: lazrs decompresses
                                   only the chunks a window needs; a window starting at a
                                   multiple of the LAZ chunk size seeks straight to it)
COPC                               as LAZ; with ``bounds`` / ``level`` / ``resolution``, the
                                   octree nodes the query needs, a group of nodes per window
PLY binary, PCD binary, ``.bin``,  fixed-size records read with ``pread`` from their offset:
NPY                                nothing mapped, so resident memory is the window's
everything else                    read whole, then handed out in windows, with a
                                   :class:`StreamingFallback` warning saying so
=================================  ==========================================================

Each format's chunk reader lives in its own package, registered beside its whole-file reader
(:mod:`pointfield.clouds.formats.chunked`); this module asks the registry for it.

A file cut short is refused when it is opened, before anything is written from it: the error
names the file and the point where its data ends. A LAZ chunk that fails to decompress is a
:class:`~pointfield.FormatError` naming the file and the points of the failing window.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.formats import format_of, formats, read
from pointfield.clouds.formats.chunked import DEFAULT_CHUNK_POINTS, ChunkSource, concatenate
from pointfield.errors import PointfieldError

__all__ = [
    "DEFAULT_CHUNK_POINTS",
    "ChunkSource",
    "StreamingFallback",
    "WholeSource",
    "concatenate",
    "open_source",
    "read_chunks",
]


class StreamingFallback(UserWarning):
    """A file that cannot be read (or written) in windows is read (or written) whole."""


def open_source(
    path: str | os.PathLike[str],
    *,
    columns: int | None = None,
    bounds: Any = None,
    level: int | range | None = None,
    resolution: float | None = None,
) -> ChunkSource:
    """Open ``path`` for reading in windows, with the source its format allows.

    ``columns`` is the values per point of a raw ``.bin`` scan; ``bounds`` (``(xmin, ymin,
    xmax, ymax)`` or ``(xmin, ymin, zmin, xmax, ymax, zmax)``), ``level`` (an octree depth or a
    range of them) and ``resolution`` query a COPC file's octree.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    fmt = format_of(path)
    given = {"columns": columns, "bounds": bounds, "level": level, "resolution": resolution}
    options = {name: value for name, value in given.items() if value is not None}
    foreign = sorted(set(options) - set(fmt.chunk_options))
    if foreign:
        owners = sorted(f.name for f in formats() if set(foreign) & set(f.chunk_options))
        raise PointfieldError(
            f"{path}: {', '.join(foreign)} apply to {' and '.join(owners)} files, not {fmt.name} files"
        )
    source = fmt.open_chunks(path, **options) if fmt.open_chunks is not None else None
    return WholeSource(path, fmt.name, columns) if source is None else source


def read_chunks(
    path: str | os.PathLike[str],
    points: int = DEFAULT_CHUNK_POINTS,
    *,
    columns: int | None = None,
    bounds: Any = None,
    level: int | range | None = None,
    resolution: float | None = None,
) -> Iterator[PointCloud]:
    """Yield the cloud in ``path`` as PointClouds of at most ``points`` points, every field kept.

    Example::

        for chunk in pointfield.read_chunks("city.laz", points=1_000_000):
            print(len(chunk), chunk.fields["classification"].max())

    Concatenated, the chunks hold exactly the points and fields :func:`pointfield.read` returns.
    Options are those of :func:`open_source` (``columns`` for ``.bin``; ``bounds``, ``level``,
    ``resolution`` for COPC spatial and level-of-detail queries).
    """
    if points < 1:
        raise ValueError(f"points must be at least 1, got {points}")
    source = open_source(path, columns=columns, bounds=bounds, level=level, resolution=resolution)
    yield from source.chunks(points)


class WholeSource(ChunkSource):
    """A file whose format cannot be read in windows: read whole, handed out in windows."""

    streams = False

    def __init__(self, path: Path, format_name: str, columns: int | None):
        warnings.warn(
            f"{path}: {format_name} files cannot be read in chunks here; it is read whole",
            StreamingFallback,
            stacklevel=3,
        )
        options = {"columns": columns} if columns is not None else {}
        cloud = read(path, **options)
        if not isinstance(cloud, PointCloud):
            raise PointfieldError(f"{path}: it holds records without x, y, z; there is nothing to stream")
        self.path = path
        self.cloud = cloud
        self.count = len(cloud)
        self.metadata = dict(cloud.metadata)

    def read(self, start: int, stop: int) -> PointCloud:
        return self.cloud.select(slice(start, stop))
