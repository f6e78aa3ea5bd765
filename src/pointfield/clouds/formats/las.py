"""ASPRS LAS / LAZ / COPC lidar files, through laspy (LAZ through its lazrs backend).

Reading
    ``points`` are the scaled coordinates ``x = X * scale + offset`` as float64 (UTM-sized
    coordinates do not survive float32). Every other dimension of the point format becomes a
    field under its laspy name and natural dtype: ``intensity`` uint16, bit fields such as
    ``return_number``, ``classification`` or ``synthetic`` as uint8, ``gps_time`` float64, extra
    bytes dimensions in their declared type (``(N, K)`` for K-element ones, float64 for scaled
    ones). ``red green blue`` become ``colors`` ``(N, 3)`` uint16; ``nir`` stays its own field.
    Extra dimensions ``nx ny nz`` become ``normals``, an extra ``alpha`` joins ``colors`` as
    ``(N, 4)``, and extra dimensions ``name[0] .. name[K-1]`` (how this writer stores ``(N, K)``
    fields with K > 3) become one ``(N, K)`` field ``name``.
    COPC files read as the LAZ files they are (``metadata["las_copc"]`` is True). Uncompressed
    files are memory-mapped and each dimension copied once into its own array, so reading holds
    the output arrays and little more.

Writing
    ``encoding`` is ``"las"`` or ``"laz"``; the registry picks ``"laz"`` for a ``.laz`` path. The point
    format is the one the cloud was read with (``metadata["las_point_format"]``) when it came
    from LAS, grown if new fields need more; otherwise the smallest standard format whose
    dimensions hold the cloud's LAS-named fields (``colors`` -> 2/3/7, ``gps_time`` -> 1/3/6/7,
    classification above 31 -> 6+, ...). Every other field becomes an extra bytes dimension of its
    own dtype: ``(N, 2)`` and ``(N, 3)`` fields as 2- and 3-element types, ``(N, K)`` uint8 as
    LAS's K-byte type, other wider ones as K scalar dimensions ``name[i]``, ``normals`` as
    ``nx ny nz``. Extra bytes have no bool, float16 or big-endian types: those come back as
    uint8, float32 and little-endian, with the same values.
    LAS quantises coordinates: ``X = round((x - offset) / scale)`` in int32. Scales and offsets
    come from the metadata of a LAS cloud; otherwise offset = the floored minimum corner and
    scale = 0.001 (a larger power of ten if the extent needs it), so a cloud from another format
    comes back within ``scale / 2`` of where it was, as float64. Points with NaN or infinite
    coordinates cannot be stored; they are dropped with a warning.
    Standard dimensions have fixed types. Values that fit are stored exactly and read back in the
    LAS type; colours of other dtypes are converted to uint16 (uint8 * 257, float in [0, 1] *
    65535), float ``intensity`` in [0, 1] is scaled by 65535, anything else that does not fit is
    rounded and clipped. One warning lists every such change.

Metadata (read, and used by the writer to write a LAS cloud back faithfully)
    ``scales``, ``offsets`` (3 floats each), ``las_version`` ("1.4"), ``las_point_format``
    (0..10), ``las_copc``, ``las_header`` (file_source_id, global_encoding, system_identifier,
    guid, creation_date, generating_software), ``las_extra_dimensions`` (name -> dtype, count,
    description, scales, offsets), and ``las_vlrs`` / ``las_evlrs``: every (extended) variable
    length record as ``{"user_id", "record_id", "description", "data": bytes}`` (CRS records
    included: GeoTIFF keys, WKT), except those the writer regenerates (LASzip, extra bytes) and
    the COPC index, which a re-written file no longer matches. The writer records itself as the
    generating software. Waveform data packets are not read.

Hostile files: the header's sizes, counts, VLR and EVLR lengths and, for LAZ, the chunk table are
checked against the file's size before laspy or lazrs allocate anything, and every laspy / lazrs
failure (including lazrs panics) becomes a :class:`FormatError` naming the file.
"""

from __future__ import annotations

import os
import struct
import warnings
from collections.abc import Callable, Iterator, Mapping
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import date
from functools import partial
from pathlib import Path
from typing import Any, BinaryIO
from uuid import UUID

import laspy
import lazrs
import numpy as np
from laspy.header import GlobalEncoding
from laspy.point import dims as laspy_dims
from laspy.vlrs.vlrlist import VLRList

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.formats.binary import check_size, map_file, read_records
from pointfield.clouds.formats.columns import (
    cloud_to_columns,
    columns_to_cloud_parts,
    group_components,
)
from pointfield.clouds.formats.registry import Format, register
from pointfield.errors import FormatError
from pointfield.version import __version__

SIGNATURE = b"LASF"

# Fixed part of every LAS header, up to the legacy point count (LAS 1.4 R15, table 3).
_HEADER_START = struct.Struct("<4sHH16sBB32s32sHHHIIBHI")
_HEADER_1_4_COUNTS = struct.Struct("<QIQ")  # start of first EVLR, EVLR count, point count
_HEADER_1_4_COUNTS_OFFSET = 235
_MIN_HEADER_SIZE = {0: 227, 1: 227, 2: 227, 3: 235, 4: 375}
_VLR_HEADER_SIZE = 54
_EVLR_HEADER_SIZE = 60
_LASZIP_USER_ID, _LASZIP_RECORD_ID = "laszip encoded", 22204
_LASZIP_KEY = (_LASZIP_USER_ID.encode(), _LASZIP_RECORD_ID)
_CHUNKED_COMPRESSORS = (2, 3)  # pointwise chunked, layered chunked: both carry a chunk table
_LAYERED_COMPRESSOR = 3
_LASZIP_ITEM_COUNT_OFFSET = 32
# Layers of each LAZ item type in layered chunks: Point14 9 (xy and returns, z, classification,
# flags, intensity, scan angle, user data, point source, gps time), RGB14 1, RGBNIR14 2,
# Wavepacket14 1; extra bytes (Byte14) have one layer per byte, i.e. as many as their size.
_LAYERS_PER_ITEM = {10: 9, 11: 1, 12: 2, 13: 1}

