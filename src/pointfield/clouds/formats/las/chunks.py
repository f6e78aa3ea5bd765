"""LAS, LAZ and COPC a window of points at a time: the chunk reader and writer of :mod:`pointfield.streaming`.

Reading goes through laspy window by window, with the records-to-fields code of :func:`read_las`:
uncompressed records are read with ``pread``; LAZ is decompressed by lazrs only for the chunks a
window needs (a window starting at a multiple of the LAZ chunk size seeks straight to it). A LAZ
file whose chunk table lies past its end is refused when it is opened, naming the point where
its data breaks, and a chunk that fails to decompress is a FormatError naming the window's
points. A COPC file queried by ``bounds`` / ``level`` / ``resolution`` reads the octree nodes
the query needs, a group of whole nodes per window.

Writing goes through laspy chunk by chunk, with the field-to-dimension code of :func:`write_las`
(LAZ compressed as it goes). The header's scales and offsets depend on the bounds of all the
points, so :class:`LasChunkWriter` needs them before the first point (``needs_bounds``);
:func:`pointfield.streaming.open_writer` parks the chunks on disk until it knows them when the
caller does not.
"""

from __future__ import annotations

import os
import struct
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import laspy
import numpy as np
from laspy.copc import Bounds, CopcReader, load_octree_for_query

from pointfield.clouds.arrays import corners, finite_rows
from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.formats.chunked import DEFAULT_CHUNK_POINTS, ChunkSource, ChunkWriter, concatenate
from pointfield.clouds.formats.las.dimensions import version_for
from pointfield.clouds.formats.las.layout import check_layout, check_laz
from pointfield.clouds.formats.las.library import library_errors
from pointfield.clouds.formats.las.reader import _metadata, cloud_parts
from pointfield.clouds.formats.las.writer import (
    _apply_header_metadata,
    _in_int32,
    _records,
    _scales_and_offsets,
    las_dimensions,
)
from pointfield.errors import FormatError, PointfieldError


def open_las_chunks(
    path: Path, bounds: Any = None, level: int | range | None = None, resolution: float | None = None
) -> ChunkSource:
    """A :class:`LasSource` for ``path``, or with ``bounds`` (``(xmin, ymin, xmax, ymax)`` or
    ``(xmin, ymin, zmin, xmax, ymax, zmax)``), ``level`` (an octree depth or a range of them) or
    ``resolution``, a :class:`CopcSource` of the COPC octree nodes the query needs."""
    source = LasSource(path)
    if bounds is None and level is None and resolution is None:
        return source
    if not source.metadata.get("las_copc"):
        raise PointfieldError(
            f"{path}: bounds, level and resolution query a COPC file's octree; this LAS file has none"
        )
    return CopcSource(path, bounds, level, resolution)


class LasSource(ChunkSource):
    """LAS and LAZ through laspy; the same records-to-fields code as :func:`read_las`."""

    def __init__(self, path: Path):
        self.path = path
        size = path.stat().st_size
        with open(path, "rb") as file:
            self.layout = check_layout(path, file, size)
            if self.layout.compressed:
                _check_laz_not_cut_short(path, file, self.layout.offset_to_points, self.layout.point_count, size)
                self.backend = check_laz(path, file, self.layout, size)
            with library_errors(path, "laspy could not read its header"):
                file.seek(0)
                self.header = laspy.LasReader(file, closefd=False, laz_backend=getattr(self, "backend", None)).header
        self.count = self.layout.point_count
        self.metadata = _metadata(self.header, self.layout)
        self.metadata["format"] = "las"
        if self.layout.compressed:
            chunk_size = _laz_chunk_size(self.layout.laszip_record)
            self.aligned = chunk_size or 1
        self.record = self.header.point_format.dtype()

    def bounds_hint(self) -> tuple[np.ndarray, np.ndarray]:
        return np.asarray(self.header.mins, np.float64), np.asarray(self.header.maxs, np.float64)

    def read(self, start: int, stop: int) -> PointCloud:
        return next(self.chunks(max(stop - start, 1), start, stop), self._empty())

    def chunks(
        self, points: int = DEFAULT_CHUNK_POINTS, start: int = 0, stop: int | None = None
    ) -> Iterator[PointCloud]:
        stop = self.count if stop is None else min(stop, self.count)
        if start >= stop:
            return
        if not self.layout.compressed:
            yield from self._uncompressed(points, start, stop)
            return
        with open(self.path, "rb") as file:
            with library_errors(self.path, "laspy could not open its points"):
                reader = laspy.LasReader(file, closefd=False, laz_backend=self.backend)
                if start:
                    reader.seek(start)
            low = start
            while low < stop:
                high = min(low + points, stop)
                with library_errors(
                    self.path, f"LAZ data is corrupt in points {low:,} to {high - 1:,}"
                ):
                    records = reader.read_points(high - low).array
                if len(records) < high - low:
                    raise FormatError(
                        self.path,
                        f"LAZ data ends at point {low + len(records):,} of {self.count:,}",
                    )
                yield self._cloud(records)
                low = high

    def _uncompressed(self, points: int, start: int, stop: int) -> Iterator[PointCloud]:
        size = self.record.itemsize
        if size != self.layout.record_length:
            raise FormatError(
                self.path,
                f"point record length {self.layout.record_length} does not match point format "
                f"{self.layout.point_format} with its extra bytes ({size} bytes)",
            )
        with open(self.path, "rb") as file:
            for low in range(start, stop, points):
                high = min(low + points, stop)
                data = os.pread(file.fileno(), (high - low) * size, self.layout.offset_to_points + low * size)
                yield self._cloud(np.frombuffer(data, self.record))

    def _cloud(self, records: np.ndarray) -> PointCloud:
        points, fields = cloud_parts(records, self.header, self.path)
        return PointCloud(points, fields, None, dict(self.metadata))

    def _empty(self) -> PointCloud:
        return self._cloud(np.zeros(0, self.record))


