"""Writing a cloud a chunk at a time, atomically: the file appears whole or not at all.

``open_writer(path)`` returns a :class:`ChunkWriter` for the format ``path``'s suffix names::

    with open_writer("out.laz", bounds=(low, high)) as writer:
        for chunk in chunks:
            writer.write(chunk)

Everything goes to a temporary file beside ``path`` that is renamed onto it when the ``with``
block ends without an exception; an exception (a killed job's KeyboardInterrupt included)
removes it, and ``path`` is left as it was. The bytes are those :func:`pointfield.write` would
write for the concatenated chunks, by the format's own writer code: each writer takes the
layout (fields, types, LAS point format and extra dimensions) from the first chunk and holds
every later chunk to it. One exception: a LAS / LAZ file of more than
:attr:`LasChunkWriter.WINDOW` points with extra dimensions, whose extra-bytes min / max (laspy's
statistics, which depend on how points are split between its calls) can differ.

===========================  ================================================================
format                       how it streams
===========================  ================================================================
LAS, LAZ                     laspy's writer, chunk by chunk (LAZ compressed as it goes). The
                             scales and offsets depend on the bounds of all the points: pass
                             ``bounds`` when known, else the chunks are parked on disk until
                             the end, which gives the bounds, then written
PLY (all encodings), PCD     the records go to a body file; the header, which states the
(ascii, binary), NPY         point count, is written at the end and the body copied after it
``.bin``                     records appended as they come
anything else, PCD           collected in memory and written whole at the end, with a
``binary_compressed``        :class:`~pointfield.streaming.StreamingFallback` warning
===========================  ================================================================
"""

from __future__ import annotations

import contextlib
import io
import os
import shutil
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any, BinaryIO, Self

import laspy
import numpy as np

from pointfield.atomic import atomic_path
from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.formats import format_of, write
from pointfield.clouds.formats.las.dimensions import (
    version_for,
)
from pointfield.clouds.formats.las.library import library_errors
from pointfield.clouds.formats.las.writer import (
    _apply_header_metadata,
    _in_int32,
    _records,
    _scales_and_offsets,
    las_dimensions,
)
from pointfield.clouds.formats.npy import write_npy
from pointfield.clouds.formats.pcd.header import BANNER
from pointfield.clouds.formats.pcd.writer import (
    _columns_to_write,
    _field_for,
    _number_text,
    _viewpoint_to_write,
    _write_ascii,
    _write_binary,
)
from pointfield.clouds.formats.ply.header import BYTE_ORDERS, ENCODINGS
from pointfield.clouds.formats.ply.writer import (
    _column_to_write,
    _header_text,
    _out_element,
    _OutElement,
    _ply_columns,
    _write_binary_element,
    _write_text_element,
)
from pointfield.clouds.formats.velodyne import write_velodyne
from pointfield.errors import FormatError
from pointfield.streaming.arrays import corners, finite_rows
from pointfield.streaming.chunks import StreamingFallback, concatenate
from pointfield.streaming.spill import Spill

Bounds = tuple[np.ndarray, np.ndarray]


class ChunkWriter:
    """Writes chunks into a temporary file renamed onto ``path`` at :meth:`close`.

    Subclasses write the first chunk's layout in :meth:`_begin`, each chunk in :meth:`_write`
    and whatever follows the points in :meth:`_finish`. ``count`` is the points written so far.
    """

    streams = True

    def __init__(self, path: str | os.PathLike[str], encoding: str | None = None, bounds: Bounds | None = None):
        self.path = Path(path)
        self.format = format_of(self.path, for_writing=True)
        self.encoding = self.format.resolve_encoding(encoding, self.path)
        self.bounds = bounds
        self.count = 0
        self.template: PointCloud | None = None
        self._notes: dict[str, type[Warning]] = {}
        self._stack = contextlib.ExitStack()
        self.tmp = self._stack.enter_context(atomic_path(self.path))
        self._closed = False

    def write(self, cloud: PointCloud) -> None:
        """Append the points of ``cloud`` (same fields as the first chunk)."""
        if self._closed:
            raise ValueError(f"{self.path}: the writer is closed")
        with self._collect_warnings():
            if self.template is None:
                self.template = cloud
                self._begin(cloud)
            elif cloud.fields.keys() != self.template.fields.keys():
                raise FormatError(
                    self.path,
                    f"a chunk has fields {sorted(cloud.fields)}; the first had "
                    f"{sorted(self.template.fields)}",
                )
            self._write(cloud)
        self.count += len(cloud)

    def close(self) -> None:
        """Finish the file and rename it into place."""
        if self._closed:
            return
        try:
            with self._collect_warnings():
                if self.template is None:
                    raise FormatError(self.path, "nothing was written: the stream had no chunks")
                self._finish()
        except BaseException as error:
            self.abort(error)
            raise
        self._closed = True
        self._stack.close()
        for message, category in self._notes.items():
            warnings.warn(message, category, stacklevel=2)

    def abort(self, error: BaseException | None = None) -> None:
        """Remove everything written; ``path`` stays as it was."""
        if self._closed:
            return
        self._closed = True
        self._cleanup()
        failure = error if error is not None else RuntimeError("aborted")
        self._stack.__exit__(type(failure), failure, failure.__traceback__)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, kind: object, error: BaseException | None, traceback: object) -> None:
        if error is None:
            self.close()
        else:
            self.abort(error)

    @contextlib.contextmanager
    def _collect_warnings(self):
        """Warnings of the format's writer, said once at the end rather than once per chunk."""
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            yield
        for warning in caught:
            self._notes.setdefault(str(warning.message), warning.category)

    def _begin(self, cloud: PointCloud) -> None:
        pass

    def _write(self, cloud: PointCloud) -> None:
        raise NotImplementedError

    def _finish(self) -> None:
        pass

    def _cleanup(self) -> None:
        pass