# A LAZ file whose header claims more points than this per compressed byte is decompressed in
# blocks, so that a lying header cannot make us allocate before the data runs out. Degenerate
# files (1M identical points) compress to about 150 points per byte; real scans to about 0.3.
_PLAUSIBLE_LAZ_POINTS_PER_BYTE = 256
_LAZ_BLOCK_POINTS = 1 << 20

# Records are turned into fields 65536 at a time (about 2 MB, an L2 cache), on up to this many
# threads.
_BLOCK_RECORDS = 1 << 16
_MAX_THREADS = 8

# Records that describe the encoding of the file itself rather than its data: the writer makes
# its own (LASzip, extra bytes), and a re-written file is not a COPC octree any more.
_REGENERATED_RECORDS = {(_LASZIP_USER_ID, _LASZIP_RECORD_ID), ("LASF_Spec", 4)}
_REGENERATED_USER_IDS = {"copc"}

_COORDINATES = ("X", "Y", "Z")
_COLOR_DIMENSIONS = ("red", "green", "blue")
_NAMES = {"normals": ("nx", "ny", "nz")}
_DEFAULT_SCALE = 0.001
_INT32_MAX = 2**31 - 1
_EXTRA_BYTES_DTYPES = {
    np.dtype(t) for t in ("u1", "i1", "u2", "i2", "u4", "i4", "u8", "i8", "f4", "f8")
}
_EXTRA_NAME_BYTES = 32
_DESCRIPTION_BYTES = 32
# Names an extra dimension cannot take: the raw coordinates, laspy's scaled ones and the packed
# bytes laspy keeps bit fields in.
_RESERVED_NAMES = {
    *_COORDINATES,
    "x",
    "y",
    "z",
    *laspy_dims.COMPOSED_FIELDS[0],
    *laspy_dims.COMPOSED_FIELDS[6],
}


def is_las(head: bytes) -> bool:
    """True for LAS, LAZ and COPC files: they all start with ``LASF``."""
    return head.startswith(SIGNATURE)


# ---------------------------------------------------------------------------------------------
# Reading
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Layout:
    """What the fixed header says about where things are, already checked against the file."""

    offset_to_points: int
    point_format: int
    record_length: int
    point_count: int
    compressed: bool
    laszip_record: bytes | None  # data of the LASzip VLR, which describes the compression


def read_las(path: Path) -> PointCloud:
    """Read a LAS, LAZ or COPC file into a PointCloud with float64 points (see module doc)."""
    path = Path(path)
    size = path.stat().st_size
    with open(path, "rb") as file:
        layout = _check_layout(path, file, size)
        backend = _check_laz(path, file, layout, size) if layout.compressed else None
        with _library_errors(path, "laspy could not read it"):
            file.seek(0)
            reader = laspy.LasReader(file, closefd=False, laz_backend=backend)
            header = reader.header
            if layout.compressed:
                records = _decompress(path, reader, layout, size)
            else:
                records = _map_records(path, file, header, layout)
    points, fields = _cloud_parts(records, header, path)
    # The fields are copies, so dropping the records releases the mapping of the file.
    del records
    return PointCloud(points, fields, None, _metadata(header, layout))


def _check_layout(path: Path, file: BinaryIO, size: int) -> _Layout:
    """Check the header's sizes and counts against the file before laspy reads anything."""
    head = file.read(_MIN_HEADER_SIZE[4])
    if not is_las(head):
        raise FormatError(path, f"not a LAS file: expected the signature {SIGNATURE!r}")
    if size < _MIN_HEADER_SIZE[0]:
        raise FormatError(
            path, f"truncated: {size} bytes, a LAS header alone needs {_MIN_HEADER_SIZE[0]}"
        )
    (
        _,
        _,
        _,
        _,
        major,
        minor,
        _,
        _,
        _,
        _,
        header_size,
        offset_to_points,
        vlr_count,
        format_byte,
        record_length,
        legacy_count,
    ) = _HEADER_START.unpack_from(head)
    if major != 1 or minor not in _MIN_HEADER_SIZE:
        raise FormatError(path, f"unsupported LAS version {major}.{minor}; expected 1.0 to 1.4")
    if size < _MIN_HEADER_SIZE[minor] or header_size < _MIN_HEADER_SIZE[minor]:
        raise FormatError(
            path,
            f"LAS {major}.{minor} header needs {_MIN_HEADER_SIZE[minor]} bytes; the header size "
            f"field says {header_size} and the file has {size}",
        )
    if not header_size <= offset_to_points <= size:
        raise FormatError(
            path,
            f"offset to point data {offset_to_points} lies outside the file "
            f"(header {header_size} bytes, file {size} bytes)",
        )
    vlrs = _walk_records(path, file, header_size, vlr_count, offset_to_points, extended=False)

    point_count, evlr_start, evlr_count = legacy_count, 0, 0
    if minor >= 4:
        evlr_start, evlr_count, point_count = _HEADER_1_4_COUNTS.unpack_from(
            head, _HEADER_1_4_COUNTS_OFFSET
        )
    if evlr_count:
        if evlr_start < offset_to_points:
            raise FormatError(path, f"EVLRs start at {evlr_start}, inside the header and VLRs")
        _walk_records(path, file, evlr_start, evlr_count, size, extended=True)

    compressed = bool(format_byte & 0x80) and not format_byte & 0x40  # as laspy decides
    point_format = format_byte & 0x3F
    if point_format > 10:
        raise FormatError(path, f"unknown point format {point_format}; expected 0 to 10")
    if record_length == 0 and point_count:
        raise FormatError(path, "point record length is 0")
    if not compressed:
        check_size(
            path, "header", point_count, record_length, size - offset_to_points, unit="points"
        )
    laszip_record = None
    if compressed:
        found = [(start, length) for key, start, length in vlrs if key == _LASZIP_KEY]
        if not found:
            raise FormatError(path, "compressed point format but no LASzip record (not a LAZ file)")
        file.seek(found[0][0])
        laszip_record = file.read(found[0][1])
    return _Layout(
        offset_to_points, point_format, record_length, point_count, compressed, laszip_record
    )