def _laz_chunk_size(laszip_record: bytes | None) -> int:
    """Points per LAZ chunk from the LASzip record (0 for variable-size chunks)."""
    if not laszip_record or len(laszip_record) < 16:
        return 0
    (chunk_size,) = struct.unpack_from("<I", laszip_record, 12)
    return 0 if chunk_size == 0xFFFFFFFF else int(chunk_size)


def _check_laz_not_cut_short(path: Path, file: Any, offset: int, count: int, size: int) -> None:
    """Refuse a LAZ file whose chunk table lies past its end: its data was cut short.

    LAZ keeps the table of its chunks at the end, so a cut-off file loses it first. The point
    where the data breaks is estimated from the share of compressed bytes still present (LAZ
    chunks hold equal numbers of points, so the estimate is close).
    """
    file.seek(offset)
    raw = file.read(8)
    if len(raw) < 8:
        raise FormatError(path, f"LAZ data is cut short: the file ends at byte {size:,}, before its points")
    (table,) = struct.unpack("<q", raw)
    if table == -1 or table + 8 <= size:
        return
    data_start = offset + 8
    share = (size - data_start) / max(table - data_start, 1)
    raise FormatError(
        path,
        f"LAZ data is cut short: the file ends at byte {size:,} but its chunk table starts at "
        f"byte {table:,}; it breaks around point {int(share * count):,} of {count:,} "
        f"({share:.0%} of its compressed points are present)",
    )