class _BodyFirst(ChunkWriter):
    """Formats whose header states the point count: the records go to a body file, and at the
    end the header is written and the body copied after it."""

    def _begin(self, cloud: PointCloud) -> None:
        self.body_path = self.tmp.with_name(self.tmp.name + ".body")
        self.body: BinaryIO = open(self.body_path, "wb")  # noqa: SIM115 -- open across write calls, closed in _finish

    def _finish(self) -> None:
        self.body.close()
        with open(self.tmp, "wb") as out:
            out.write(self._header())
            with open(self.body_path, "rb") as body:
                shutil.copyfileobj(body, out, 1 << 24)
            self._trailer(out)
        self.body_path.unlink()

    def _cleanup(self) -> None:
        body = getattr(self, "body", None)
        if body is not None:
            body.close()
            self.body_path.unlink(missing_ok=True)

    def _header(self) -> bytes:
        raise NotImplementedError

    def _trailer(self, out: BinaryIO) -> None:
        pass


class PlyChunkWriter(_BodyFirst):
    """PLY in any encoding, by the PLY writer's own column and record code."""

    def _begin(self, cloud: PointCloud) -> None:
        super()._begin(cloud)
        self.columns = self._columns(cloud)
        self.extra = [
            _out_element(self.path, str(name), {str(k): np.asarray(v) for k, v in columns.items()})
            for name, columns in (cloud.metadata.get("ply_elements") or {}).items()
        ]

    def _columns(self, cloud: PointCloud) -> list[Any]:
        columns = [
            _column_to_write(self.path, "vertex", name, values)
            for name, values in _ply_columns(self.path, "vertex", cloud.points, cloud.fields).items()
        ]
        for column in columns:
            if column.lengths is not None:
                raise FormatError(
                    self.path,
                    f"vertex property {column.name!r} holds lists of varying length, which "
                    "cannot be written in chunks",
                )
        return columns

    def _write(self, cloud: PointCloud) -> None:
        columns = self._columns(cloud) if cloud is not self.template else self.columns
        for column, first in zip(columns, self.columns, strict=True):
            if column.values.dtype != first.values.dtype:
                raise FormatError(
                    self.path,
                    f"vertex property {column.name!r} is {column.values.dtype} in a later chunk "
                    f"but {first.values.dtype} in the first",
                )
        element = _OutElement("vertex", len(cloud), columns)
        if self.encoding == "ascii":
            _write_text_element(self.body, element)
        else:
            _write_binary_element(self.body, element, BYTE_ORDERS[self.encoding])

    def _header(self) -> bytes:
        vertex = _OutElement("vertex", self.count, self.columns)
        return _header_text(self.encoding, [vertex, *self.extra], self.template.metadata)

    def _trailer(self, out: BinaryIO) -> None:
        for element in self.extra:
            if self.encoding == "ascii":
                _write_text_element(out, element)
            else:
                _write_binary_element(out, element, BYTE_ORDERS[self.encoding])