def _walk_records(
    path: Path, file: BinaryIO, start: int, count: int, end: int, *, extended: bool
) -> list[tuple[tuple[bytes, int], int, int]]:
    """Walk the (E)VLR headers from ``start``: every record must end by ``end``.

    laspy reads the declared number of records without looking for the end of the data, so a
    count of 4 billion would otherwise spin for hours. Returns ``((user_id, record_id), data
    offset, data length)`` of each record.
    """
    kind, header_size = ("EVLR", _EVLR_HEADER_SIZE) if extended else ("VLR", _VLR_HEADER_SIZE)
    if count * header_size > end - start:
        raise FormatError(
            path, f"header declares {count} {kind}s but only {end - start} bytes can hold them"
        )
    record_header = struct.Struct("<2x16sHQ" if extended else "<2x16sHH")
    records = []
    position = start
    for index in range(count):
        file.seek(position)
        user_id, record_id, length = record_header.unpack(file.read(record_header.size))
        records.append(((user_id.rstrip(b"\0"), record_id), position + header_size, length))
        position += header_size + length
        if position > end:
            raise FormatError(
                path, f"{kind} {index} ({length} bytes of data) runs past byte {end} of the file"
            )
    return records


def _check_laz(path: Path, file: BinaryIO, layout: _Layout, size: int) -> laspy.LazBackend:
    """Check the LAZ chunk table before lazrs sizes its buffers from it; pick the decompressor.

    lazrs reserves memory for the chunk count and the chunk point counts of the table, and for
    ``chunk_size * record size`` per chunk, and aborts the whole process when an allocation
    fails; so the table must agree with the file and with the header's point count. The
    parallel decompressor (laspy's default) is used when there are several chunks; a single
    chunk gains nothing from it, and its buffer would be sized by the declared chunk size.
    """
    record_data = layout.laszip_record
    if len(record_data) < _LASZIP_ITEM_COUNT_OFFSET + 2:
        raise FormatError(path, f"LASzip record is {len(record_data)} bytes, too short")
    (compressor,) = struct.unpack_from("<H", record_data)
    if compressor not in _CHUNKED_COMPRESSORS or layout.point_count == 0:
        return laspy.LazBackend.Lazrs  # no chunk table; lazrs reads such data point by point
    data_start = layout.offset_to_points + 8
    file.seek(layout.offset_to_points)
    raw = file.read(8)
    if len(raw) < 8:
        raise FormatError(path, "LAZ point data ends before its chunk table offset")
    (table_offset,) = struct.unpack("<q", raw)
    if table_offset == -1:  # written by a streaming writer: the offset sits at the end instead
        file.seek(size - 8)
        (table_offset,) = struct.unpack("<q", file.read(8))
    if not data_start <= table_offset <= size - 8:
        raise FormatError(
            path, f"LAZ chunk table offset {table_offset} lies outside the point data"
        )
    file.seek(table_offset)
    _, chunk_count = struct.unpack("<II", file.read(8))
    compressed_bytes = table_offset - data_start
    if not 0 < chunk_count <= compressed_bytes:
        raise FormatError(
            path,
            f"LAZ chunk table declares {chunk_count} chunks in {compressed_bytes} bytes of data",
        )
    with _library_errors(path, "lazrs could not read the LAZ chunk table"):
        vlr = lazrs.LazVlr(record_data)
        file.seek(layout.offset_to_points)
        chunks = lazrs.read_chunk_table(file, vlr)
        variable_chunks = vlr.uses_variable_size_chunks()
        chunk_size = vlr.chunk_size()
    chunk_bytes = sum(byte_count for _, byte_count in chunks)
    if any(byte_count <= 0 for _, byte_count in chunks) or chunk_bytes > compressed_bytes:
        raise FormatError(
            path,
            f"LAZ chunk table sizes add up to {chunk_bytes} bytes; the data has {compressed_bytes}",
        )
    count = layout.point_count
    if variable_chunks:
        listed = sum(point_count for point_count, _ in chunks)
        if listed != count:
            raise FormatError(path, f"header declares {count} points, the LAZ chunk table {listed}")
    elif not (len(chunks) - 1) * chunk_size < count <= len(chunks) * chunk_size:
        raise FormatError(
            path,
            f"header declares {count} points; {len(chunks)} LAZ chunks of {chunk_size} points "
            f"hold more than {(len(chunks) - 1) * chunk_size} and at most "
            f"{len(chunks) * chunk_size}",
        )
    if compressor == _LAYERED_COMPRESSOR:
        _check_layer_sizes(path, file, record_data, chunks, data_start)
    return laspy.LazBackend.LazrsParallel if len(chunks) > 1 else laspy.LazBackend.Lazrs


