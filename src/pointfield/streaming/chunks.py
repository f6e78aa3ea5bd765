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

A file cut short is refused when it is opened, before anything is written from it: the error
names the file and the point where its data ends. A LAZ chunk that fails to decompress is a
:class:`~pointfield.FormatError` naming the file and the points of the failing window.
"""

from __future__ import annotations

import os
import struct
import warnings
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import laspy
import numpy as np
from laspy.copc import Bounds, CopcReader, load_octree_for_query

from pointfield.clouds.cloud import PointCloud, Records
from pointfield.clouds.formats import format_of, read
from pointfield.clouds.formats.binary import record_dtype
from pointfield.clouds.formats.las.layout import check_layout, check_laz
from pointfield.clouds.formats.las.library import library_errors
from pointfield.clouds.formats.las.reader import _metadata, cloud_parts
from pointfield.clouds.formats.npy import cloud_from_array, read_array_header
from pointfield.clouds.formats.pcd.header import MAX_HEADER_BYTES as PCD_HEADER_LIMIT
from pointfield.clouds.formats.pcd.header import parse_header as parse_pcd_header
from pointfield.clouds.formats.pcd.reader import _assemble as assemble_pcd
from pointfield.clouds.formats.ply.header import BYTE_ORDERS, HEADER_LIMIT, parse_header
from pointfield.clouds.formats.ply.reader import _assemble as assemble_ply
from pointfield.clouds.formats.ply.reader import _empty_columns
from pointfield.clouds.formats.velodyne import (
    RECORD_DTYPE,
    cloud_from_records,
    guess_columns,
    read_velodyne,
)
from pointfield.errors import FormatError, PointfieldError

DEFAULT_CHUNK_POINTS = 1 << 20


class StreamingFallback(UserWarning):
    """A file that cannot be read (or written) in windows is read (or written) whole."""


class ChunkSource:
    """One file opened for windows of points (see the module docstring).

    ``count`` is the number of points stored (NaN points included), ``metadata`` what
    :func:`pointfield.read` puts in ``cloud.metadata``, ``streams`` False for files read whole,
    and ``aligned`` the window size a reader seeks to cheaply (a LAZ chunk), 1 otherwise.
    """

    path: Path
    count: int
    metadata: dict[str, Any]
    streams = True
    aligned = 1

    def read(self, start: int, stop: int) -> PointCloud:
        """The cloud of points ``start .. stop - 1``."""
        raise NotImplementedError

    def chunks(
        self, points: int = DEFAULT_CHUNK_POINTS, start: int = 0, stop: int | None = None
    ) -> Iterator[PointCloud]:
        """Windows of ``points`` points from ``start`` up to ``stop`` (default: the end)."""
        stop = self.count if stop is None else min(stop, self.count)
        for low in range(start, stop, points):
            yield self.read(low, min(low + points, stop))

    def bounds_hint(self) -> tuple[np.ndarray, np.ndarray] | None:
        """``(min, max)`` of the points as the file's header states them, or None.

        A hint, not a fact: headers can be stale. Callers that need exact bounds check it.
        """
        return None

    def __repr__(self) -> str:
        return f"{type(self).__name__}({str(self.path)!r}, {self.count} points)"


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
    query = bounds is not None or level is not None or resolution is not None
    if columns is not None and fmt.name != "velodyne":
        raise PointfieldError(f"{path}: columns= applies to raw .bin scans, not {fmt.name} files")
    if fmt.name == "las":
        source: ChunkSource = LasSource(path)
        if query:
            if not source.metadata.get("las_copc"):
                raise PointfieldError(
                    f"{path}: bounds, level and resolution query a COPC file's octree; this "
                    "LAS file has none"
                )
            source = CopcSource(path, bounds, level, resolution)
        return source
    if query:
        raise PointfieldError(f"{path}: bounds, level and resolution apply to COPC files only")
    opener = _RECORD_SOURCES.get(fmt.name)
    source = opener(path, columns) if opener is not None else None
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


def concatenate(clouds: list[PointCloud], metadata: dict[str, Any] | None = None) -> PointCloud:
    """One cloud of the points and fields of ``clouds``, in order (metadata of the first)."""
    if not clouds:
        raise ValueError("nothing to concatenate")
    first = clouds[0]
    return PointCloud(
        np.concatenate([c.points for c in clouds]),
        {name: np.concatenate([c.fields[name] for c in clouds]) for name in first.fields},
        None,
        dict(first.metadata if metadata is None else metadata),
    )


# ---------------------------------------------------------------------------------------------
# LAS, LAZ, COPC


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


# ---------------------------------------------------------------------------------------------
# Fixed-size records: PLY binary, PCD binary, .bin, NPY


class RecordSource(ChunkSource):
    """``count`` records of ``dtype`` at byte ``offset``, read with ``pread`` and turned into
    clouds by ``convert`` (the format's own records-to-cloud code)."""

    def __init__(
        self,
        path: Path,
        dtype: np.dtype,
        offset: int,
        count: int,
        convert: Callable[[np.ndarray], PointCloud | Records],
        format_name: str,
        what: str = "point",
    ):
        self.path, self.dtype, self.offset, self.count = path, dtype, offset, count
        self.convert, self.format_name = convert, format_name
        size = path.stat().st_size
        whole = (size - offset) // dtype.itemsize if size > offset else 0
        if whole < count:
            inside = size - offset - whole * dtype.itemsize
            where = (
                f"{what} {whole:,} of {count:,} is cut short {inside} bytes into its "
                f"{dtype.itemsize}-byte record"
                if inside
                else f"only {whole:,} of its {count:,} {what}s are present"
            )
            raise FormatError(path, f"the file ends at byte {size:,}: {where}")
        self.metadata = dict(self._convert(np.zeros(0, dtype)).metadata)

    def read(self, start: int, stop: int) -> PointCloud:
        size = self.dtype.itemsize
        with open(self.path, "rb") as file:
            data = os.pread(file.fileno(), (stop - start) * size, self.offset + start * size)
        return self._convert(np.frombuffer(data, self.dtype))

    def chunks(
        self, points: int = DEFAULT_CHUNK_POINTS, start: int = 0, stop: int | None = None
    ) -> Iterator[PointCloud]:
        stop = self.count if stop is None else min(stop, self.count)
        size = self.dtype.itemsize
        with open(self.path, "rb") as file:
            for low in range(start, stop, points):
                high = min(low + points, stop)
                data = os.pread(file.fileno(), (high - low) * size, self.offset + low * size)
                yield self._convert(np.frombuffer(data, self.dtype))

    def _convert(self, records: np.ndarray) -> PointCloud:
        cloud = self.convert(records)
        if not isinstance(cloud, PointCloud):
            raise PointfieldError(f"{self.path}: its records have no x, y, z; there is nothing to stream")
        cloud.metadata["format"] = self.format_name
        return cloud


def _ply_source(path: Path, columns: int | None) -> RecordSource | None:
    with open(path, "rb") as file:
        header = parse_header(path, file.read(HEADER_LIMIT))
    if header.encoding == "ascii":
        return None
    offset = header.data_offset
    vertex = None
    for element in header.elements:
        if any(prop.is_list for prop in element.properties) and element.count:
            return None
        if element.name == "vertex":
            vertex = element
        elif element.count:
            # Faces or other elements: a mesh; read whole so that nothing is lost.
            return None
        if vertex is None:
            offset += element.count * sum(p.dtype.itemsize for p in element.properties)
    if vertex is None or any(prop.is_list for prop in vertex.properties):
        return None
    dtype = record_dtype([(p.name, p.dtype) for p in vertex.properties], BYTE_ORDERS[header.encoding])
    native = dtype.newbyteorder("=")
    # The other elements are all empty: read_ply's columns for them.
    empty = {element.name: _empty_columns(element) for element in header.elements if element.name != "vertex"}

    def convert(records: np.ndarray) -> PointCloud | Records:
        records = records if records.dtype == native else records.astype(native)
        return assemble_ply(path, header, {"vertex": {name: records[name] for name in native.names}, **empty})

    return RecordSource(path, dtype, offset, vertex.count, convert, "ply", "vertex")


def _pcd_source(path: Path, columns: int | None) -> RecordSource | None:
    with open(path, "rb") as file:
        header = parse_pcd_header(file.read(PCD_HEADER_LIMIT), path)
    if header.encoding != "binary":
        return None
    fields, offsets = [], []
    offset = 0
    for f in header.fields:
        if not f.is_padding:
            if f.is_packed_color:
                fields.append((f.name, np.dtype("u1"), (4,)))
            else:
                fields.append((f.name, f.dtype, () if f.count == 1 else (f.count,)))
            offsets.append(offset)
        offset += f.nbytes
    dtype = record_dtype(fields, "<", offsets, header.point_size)

    def convert(records: np.ndarray) -> PointCloud | Records:
        window = replace(header, width=len(records), height=1, points=len(records))
        return assemble_pcd({name: records[name] for name, *_ in fields}, window, path)

    return RecordSource(path, dtype, header.data_offset, header.points, convert, "pcd")


def _velodyne_source(path: Path, columns: int | None) -> RecordSource:
    columns = guess_columns(path) if columns is None else columns  # 4 or 5, as pointfield.read guesses
    size = path.stat().st_size
    record = RECORD_DTYPE.itemsize * columns if isinstance(columns, int) and columns >= 3 else 0
    if not record or size == 0 or size % record:
        read_velodyne(path, columns)  # raises the reader's own error for this file
    dtype = np.dtype((RECORD_DTYPE, columns))

    def convert(records: np.ndarray) -> PointCloud:
        return cloud_from_records(records.reshape(-1, columns))

    return RecordSource(path, dtype, 0, size // record, convert, "velodyne")


def _npy_source(path: Path, columns: int | None) -> RecordSource | None:
    with open(path, "rb") as file:
        header = read_array_header(file, path)
    if header.fortran_order and len(header.shape) > 1:
        return None
    structured = header.dtype.names is not None
    if structured and len(header.shape) in (1, 2):
        count, dtype = header.count, header.dtype
    elif not structured and len(header.shape) in (2, 3) and header.shape[-1] >= 3:
        count = header.count // header.shape[-1]
        dtype = np.dtype((header.dtype, (header.shape[-1],)))
    else:
        return None

    def convert(records: np.ndarray) -> PointCloud | Records:
        cloud = cloud_from_array(records, path, "the array")
        cloud.metadata["encoding"] = "binary"
        return cloud

    return RecordSource(path, dtype, header.size, count, convert, "npy", "record")


_RECORD_SOURCES: dict[str, Callable[[Path, int | None], RecordSource | None]] = {
    "ply": _ply_source,
    "pcd": _pcd_source,
    "velodyne": _velodyne_source,
    "npy": _npy_source,
}


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