class PcdChunkWriter(_BodyFirst):
    """PCD ``binary`` and ``ascii``, by the PCD writer's own column and record code."""

    def _begin(self, cloud: PointCloud) -> None:
        super()._begin(cloud)
        self.columns = _columns_to_write(cloud, ascii_text=self.encoding == "ascii")
        if not self.columns:
            raise FormatError(self.path, "nothing to write: the records have no field PCD can hold")
        self.fields = [_field_for(name, values) for name, values in self.columns.items()]
        self.viewpoint = _viewpoint_to_write(cloud.metadata.get("viewpoint"), self.path)

    def _write(self, cloud: PointCloud) -> None:
        columns = _columns_to_write(cloud, ascii_text=self.encoding == "ascii")
        if [_field_for(n, v) for n, v in columns.items()] != self.fields:
            raise FormatError(self.path, "a later chunk's PCD fields differ from the first chunk's")
        if self.encoding == "ascii":
            _write_ascii(self.body, columns)
        else:
            _write_binary(self.body, columns, self.fields, len(cloud))

    def _header(self) -> bytes:
        # The header write_pcd writes, for an unorganised cloud of all the points.
        comments = self.template.metadata.get("comments", ())
        comments = [comments] if isinstance(comments, str) else comments
        lines = [BANNER]
        lines += [f"# {line}" for comment in comments for line in str(comment).splitlines()]
        lines += [
            "VERSION 0.7",
            "FIELDS " + " ".join(f.name for f in self.fields),
            "SIZE " + " ".join(str(f.size) for f in self.fields),
            "TYPE " + " ".join(f.type for f in self.fields),
            "COUNT " + " ".join(str(f.count) for f in self.fields),
            f"WIDTH {self.count}",
            "HEIGHT 1",
            "VIEWPOINT " + " ".join(_number_text(v) for v in self.viewpoint),
            f"POINTS {self.count}",
            f"DATA {self.encoding}",
        ]
        return ("\n".join(lines) + "\n").encode("utf-8")


class NpyChunkWriter(_BodyFirst):
    """A structured ``.npy``: the record layout :func:`write_npy` chooses, taken from the
    first chunk, then the records; the header (with the count) at the end."""

    def _begin(self, cloud: PointCloud) -> None:
        super()._begin(cloud)
        probe = self.tmp.with_name(self.tmp.name + ".layout.npy")
        try:
            write_npy(probe, cloud.select(slice(0, 0)))
            self.dtype = np.load(probe, allow_pickle=False).dtype
        finally:
            probe.unlink(missing_ok=True)

    def _write(self, cloud: PointCloud) -> None:
        records = np.empty(len(cloud), self.dtype)
        for i, axis in enumerate("xyz"):
            records[axis] = cloud.points[:, i]
        for name in self.dtype.names[3:]:
            records[name] = cloud.fields[name]
        records.tofile(self.body)

    def _header(self) -> bytes:
        header = np.lib.format.header_data_from_array_1_0(np.empty(0, self.dtype))
        header["shape"] = (self.count,)
        buffer = io.BytesIO()
        try:  # the version np.save picks: 1.0 unless the header is too long for it
            np.lib.format.write_array_header_1_0(buffer, header)
        except ValueError:
            buffer = io.BytesIO()
            np.lib.format.write_array_header_2_0(buffer, header)
        return buffer.getvalue()


class VelodyneChunkWriter(ChunkWriter):
    """Raw float32 scans: no header, the records of each chunk appended."""

    def _begin(self, cloud: PointCloud) -> None:
        self.file = open(self.tmp, "wb")  # noqa: SIM115 -- open across write calls, closed in _finish

    def _write(self, cloud: PointCloud) -> None:
        if len(cloud):
            write_velodyne(self.file, cloud)  # its records go to the open file's end

    def _finish(self) -> None:
        self.file.close()
        if self.count == 0:
            raise FormatError(
                self.path, "a float32 scan cannot hold zero points (an empty .bin reads as an error)"
            )

    def _cleanup(self) -> None:
        if hasattr(self, "file"):
            self.file.close()