def _check_layer_sizes(
    path: Path, file: BinaryIO, record_data: bytes, chunks: list[tuple[int, int]], data_start: int
) -> None:
    """Check the layer sizes each chunk of a layered LAZ file (point formats 6-10) declares.

    A layered chunk is: the first point raw, a u32 point count, a u32 byte size for every layer
    of every item, then the layers. lazrs allocates each layer at its declared size, so one
    flipped bit there costs gigabytes and seconds; here the sizes must fit in their chunk.
    """
    (item_count,) = struct.unpack_from("<H", record_data, _LASZIP_ITEM_COUNT_OFFSET)
    items_end = _LASZIP_ITEM_COUNT_OFFSET + 2 + 6 * item_count
    if len(record_data) < items_end:
        raise FormatError(
            path, f"LASzip record lists {item_count} items but is {len(record_data)} bytes"
        )
    items = [
        struct.unpack_from("<HH", record_data, _LASZIP_ITEM_COUNT_OFFSET + 2 + 6 * index)
        for index in range(item_count)
    ]
    first_point_bytes = sum(size for _, size in items)
    layer_count = sum(_LAYERS_PER_ITEM.get(item_type, size) for item_type, size in items)
    chunk_header_bytes = first_point_bytes + 4 + 4 * layer_count
    position = data_start
    for index, (_, byte_count) in enumerate(chunks):
        if byte_count < chunk_header_bytes:
            raise FormatError(
                path,
                f"LAZ chunk {index} is {byte_count} bytes, less than its "
                f"{chunk_header_bytes}-byte header",
            )
        file.seek(position + first_point_bytes + 4)
        layer_bytes = sum(struct.unpack(f"<{layer_count}I", file.read(4 * layer_count)))
        if layer_bytes > byte_count - chunk_header_bytes:
            raise FormatError(
                path,
                f"LAZ chunk {index} declares {layer_bytes} bytes of layers in "
                f"{byte_count - chunk_header_bytes}",
            )
        position += byte_count


def _decompress(path: Path, reader: laspy.LasReader, layout: _Layout, size: int) -> np.ndarray:
    """All point records of a LAZ file as laspy's structured array.

    A plausible point count is decompressed into one buffer, as laspy does. A count the
    compressed bytes could only hold if the points were all alike is read in blocks instead,
    so that a lying header fails when the data runs out rather than after a huge allocation.
    """
    count = layout.point_count
    if count <= _PLAUSIBLE_LAZ_POINTS_PER_BYTE * (size - layout.offset_to_points):
        return reader.read_points(count).array
    blocks = []
    while count:
        block = reader.read_points(min(count, _LAZ_BLOCK_POINTS)).array
        if len(block) == 0:
            raise FormatError(path, f"LAZ data ended {count} points early")
        blocks.append(block)
        count -= len(block)
    return np.concatenate(blocks)


def _map_records(
    path: Path, file: BinaryIO, header: laspy.LasHeader, layout: _Layout
) -> np.ndarray:
    """The point records of an uncompressed file, memory-mapped instead of read.

    Mapping skips the copy from the page cache that reading would make; the fields are then
    copied out of the mapping once, straight into their final arrays.
    """
    dtype = header.point_format.dtype()
    if dtype.itemsize != layout.record_length:
        raise FormatError(
            path,
            f"point record length {layout.record_length} does not match point format "
            f"{layout.point_format} with its extra bytes ({dtype.itemsize} bytes)",
        )
    return read_records(map_file(file), dtype, layout.point_count, layout.offset_to_points)


