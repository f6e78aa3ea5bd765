"""The LAS header checked against the file before laspy or lazrs read anything by it.

A header's sizes, counts, VLR and EVLR lengths and, for LAZ, the chunk table and the layer sizes
of layered chunks are claims that laspy and lazrs allocate by; here each is checked against the
bytes the file really has, so a hostile file is a FormatError rather than gigabytes or hours.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import laspy
import lazrs

from pointfield.clouds.formats.binary import check_size
from pointfield.clouds.formats.las.library import library_errors, rust_panics_quiet
from pointfield.errors import FormatError

SIGNATURE = b"LASF"

# Fixed part of every LAS header, up to the legacy point count (LAS 1.4 R15, table 3).
_HEADER_START = struct.Struct("<4sHH16sBB32s32sHHHIIBHI")
_HEADER_1_4_COUNTS = struct.Struct("<QIQ")  # start of first EVLR, EVLR count, point count
_HEADER_1_4_COUNTS_OFFSET = 235
_MIN_HEADER_SIZE = {0: 227, 1: 227, 2: 227, 3: 235, 4: 375}
_VLR_HEADER_SIZE = 54
_EVLR_HEADER_SIZE = 60
LASZIP_USER_ID, LASZIP_RECORD_ID = "laszip encoded", 22204
_LASZIP_KEY = (LASZIP_USER_ID.encode(), LASZIP_RECORD_ID)
_POINTWISE_COMPRESSOR = 1  # LASzip 1.x: one stream, no chunks
_CHUNKED_COMPRESSORS = (2, 3)  # pointwise chunked, layered chunked: both carry a chunk table
_LASZIP_CHUNK_SIZE_OFFSET = 12
_VARIABLE_CHUNKS = 2**32 - 1  # the chunk size that means "variable-size chunks"
_LAYERED_COMPRESSOR = 3
_LASZIP_ITEM_COUNT_OFFSET = 32
# Layers of each LAZ item type in layered chunks: Point14 9 (xy and returns, z, classification,
# flags, intensity, scan angle, user data, point source, gps time), RGB14 1, RGBNIR14 2,
# Wavepacket14 1; extra bytes (Byte14) have one layer per byte, i.e. as many as their size.
_LAYERS_PER_ITEM = {10: 9, 11: 1, 12: 2, 13: 1}


def is_las(head: bytes) -> bool:
    """True for LAS, LAZ and COPC files: they all start with ``LASF``."""
    return head.startswith(SIGNATURE)


@dataclass(frozen=True)
class Layout:
    """What the fixed header says about where things are, already checked against the file."""

    offset_to_points: int
    point_format: int
    record_length: int
    point_count: int
    compressed: bool
    laszip_record: bytes | None  # data of the LASzip VLR, which describes the compression


def check_layout(path: Path, file: BinaryIO, size: int) -> Layout:
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
    return Layout(
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


def check_laz(path: Path, file: BinaryIO, layout: Layout, size: int) -> laspy.LazBackend:
    """Check the LAZ chunk table before lazrs sizes its buffers from it; pick the decompressor.

    lazrs reserves memory for the chunk count and the chunk point counts of the table, and for
    ``chunk_size * record size`` per chunk, and aborts the whole process when an allocation
    fails; so the table must agree with the file and with the header's point count. The
    parallel decompressor (laspy's default) is used when there are several chunks; a single
    chunk gains nothing from it, and its buffer would be sized by the declared chunk size.

    Files of the LASzip 1.2r0 compressor (one pointwise stream whose record declares
    variable-size chunks) make lazrs panic ("Variable-size chunks, but no chunk table"); they
    get the LASzip backend (PyPI ``laszip``), which reads them, or a FormatError saying so.
    """
    record_data = layout.laszip_record
    if len(record_data) < _LASZIP_ITEM_COUNT_OFFSET + 2:
        raise FormatError(path, f"LASzip record is {len(record_data)} bytes, too short")
    (compressor,) = struct.unpack_from("<H", record_data)
    (declared_chunk_size,) = struct.unpack_from("<I", record_data, _LASZIP_CHUNK_SIZE_OFFSET)
    if compressor == _POINTWISE_COMPRESSOR and declared_chunk_size == _VARIABLE_CHUNKS:
        if not laspy.LazBackend.Laszip.is_available():
            raise FormatError(
                path,
                "LAZ of an old LASzip (one pointwise stream declaring variable-size chunks): "
                "lazrs cannot read it and the LASzip backend is not installed (pip install laszip)",
            )
        return laspy.LazBackend.Laszip
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
    with rust_panics_quiet(), library_errors(path, "lazrs could not read the LAZ chunk table"):
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


def laz_backends(
    path: Path, file: BinaryIO, layout: Layout, size: int
) -> tuple[laspy.LazBackend, ...]:
    """The decompressors to try in turn: :func:`check_laz`'s choice, then LASzip if installed.

    LASzip reads some files lazrs refuses; the table checks above come first either way.
    """
    first = check_laz(path, file, layout, size)
    fallback = laspy.LazBackend.Laszip
    if first is not fallback and fallback.is_available():
        return first, fallback
    return (first,)


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