class CopcSource(ChunkSource):
    """A COPC octree query (bounds, level of detail), a group of octree nodes per window.

    ``count`` counts the points of the nodes the query touches; with ``bounds``, points of
    those nodes outside the bounds are dropped, so windows hold fewer points than they span.
    """

    def __init__(self, path: Path, bounds: Any, level: int | range | None, resolution: float | None):
        self.path = path
        with library_errors(path, "laspy could not read its COPC octree"), CopcReader.open(str(path)) as reader:
            header = reader.header
            if resolution is not None and level is not None:
                raise PointfieldError("give level or resolution, not both")
            if resolution is not None:
                levels = int(np.ceil(np.log2(reader.copc_info.spacing / resolution))) + 1
                level = range(max(1, levels))
            if isinstance(level, int):
                level = range(level, level + 1)
            self.bounds = None
            if bounds is not None:
                values = np.asarray(bounds, np.float64).reshape(-1)
                if len(values) not in (4, 6):
                    raise PointfieldError(f"bounds {bounds!r}: expected 4 or 6 numbers")
                half = len(values) // 2
                self.bounds = Bounds(values[:half], values[half:]).ensure_3d(header.mins, header.maxs)
            nodes = load_octree_for_query(
                reader.source, reader.copc_info, reader.root_page, self.bounds, level
            )
        self.nodes = sorted((n for n in nodes if n.point_count > 0), key=lambda n: n.offset)
        self.starts = np.cumsum([0] + [n.point_count for n in self.nodes])
        self.count = int(self.starts[-1])
        self.header = header
        self.metadata = LasSource(path).metadata

    def bounds_hint(self) -> tuple[np.ndarray, np.ndarray]:
        return np.asarray(self.header.mins, np.float64), np.asarray(self.header.maxs, np.float64)

    def read(self, start: int, stop: int) -> PointCloud:
        clouds = list(self._windows([(start, stop)]))
        return concatenate(clouds) if clouds else self._filter(None)

    def chunks(
        self, points: int = DEFAULT_CHUNK_POINTS, start: int = 0, stop: int | None = None
    ) -> Iterator[PointCloud]:
        """Windows of whole octree nodes, at most ``points`` points each unless one node is more."""
        stop = self.count if stop is None else min(stop, self.count)
        windows, low = [], start
        for end in self.starts[1:]:
            if end >= stop:
                break
            if end - low >= points:
                windows.append((low, int(end)))
                low = int(end)
        if low < stop:
            windows.append((low, stop))
        yield from self._windows(windows)

    def _windows(self, windows: list[tuple[int, int]]) -> Iterator[PointCloud]:
        with library_errors(self.path, "laspy could not read its COPC octree"):
            reader = CopcReader.open(str(self.path))
        with reader:
            for start, stop in windows:
                first = int(np.searchsorted(self.starts, start, side="right")) - 1
                last = int(np.searchsorted(self.starts, stop, side="left"))
                with library_errors(self.path, f"COPC data is corrupt in points {start:,} to {stop - 1:,}"):
                    records = reader._fetch_and_decompress_points_of_nodes(self.nodes[first:last])
                skip = start - int(self.starts[first])
                yield self._filter(records.array[skip : skip + stop - start])

    def _filter(self, records: np.ndarray | None) -> PointCloud:
        if records is None:
            records = np.zeros(0, self.header.point_format.dtype())
        if self.bounds is not None:
            low = np.round((self.bounds.mins - self.header.offsets) / self.header.scales)
            high = np.round((self.bounds.maxs - self.header.offsets) / self.header.scales)
            raw = np.stack([records["X"], records["Y"], records["Z"]], axis=1)
            records = records[np.all((raw >= low) & (raw <= high), axis=1)]
        points, fields = cloud_parts(records, self.header, self.path)
        return PointCloud(points, fields, None, dict(self.metadata))


class LasChunkWriter(ChunkWriter):
    """LAS and LAZ through laspy, with the LAS writer's own field-to-dimension code.

    The header (point format, extra dimensions, scales and offsets) is decided on the first
    chunk and ``bounds``, the bounds of all the points (``needs_bounds``). Points go to laspy in
    windows of ``WINDOW`` whatever the chunks are: laspy's statistics of extra-bytes dimensions
    depend on how the points are split between its calls, and fixed windows make the file the
    same for any chunking. NaN and infinite points are dropped, with one warning at the end.
    """

    WINDOW = 1 << 20
    needs_bounds = True

    def _begin(self, cloud: PointCloud) -> None:
        self.dropped = 0
        self.pending: list[PointCloud] = []
        metadata = cloud.metadata
        # The header's layout; what the fields lose is warned about as each window is written.
        self.format_id, _, extra_params, _ = las_dimensions(cloud.fields, metadata, [])
        header = laspy.LasHeader(
            point_format=laspy.PointFormat(self.format_id),
            version=version_for(self.format_id, metadata),
        )
        with library_errors(self.path, "laspy could not write it"):
            if extra_params:
                header.add_extra_dims(extra_params)
            ends = np.array([np.asarray(self.bounds[0], np.float64), np.asarray(self.bounds[1], np.float64)])
            if not np.all(np.isfinite(ends)):
                ends = np.zeros((0, 3))
            header.scales, header.offsets = _scales_and_offsets(ends, metadata)
            self.evlrs = _apply_header_metadata(header, metadata)
            self.file = open(self.tmp, "wb")  # noqa: SIM115 -- open across write calls, closed in _finish
            self.writer = laspy.LasWriter(self.file, header, do_compress=self.encoding == "laz", closefd=False)
        self.header = header

    def _write(self, cloud: PointCloud) -> None:
        finite = finite_rows(cloud.points)
        if finite is not None:
            self.dropped += int((~finite).sum())
            cloud = cloud.select(finite)
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


def las_chunk_writer(encoding: str | None) -> type[LasChunkWriter]:
    """LAS and LAZ both stream."""
    return LasChunkWriter