class LasChunkWriter(ChunkWriter):
    """LAS and LAZ through laspy, with the LAS writer's own field-to-dimension code.

    The header (point format, extra dimensions, scales and offsets) is decided on the first
    chunk and the bounds of all the points; without ``bounds`` the chunks wait in a spill on
    disk until :meth:`close`. Points go to laspy in windows of ``WINDOW`` whatever the chunks
    are: laspy's statistics of extra-bytes dimensions depend on how the points are split
    between its calls, and fixed windows make the file the same for any chunking.
    """

    WINDOW = 1 << 20

    def _begin(self, cloud: PointCloud) -> None:
        self.dropped = 0
        self.pending: list[PointCloud] = []
        self.spill: Spill | None = None
        self.low = np.full(3, np.inf)
        self.high = np.full(3, -np.inf)
        if self.bounds is None:
            self.spill = Spill(self.tmp.with_name(self.tmp.name + ".spill"), cloud)
        else:
            self._open(cloud, self.bounds)

    def _write(self, cloud: PointCloud) -> None:
        finite = finite_rows(cloud.points)
        if finite is not None:
            self.dropped += int((~finite).sum())
            cloud = cloud.select(finite)
        if self.spill is not None:
            low, high = corners(cloud.points)
            self.low, self.high = np.minimum(self.low, low), np.maximum(self.high, high)
            self.spill.append(cloud)
            return
        self._buffer(cloud)

    def _buffer(self, cloud: PointCloud, flush: bool = False) -> None:
        if len(cloud):
            self.pending.append(cloud)
        waiting = sum(len(c) for c in self.pending)
        if waiting < self.WINDOW and not (flush and waiting):
            return
        points = concatenate(self.pending) if len(self.pending) > 1 else self.pending[0]
        self.pending = []
        full = len(points) if flush else len(points) // self.WINDOW * self.WINDOW
        for low in range(0, full, self.WINDOW):
            self._write_points(points.select(slice(low, min(low + self.WINDOW, full))))
        if full < len(points):
            self.pending = [points.select(slice(full, None))]

    def _open(self, template: PointCloud, bounds: Bounds) -> None:
        metadata = template.metadata
        # The header's layout; what the fields lose is warned about as each window is written.
        self.format_id, _, extra_params, _ = las_dimensions(template.fields, metadata, [])
        header = laspy.LasHeader(
            point_format=laspy.PointFormat(self.format_id),
            version=version_for(self.format_id, metadata),
        )
        with library_errors(self.path, "laspy could not write it"):
            if extra_params:
                header.add_extra_dims(extra_params)
            corners = np.array([np.asarray(bounds[0], np.float64), np.asarray(bounds[1], np.float64)])
            if not np.all(np.isfinite(corners)):
                corners = np.zeros((0, 3))
            header.scales, header.offsets = _scales_and_offsets(corners, metadata)
            self.evlrs = _apply_header_metadata(header, metadata)
            self.file = open(self.tmp, "wb")  # noqa: SIM115 -- open across write calls, closed in _finish
            self.writer = laspy.LasWriter(self.file, header, do_compress=self.encoding == "laz", closefd=False)
        self.header = header

    def _write_points(self, cloud: PointCloud) -> None:
        if len(cloud) and not _in_int32(*corners(cloud.points), self.header.scales, self.header.offsets):
            raise FormatError(
                self.path,
                "points lie outside the bounds the writer was given: their coordinates do not fit "
                "the LAS scales and offsets chosen from them",
            )
        notes: list[str] = []
        _, standard, _, extra_values = las_dimensions(cloud.fields, cloud.metadata, notes, self.format_id)
        if notes:
            warnings.warn("LAS changes these fields: " + "; ".join(notes), stacklevel=2)
        with library_errors(self.path, "laspy could not write it"):
            self.writer.write_points(_records(cloud.points, standard, extra_values, self.header))

    def _finish(self) -> None:
        if self.spill is not None:
            bounds = (self.low, self.high) if np.all(self.low <= self.high) else (self.low, self.low)
            self._open(self.template, bounds)
            for chunk, _ in self.spill.chunks(self.WINDOW):
                self._buffer(chunk)
            self.spill.remove()
        self._buffer(self.template.select(slice(0, 0)), flush=True)
        with library_errors(self.path, "laspy could not write it"):
            if self.evlrs:
                self.writer.write_evlrs(self.evlrs)
            self.writer.close()
            self.file.close()
        if self.dropped:
            warnings.warn(
                f"LAS cannot store NaN or infinite coordinates: {self.dropped} of "
                f"{self.count} points dropped",
                stacklevel=2,
            )

    def _cleanup(self) -> None:
        if getattr(self, "file", None) is not None:
            self.file.close()
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


_WRITERS: dict[str, Callable[[str | None], type[ChunkWriter] | None]] = {
    "las": lambda encoding: LasChunkWriter,
    "ply": lambda encoding: PlyChunkWriter if encoding in ENCODINGS else None,
    "pcd": lambda encoding: PcdChunkWriter if encoding in ("binary", "ascii") else None,
    "npy": lambda encoding: NpyChunkWriter,
    "velodyne": lambda encoding: VelodyneChunkWriter,
}


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
    chooser = _WRITERS.get(fmt.name)
    kind = chooser(resolved) if chooser is not None else None
    return (kind or WholeWriter)(path, encoding, bounds)