def _cloud_parts(
    records: np.ndarray, header: laspy.LasHeader, path: Path
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Points ``(N, 3)`` float64 and fields (owned, contiguous arrays) from laspy's records.

    Each dimension is copied out of the records into its final array; see :func:`_run_in_blocks`
    for why the copying goes block by block.
    """
    count = len(records)
    point_format = header.point_format
    storage = point_format.dtype()
    # An extra-bytes record may name a dimension '' or repeat a name; numpy then drops it.
    missing = [
        d.name
        for d in point_format.extra_dimensions
        if not d.name or d.name not in storage.names
    ]
    if missing:
        raise FormatError(
            path, f"the extra-bytes record declares unusable dimension names {missing!r}"
        )
    points = np.empty((count, 3), np.float64)
    # The same operations as laspy's x / y / z, so the coordinates are bit-identical to laspy's.
    steps = [
        partial(_scale_into, points[:, axis], name, header.scales[axis], header.offsets[axis])
        for axis, name in enumerate(_COORDINATES)
    ]
    # laspy's table of which bits of which packed byte hold each bit field (LAS 1.4 tables 7, 15).
    bit_fields = laspy_dims.get_sub_fields_dict(point_format.id)
    color_names = _color_dimensions(point_format)
    columns: dict[str, np.ndarray] = {}
    for dimension in point_format.dimensions:
        name = dimension.name
        if name in _COORDINATES or name in color_names[1:]:
            continue
        if color_names and name == color_names[0]:
            colors = columns["colors"] = np.empty((count, len(color_names)), np.uint16)
            steps += [partial(_copy_into, colors[:, i], part) for i, part in enumerate(color_names)]
        elif name in bit_fields:
            packed_name, bits = bit_fields[name]
            shift = (bits.mask & -bits.mask).bit_length() - 1
            values = columns[name] = np.empty(count, np.uint8)
            steps.append(partial(_unpack_into, values, packed_name, np.uint8(bits.mask), shift))
        elif not dimension.is_standard and dimension.is_scaled:
            values = columns[name] = np.empty((count, *storage[name].shape), np.float64)
            steps.append(partial(_scale_into, values, name, dimension.scales, dimension.offsets))
        else:
            values = columns[name] = np.empty((count, *storage[name].shape), storage[name].base)
            steps.append(partial(_copy_into, values, name))
    _run_in_blocks(steps, records)
    _, fields = columns_to_cloud_parts(
        # How write_las stores fields of more than three components (see the module docstring).
        group_components(columns, min_components=4), path
    )
    return points, fields


def _color_dimensions(point_format: laspy.PointFormat) -> tuple[str, ...]:
    """``red green blue``, plus an extra ``alpha`` of the same type, when the format has colours."""
    names = set(point_format.dimension_names)
    if not names.issuperset(_COLOR_DIMENSIONS):
        return ()
    alpha = next((d for d in point_format.extra_dimensions if d.name == "alpha"), None)
    if alpha is not None and not alpha.is_scaled and point_format.dtype()["alpha"] == np.uint16:
        return (*_COLOR_DIMENSIONS, "alpha")
    return _COLOR_DIMENSIONS


def _scale_into(
    out: np.ndarray, name: str, scale: Any, offset: Any, block: np.ndarray, rows: slice
) -> None:
    np.multiply(block[name], scale, out=out[rows])
    out[rows] += offset


def _unpack_into(
    out: np.ndarray, name: str, mask: np.uint8, shift: int, block: np.ndarray, rows: slice
) -> None:
    np.bitwise_and(block[name], mask, out=out[rows])
    out[rows] >>= shift


def _copy_into(out: np.ndarray, name: str, block: np.ndarray, rows: slice) -> None:
    np.copyto(out[rows], block[name])


def _run_in_blocks(steps: list[Callable[[np.ndarray, slice], None]], records: np.ndarray) -> None:
    """Run every step on each block of ``_BLOCK_RECORDS`` records, blocks spread over threads.

    Pulling one dimension out of the interleaved records is a strided loop that costs about a
    nanosecond per value, whatever its size; block by block the records stay in cache across
    the steps, and numpy releases the GIL in these loops, so threads share the work.
    """
    starts = range(0, len(records), _BLOCK_RECORDS)

    def run(start: int) -> None:
        rows = slice(start, start + _BLOCK_RECORDS)
        block = records[rows]
        for step in steps:
            step(block, rows)

    # Starting a thread costs about a millisecond, worth it only for many blocks.
    workers = min(len(starts) // 2, _usable_cpus(), _MAX_THREADS)
    if workers <= 1:
        for start in starts:
            run(start)
        return
    with ThreadPoolExecutor(workers) as pool:
        list(pool.map(run, starts))


def _usable_cpus() -> int:
    """CPUs this process may run on (its affinity where the OS tells it, else all of them)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def _metadata(header: laspy.LasHeader, layout: _Layout) -> dict[str, Any]:
    point_format = header.point_format
    extra_dimensions = {}
    for dimension in point_format.extra_dimensions:
        element = point_format.dtype()[dimension.name]
        extra_dimensions[dimension.name] = {
            "dtype": element.base.str,
            "count": dimension.num_elements,
            "description": dimension.description,
            "scales": None if dimension.scales is None else [float(s) for s in dimension.scales],
            "offsets": None if dimension.offsets is None else [float(o) for o in dimension.offsets],
        }
    vlrs = list(header.vlrs)
    evlrs = list(header.evlrs or [])
    return {
        "encoding": "laz" if layout.compressed else "las",
        "scales": [float(s) for s in header.scales],
        "offsets": [float(o) for o in header.offsets],
        "las_version": f"{header.version.major}.{header.version.minor}",
        "las_point_format": point_format.id,
        "las_copc": any(vlr.user_id == "copc" for vlr in vlrs),
        "las_header": {
            "file_source_id": int(header.file_source_id),
            "global_encoding": int(header.global_encoding.value),
            "system_identifier": _text(header.system_identifier),
            "generating_software": _text(header.generating_software),
            "guid": str(header.uuid),
            "creation_date": header.creation_date.isoformat() if header.creation_date else None,
        },
        "las_extra_dimensions": extra_dimensions,
        "las_vlrs": [_record(vlr) for vlr in vlrs if _kept(vlr)],
        "las_evlrs": [_record(vlr) for vlr in evlrs if _kept(vlr)],
    }


def _text(value: str | bytes) -> str:
    return value.decode("ascii", "replace") if isinstance(value, bytes) else value


def _kept(vlr: Any) -> bool:
    return (
        vlr.user_id,
        vlr.record_id,
    ) not in _REGENERATED_RECORDS and vlr.user_id not in _REGENERATED_USER_IDS


def _record(vlr: Any) -> dict[str, Any]:
    return {
        "user_id": vlr.user_id,
        "record_id": int(vlr.record_id),
        "description": _text(vlr.description),
        "data": bytes(vlr.record_data_bytes()),
    }


@contextmanager
def _library_errors(path: Path, action: str) -> Iterator[None]:
    """Turn whatever laspy or lazrs raise into a FormatError naming the file.

    They raise LaspyException, ValueError, struct.error, EOFError, UnicodeDecodeError,
    LazrsError, MemoryError for sizes read from garbage, and pyo3's PanicException for Rust
    panics, which derives from BaseException; only interpreter exits pass through.
    """
    try:
        yield
    except (FormatError, KeyboardInterrupt, SystemExit, GeneratorExit):
        raise
    except BaseException as error:  # lazrs panics are BaseExceptions (see docstring)
        reason = str(error).strip().splitlines()
        detail = reason[0][:200] if reason else ""
        raise FormatError(path, f"{action}: {type(error).__name__} {detail}".rstrip()) from error


# ---------------------------------------------------------------------------------------------
# Writing
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Dimension:
    """A standard dimension of a point format: the dtype laspy reads it as, and its range."""

    dtype: np.dtype
    low: float
    high: float


def _standard_dimensions(format_id: int) -> dict[str, _Dimension]:
    point_format = laspy.PointFormat(format_id)
    storage = point_format.dtype()
    dimensions = {}
    for dimension in point_format.standard_dimensions:
        if dimension.name in _COORDINATES:
            continue
        if dimension.kind == laspy.DimensionKind.BitField:
            dimensions[dimension.name] = _Dimension(
                np.dtype(np.uint8), 0, 2**dimension.num_bits - 1
            )
            continue
        dtype = storage[dimension.name]
        if dtype.kind == "f":
            dimensions[dimension.name] = _Dimension(dtype, -np.inf, np.inf)
        else:
            info = np.iinfo(dtype)
            dimensions[dimension.name] = _Dimension(dtype, info.min, info.max)
    return dimensions


_FORMATS = {format_id: _standard_dimensions(format_id) for format_id in range(11)}
_STANDARD_NAMES = set().union(*_FORMATS.values())
_MIN_VERSION = {
    **dict.fromkeys(range(4), "1.2"),
    4: "1.3",
    5: "1.3",
    **dict.fromkeys(range(6, 11), "1.4"),
}


def write_las(path: Path, cloud: PointCloud, encoding: str | None = None) -> None:
    """Write ``cloud`` as LAS (``encoding="las"``) or LAZ (``"laz"``, the default for .laz)."""
    path = Path(path)
    compress = encoding == "laz"
    metadata = cloud.metadata
    notes: list[str] = []
    points, fields = _finite_points(cloud)

    standard, extra = _split_fields(fields, notes)
    format_id = _choose_point_format(standard, metadata)
    dimensions = _FORMATS[format_id]
    for name in list(standard):
        if name not in dimensions:
            extra[name] = standard.pop(name)
    standard = {
        name: _fit(name, values, dimensions[name], notes) for name, values in standard.items()
    }
    extra_params, extra_values = _extra_dimensions(extra, set(dimensions), metadata, notes)
    if notes:
        warnings.warn("LAS changes these fields: " + "; ".join(notes), stacklevel=3)

    header = laspy.LasHeader(
        point_format=laspy.PointFormat(format_id), version=_version(format_id, metadata)
    )
    with _library_errors(path, "laspy could not write it"):
        if extra_params:
            header.add_extra_dims(extra_params)
        header.scales, header.offsets = _scales_and_offsets(points, metadata)
        evlrs = _apply_header_metadata(header, metadata)
        records = _records(points, standard, extra_values, header)
        with (
            open(path, "wb") as file,
            laspy.LasWriter(file, header, do_compress=compress, closefd=False) as writer,
        ):
            writer.write_points(records)
            if evlrs:
                writer.write_evlrs(evlrs)


def _finite_points(cloud: PointCloud) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The cloud's points and fields without the points LAS cannot store (NaN, infinite)."""
    points, fields = cloud.points, cloud.fields
    finite = np.isfinite(points).all(axis=1)
    if not finite.all():
        warnings.warn(
            f"LAS cannot store NaN or infinite coordinates: {int((~finite).sum())} of "
            f"{len(points)} points dropped",
            stacklevel=4,
        )
        points = points[finite]
        fields = {name: values[finite] for name, values in fields.items()}
    if cloud.shape is not None:
        warnings.warn(
            f"LAS has no organised layout: the {cloud.shape} grid is not kept", stacklevel=4
        )
    return points, fields


def _split_fields(
    fields: Mapping[str, np.ndarray], notes: list[str]
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Fields named like a standard dimension (colours split into red/green/blue), and the rest."""
    standard: dict[str, np.ndarray] = {}
    extra: dict[str, np.ndarray] = {}
    for name, values in fields.items():
        if name == "colors" and values.ndim == 2 and values.shape[1] in (3, 4):
            rgb = _colors_as_uint16(values, notes)
            standard.update(zip(_COLOR_DIMENSIONS, rgb.T[:3], strict=True))
            if rgb.shape[1] == 4:
                extra["alpha"] = rgb[:, 3]
        elif name == "intensity" and _is_unit_float(values):
            notes.append(f"intensity {values.dtype} in [0, 1] -> uint16 (x65535)")
            standard[name] = _unit_to_uint16(values)
        elif name in _STANDARD_NAMES and values.ndim == 1 and values.dtype.kind in "biuf":
            standard[name] = values
        else:
            extra[name] = values
    return standard, extra


def _colors_as_uint16(colors: np.ndarray, notes: list[str]) -> np.ndarray:
    """LAS colours are uint16: uint8 * 257 (so 255 -> 65535), float [0, 1] * 65535."""
    if colors.dtype == np.uint16:
        return colors
    if colors.dtype == np.uint8:
        notes.append("colors uint8 -> uint16 (x257)")
        return colors.astype(np.uint16) * np.uint16(257)
    if _is_unit_float(colors):
        notes.append(f"colors {colors.dtype} in [0, 1] -> uint16 (x65535)")
        return _unit_to_uint16(colors)
    return _fit("colors", colors, _Dimension(np.dtype(np.uint16), 0, 65535), notes)


def _is_unit_float(values: np.ndarray) -> bool:
    """True for float values in [0, 1] (NaN ignored): colours or intensity on a unit scale."""
    return values.dtype.kind == "f" and bool(
        np.nanmin(values, initial=0) >= 0 and np.nanmax(values, initial=0) <= 1
    )


def _unit_to_uint16(values: np.ndarray) -> np.ndarray:
    return np.round(np.nan_to_num(values.astype(np.float64)) * 65535).astype(np.uint16)


def _choose_point_format(standard: Mapping[str, np.ndarray], metadata: Mapping[str, Any]) -> int:
    """The point format for the fields: the LAS cloud's own if it still fits, else the smallest.

    Formats are ranked by: holding every dimension of the format the cloud was read with, the
    number of the cloud's standard-named fields they hold, the number of those whose values fit
    without loss, and finally the smaller id (0..10, which is also the smaller record for the
    same dimensions).
    """
    base = metadata.get("las_point_format")
    base_names = set(_FORMATS[base]) if base in _FORMATS else set()
    ranges = {name: _value_range(values) for name, values in standard.items()}

    def rank(format_id: int) -> tuple[bool, int, int, int]:
        dimensions = _FORMATS[format_id]
        held = [name for name in standard if name in dimensions]
        fitting = sum(_fits(ranges[name], dimensions[name]) for name in held)
        return base_names <= dimensions.keys(), len(held), fitting, -format_id

    return max(_FORMATS, key=rank)


def _value_range(values: np.ndarray) -> tuple[str, float, float, bool]:
    """(dtype kind, min, max, all finite integers) of a field, computed once per field."""
    if values.dtype.kind not in "biuf" or len(values) == 0:
        return values.dtype.kind, 0, 0, values.dtype.kind != "f" or len(values) == 0
    low, high = values.min(), values.max()
    integral = values.dtype.kind != "f" or bool(
        np.all(np.isfinite(values)) and np.all(values == np.round(values))
    )
    return values.dtype.kind, float(low), float(high), integral


def _fits(value_range: tuple[str, float, float, bool], dimension: _Dimension) -> bool:
    kind, low, high, integral = value_range
    if kind not in "biuf":
        return False
    if dimension.dtype.kind == "f":
        return True
    return integral and dimension.low <= low and high <= dimension.high


def _fit(name: str, values: np.ndarray, dimension: _Dimension, notes: list[str]) -> np.ndarray:
    """``values`` in the dimension's dtype; converted (and noted) where they do not fit."""
    if values.dtype == dimension.dtype:
        return values
    if _fits(_value_range(values), dimension):
        notes.append(f"{name} {values.dtype} -> {dimension.dtype}")
        return values.astype(dimension.dtype)
    converted = np.clip(
        np.round(np.nan_to_num(values.astype(np.float64))), dimension.low, dimension.high
    )
    changed = int(np.count_nonzero(converted != values))
    notes.append(
        f"{name} {values.dtype} -> {dimension.dtype}, {changed} values rounded or clipped to "
        f"[{dimension.low:g}, {dimension.high:g}]"
    )
    return converted.astype(dimension.dtype)


def _extra_dimensions(
    extra: Mapping[str, np.ndarray],
    standard_names: set[str],
    metadata: Mapping[str, Any],
    notes: list[str],
) -> tuple[list[laspy.ExtraBytesParams], dict[str, np.ndarray]]:
    """Extra bytes dimensions, and the values to store in them, for the fields left over.

    A field read from LAS gets its original type, description, scales and offsets back; any
    other field an extra dimension of its own dtype. ``normals`` become ``nx ny nz``, ``(N, 2)``
    and ``(N, 3)`` fields 2- and 3-element types, wider ones K dimensions ``name[i]``.
    """
    known = metadata.get("las_extra_dimensions")
    known = known if isinstance(known, Mapping) else {}
    taken = standard_names | _RESERVED_NAMES
    params: list[laspy.ExtraBytesParams] = []
    stored: dict[str, np.ndarray] = {}
    skipped: list[str] = []
    for name, values in cloud_to_columns(None, extra, _NAMES).items():
        for column_name, column in _columns_of(name, values):
            reason = _unstorable(column_name, column, taken)
            if reason:
                skipped.append(f"{column_name} ({reason})")
                continue
            taken.add(column_name)
            param, stored[column_name] = _extra_dimension(
                column_name, column, known.get(column_name), notes
            )
            params.append(param)
    if skipped:
        warnings.warn(f"LAS cannot hold these fields: {', '.join(skipped)}", stacklevel=4)
    return params, stored


def _unstorable(name: str, column: np.ndarray, taken: set[str]) -> str | None:
    """Why ``column`` cannot be an extra bytes dimension called ``name``, or None if it can."""
    if _extra_bytes_dtype(column.dtype) is None:
        return f"dtype {column.dtype}"
    if column.ndim > 2 or (column.ndim == 2 and column.shape[1] < 2):
        return f"shape {column.shape}"
    if name in taken:
        return "name taken by a LAS dimension"
    if not name.isascii() or len(name) > _EXTRA_NAME_BYTES:
        return f"name not ASCII or over {_EXTRA_NAME_BYTES} characters"
    return None


def _extra_dimension(
    name: str, column: np.ndarray, previous: Any, notes: list[str]
) -> tuple[laspy.ExtraBytesParams, np.ndarray]:
    """One extra bytes dimension and its values; as in the file the field came from, if any."""
    count = 1 if column.ndim == 1 else column.shape[1]
    description = ""
    if isinstance(previous, Mapping) and previous.get("count") == count:
        description = str(previous.get("description") or "")[:_DESCRIPTION_BYTES]
        rescaled = _rescaled(column, previous)
        if rescaled is not None:
            raw, scales, offsets = rescaled
            element = raw.dtype if count == 1 else np.dtype((raw.dtype, (count,)))
            return laspy.ExtraBytesParams(name, element, description, offsets, scales), raw
    dtype = _extra_bytes_dtype(column.dtype)
    if dtype != column.dtype:
        notes.append(f"{name} {column.dtype} -> {dtype}")
    element = dtype if count == 1 else np.dtype((dtype, (count,)))
    return laspy.ExtraBytesParams(name, element, description), column


def _rescaled(
    column: np.ndarray, previous: Mapping[str, Any]
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """``(raw, scales, offsets)`` storing a float field the way its LAS file did, if it still fits.

    Scaled extra dimensions read as ``raw * scale + offset``; this is the inverse,
    ``raw = round((value - offset) / scale)``, in the original integer type.
    """
    if previous.get("scales") is None or column.dtype.kind != "f":
        return None
    try:
        dtype = np.dtype(previous["dtype"])
        scales = np.asarray(previous["scales"], np.float64)
        offsets = np.asarray(previous["offsets"], np.float64)
        raw = np.round((column - offsets) / scales)
    except (KeyError, TypeError, ValueError):
        return None
    if dtype.kind not in "iu" or not np.all(np.isfinite(raw)):
        return None
    info = np.iinfo(dtype)
    if len(raw) and (raw.min() < info.min or raw.max() > info.max):
        return None
    return raw.astype(dtype), scales, offsets


def _columns_of(name: str, values: np.ndarray) -> list[tuple[str, np.ndarray]]:
    """A field as extra-dimension columns.

    ``(N,)``, ``(N, 2)``, ``(N, 3)`` and ``(N, K)`` uint8 (LAS's undocumented-bytes type) stay
    one column; other ``(N, K)`` fields become K ``(N,)`` columns ``name[i]``.
    """
    if values.ndim == 2 and values.shape[1] > 3 and values.dtype != np.uint8:
        return [(f"{name}[{i}]", values[:, i]) for i in range(values.shape[1])]
    return [(name, values)]  # (N, K, M) and (N, 1) are reported as not storable


def _extra_bytes_dtype(dtype: np.dtype) -> np.dtype | None:
    """The little-endian extra bytes type that holds ``dtype`` exactly, or None."""
    if dtype.kind == "b":
        return np.dtype(np.uint8)
    if dtype.kind == "f" and dtype.itemsize < 4:
        return np.dtype(np.float32)
    little = dtype.newbyteorder("<")
    return little if little in _EXTRA_BYTES_DTYPES else None


def _version(format_id: int, metadata: Mapping[str, Any]) -> str:
    """The cloud's LAS version if it allows the point format, else the lowest that does."""
    version = metadata.get("las_version")
    if (
        version in laspy_dims.VERSION_TO_POINT_FMT
        and format_id in laspy_dims.VERSION_TO_POINT_FMT[version]
    ):
        return version
    return _MIN_VERSION[format_id]


def _scales_and_offsets(
    points: np.ndarray, metadata: Mapping[str, Any]
) -> tuple[np.ndarray, np.ndarray]:
    """Scales and offsets that put every coordinate in int32.

    The cloud's own (a LAS cloud's metadata) when they do; otherwise offset = the floored
    minimum corner and scale = 0.001, or the smallest power of ten above it that spans the
    extent.
    """
    low = points.min(axis=0).astype(np.float64) if len(points) else np.zeros(3)
    high = points.max(axis=0).astype(np.float64) if len(points) else np.zeros(3)
    scales = _three_floats(metadata.get("scales"))
    offsets = _three_floats(metadata.get("offsets"))
    if scales is not None and offsets is not None and np.all(scales > 0):
        if _in_int32(low, high, scales, offsets):
            return scales, offsets
        warnings.warn(
            "the cloud's LAS scales and offsets do not span its points; new ones chosen",
            stacklevel=4,
        )
    offsets = np.floor(low).astype(np.float64)
    extent = np.max(high - offsets) if len(points) else 0.0
    scale = _DEFAULT_SCALE
    while extent / scale > _INT32_MAX:
        scale *= 10
    return np.full(3, scale), offsets


def _three_floats(value: Any) -> np.ndarray | None:
    try:
        array = np.asarray(value, np.float64)
    except (TypeError, ValueError):
        return None
    return array if array.shape == (3,) and np.all(np.isfinite(array)) else None


def _in_int32(low: np.ndarray, high: np.ndarray, scales: np.ndarray, offsets: np.ndarray) -> bool:
    raw_low = np.round((low - offsets) / scales)
    raw_high = np.round((high - offsets) / scales)
    return bool(np.all(raw_low >= -_INT32_MAX - 1) and np.all(raw_high <= _INT32_MAX))


def _apply_header_metadata(header: laspy.LasHeader, metadata: Mapping[str, Any]) -> VLRList:
    """Header fields, VLRs and EVLRs of a LAS cloud; returns the EVLRs to write after the points."""
    header.generating_software = f"pointfield {__version__}"
    # LAS 1.4 requires formats 6-10 to describe any CRS in WKT; a LAS cloud brings its own flags.
    header.global_encoding.wkt = header.point_format.id >= 6
    info = metadata.get("las_header")
    if isinstance(info, Mapping):
        header.file_source_id = int(info.get("file_source_id") or 0)
        header.global_encoding = GlobalEncoding(int(info.get("global_encoding") or 0))
        header.system_identifier = str(info.get("system_identifier") or "")[:32]
        if info.get("guid"):
            header.uuid = UUID(str(info["guid"]))
        if info.get("creation_date"):
            header.creation_date = date.fromisoformat(str(info["creation_date"]))
    for record in metadata.get("las_vlrs") or []:
        header.vlrs.append(_vlr(record))
    evlrs = VLRList(_vlr(record) for record in metadata.get("las_evlrs") or [])
    if evlrs and header.version.minor < 4:
        warnings.warn(f"LAS {header.version} has no EVLRs; {len(evlrs)} dropped", stacklevel=4)
        return VLRList()
    return evlrs


def _vlr(record: Mapping[str, Any]) -> laspy.VLR:
    return laspy.VLR(
        str(record["user_id"]),
        int(record["record_id"]),
        str(record.get("description") or ""),
        bytes(record["data"]),
    )


def _records(
    points: np.ndarray,
    standard: Mapping[str, np.ndarray],
    extra: Mapping[str, np.ndarray],
    header: laspy.LasHeader,
) -> laspy.PackedPointRecord:
    """The point records: quantised coordinates ``X = round((x - offset) / scale)``, then the
    standard and the extra dimensions."""
    records = laspy.PackedPointRecord.zeros(len(points), header.point_format)
    for axis, name in enumerate(_COORDINATES):
        coordinate = points[:, axis].astype(np.float64)
        records[name] = np.round((coordinate - header.offsets[axis]) / header.scales[axis])
    for name, values in standard.items():
        records[name] = values  # laspy packs bit fields into their bytes
    for name, values in extra.items():
        records.array[name] = values
    return records


register(
    Format(
        name="las",
        description="ASPRS LAS / LAZ / COPC lidar (laspy + lazrs)",
        suffixes=(".las", ".laz"),
        read=read_las,
        write=write_las,
        encodings=("las", "laz"),
        aliases={"binary": "las", "compressed": "laz"},
        signature=is_las,
        suffix_encodings={".laz": "laz"},
    )
)
