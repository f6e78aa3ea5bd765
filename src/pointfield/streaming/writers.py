"""Writing a cloud a chunk at a time, atomically: the file appears whole or not at all.

``open_writer(path)`` returns a :class:`ChunkWriter` for the format ``path``'s suffix names::

    with open_writer("out.laz", bounds=(low, high)) as writer:
        for chunk in chunks:
            writer.write(chunk)

Everything goes to a temporary file beside ``path`` that is renamed onto it when the ``with``
block ends without an exception; an exception (a killed job's KeyboardInterrupt included)
removes it, and ``path`` is left as it was. Each format's chunk writer lives in its own package,
registered beside its whole-file writer (:mod:`pointfield.clouds.formats.chunked`); this module
asks the registry for it. The bytes are those :func:`pointfield.write` would write for the
concatenated chunks, by the format's own writer code: each writer takes the layout (fields,
types, LAS point format and extra dimensions) from the first chunk and holds every later chunk
to it. One exception: a LAS / LAZ file of more than ``LasChunkWriter.WINDOW`` points with extra
dimensions, whose extra-bytes min / max (laspy's statistics, which depend on how points are
split between its calls) can differ.

===========================  ================================================================
format                       how it streams
===========================  ================================================================
LAS, LAZ                     laspy's writer, chunk by chunk (LAZ compressed as it goes). The
                             scales and offsets depend on the bounds of all the points: pass
                             ``bounds`` when known, else the chunks are parked on disk until
                             the end, which gives the bounds, then written (:class:`BoundsFirst`)
PLY (all encodings), PCD     the records go to a body file; the header, which states the
(ascii, binary), NPY         point count, is written at the end and the body copied after it
``.bin``                     records appended as they come
anything else, PCD           collected in memory and written whole at the end, with a
``binary_compressed``        :class:`~pointfield.streaming.StreamingFallback` warning
===========================  ================================================================
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np

from pointfield.clouds.arrays import finite_corners
from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.formats import format_of, write
from pointfield.clouds.formats.chunked import Bounds, ChunkWriter, concatenate
from pointfield.errors import FormatError
from pointfield.streaming.chunks import StreamingFallback
from pointfield.streaming.spill import Spill

__all__ = ["BoundsFirst", "ChunkWriter", "WholeWriter", "open_writer"]


class BoundsFirst(ChunkWriter):
    """A writer that needs the bounds of all the points before the first (LAS): the chunks are
    parked in a spill on disk, and at :meth:`close`, when their bounds are known, the format's
    writer ``kind`` writes them into this writer's temporary file.

    The first chunk is kept in memory, as every writer keeps it (its ``template``), and handed
    over first, so that the format's writer decides its layout on the same chunk it would have
    without the spill.
    """

    WINDOW = 1 << 20

    def __init__(self, path: str | os.PathLike[str], encoding: str | None, kind: type[ChunkWriter]):
        super().__init__(path, encoding)
        self.kind = kind

    def _begin(self, cloud: PointCloud) -> None:
        self.spill = Spill(self.tmp.with_name(self.tmp.name + ".spill"), cloud)
        self.low = np.full(3, np.inf)
        self.high = np.full(3, -np.inf)

    def _write(self, cloud: PointCloud) -> None:
        low, high, _ = finite_corners(cloud.points)
        self.low, self.high = np.minimum(self.low, low), np.maximum(self.high, high)
        if cloud is not self.template:
            self.spill.append(cloud)

    def _finish(self) -> None:
        bounds = (self.low, self.high) if np.all(self.low <= self.high) else (self.low, self.low)
        writer = self.kind(self.path, self.encoding, bounds, into=self.tmp)
        try:
            writer.write(self.template)
            for chunk, _ in self.spill.chunks(self.WINDOW):
                writer.write(chunk)
            writer.close()
        except BaseException as error:
            writer.abort(error)
            raise
        self.spill.remove()

    def _cleanup(self) -> None:
        if getattr(self, "spill", None) is not None:
            self.spill.remove()


class WholeWriter(ChunkWriter):
    """A format (or encoding) that cannot be written in chunks: collected, then written whole."""

    streams = False

    def __init__(self, path: str | os.PathLike[str], encoding: str | None = None, bounds: Bounds | None = None):
        super().__init__(path, encoding, bounds)
        warnings.warn(
            f"{self.path}: {self.format.name} {self.encoding or ''} cannot be written in chunks; "
            "the points are collected in memory and written whole",
            StreamingFallback,
            stacklevel=3,
        )
        self.chunks: list[PointCloud] = []

    def _write(self, cloud: PointCloud) -> None:
        self.chunks.append(cloud)

    def _finish(self) -> None:
        cloud = concatenate(self.chunks)
        self.chunks.clear()
        write(self.tmp, cloud, format=self.format.name, encoding=self.encoding)


def open_writer(
    path: str | os.PathLike[str], encoding: str | None = None, *, bounds: Bounds | None = None
) -> ChunkWriter:
    """A chunk writer for ``path`` (format from its suffix; ``encoding`` as :func:`pointfield.write`).

    ``bounds`` ``(min, max)`` of the finite points to come lets LAS / LAZ write as the chunks
    arrive; other formats ignore it.
    """
    path = Path(path)
    fmt = format_of(path, for_writing=True)
    if fmt.write is None:
        raise FormatError(path, f"pointfield reads {fmt.name} but cannot write it")
    resolved = fmt.resolve_encoding(encoding, path)
    kind = fmt.chunk_writer(resolved) if fmt.chunk_writer is not None else None
    if kind is None:
        return WholeWriter(path, encoding, bounds)
    if kind.needs_bounds and bounds is None:
        return BoundsFirst(path, encoding, kind)
    return kind(path, encoding, bounds)
