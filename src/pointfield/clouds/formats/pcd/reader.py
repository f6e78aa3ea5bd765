"""Reading PCD: ``ascii``, ``binary`` and ``binary_compressed`` data into a cloud or records."""

from __future__ import annotations

import os
import struct
from pathlib import Path
from typing import Any, BinaryIO

import lzf
import numpy as np

from pointfield.clouds.cloud import PointCloud, Records
from pointfield.clouds.formats.ascii import TableError, read_table, single_spaced
from pointfield.clouds.formats.binary import (
    check_size,
    map_file,
    read_records,
    record_dtype,
)
from pointfield.clouds.formats.columns import columns_to_cloud_parts
from pointfield.clouds.formats.pcd.header import (
    LZF_MAX_EXPANSION,
    MAX_HEADER_BYTES,
    PcdField,
    PcdHeader,
    parse_header,
)
from pointfield.errors import FormatError


def read_pcd(path: Path) -> PointCloud | Records:
    """Read a PCD file: a :class:`PointCloud`, or :class:`Records` when it has no x/y/z.

    See the module docstring for how fields, colours, organised clouds and metadata map.
    Raises FormatError naming the file for anything malformed, truncated or inconsistent; every
    declared size is checked against the bytes the file really has before anything is allocated.
    """
    with open(path, "rb") as file:
        head = file.read(MAX_HEADER_BYTES)
        header = parse_header(head, path)
        available = os.fstat(file.fileno()).st_size - header.data_offset
        if header.encoding == "binary":
            check_size(path, "header", header.points, header.point_size, available, unit="points")
            # A small file's head is the whole file, which is then not read a second time.
            buffer = map_file(file, head)
        del head  # else up to a megabyte, not to be held while the data is decoded
        file.seek(header.data_offset)
        if header.encoding == "binary":
            columns = _read_binary(buffer, header)
        elif header.encoding == "binary_compressed":
            columns = _read_compressed(file, header, available, path)
        else:
            columns = _read_ascii(file.read(), header, path)
    return _assemble(columns, header, path)


def _binary_records(header: PcdHeader) -> np.dtype:
    """The structured dtype of one ``DATA binary`` point record: a field per non-padding PCD
    field at its byte offset, packed colours as their 4 bytes (B G R A, ready for decoding)."""
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
    return record_dtype(fields, "<", offsets, header.point_size)


def _read_binary(buffer: Any, header: PcdHeader) -> dict[str, np.ndarray]:
    """Columns of ``DATA binary``: views into the points' records in ``buffer``, the file."""
    records = read_records(buffer, _binary_records(header), header.points, header.data_offset)
    return {name: records[name] for name in records.dtype.names}


def _read_compressed(
    file: BinaryIO, header: PcdHeader, available: int, path: Path
) -> dict[str, np.ndarray]:
    """Columns of ``DATA binary_compressed``: views into the decompressed column-major buffer."""
    expected = header.points * header.point_size
    if available < 8:
        if expected == 0 and available == 0:
            return _columns_of(b"", header)
        raise FormatError(
            path, f"DATA binary_compressed needs an 8-byte size prefix; {available} bytes follow"
        )
    compressed_size, uncompressed_size = struct.unpack("<II", file.read(8))
    if uncompressed_size != expected:
        raise FormatError(
            path,
            f"binary_compressed block expands to {uncompressed_size} bytes but {header.points} "
            f"points x {header.point_size} bytes need {expected}",
        )
    if compressed_size > available - 8:
        raise FormatError(
            path,
            f"binary_compressed block claims {compressed_size} bytes but only {available - 8} "
            f"follow",
        )
    if expected == 0:
        return _columns_of(b"", header)
    if expected > LZF_MAX_EXPANSION * compressed_size:
        raise FormatError(
            path,
            f"{compressed_size} LZF bytes cannot expand to {expected} bytes (LZF expands at "
            f"most {LZF_MAX_EXPANSION}x)",
        )
    block = file.read(compressed_size)
    try:
        data = lzf.decompress(block, expected)
    except ValueError:
        raise FormatError(path, "binary_compressed block is corrupt (LZF error)") from None
    if data is None or len(data) != expected:
        got = "more than" if data is None else f"only {len(data)} of"
        raise FormatError(
            path, f"binary_compressed block expands to {got} the {expected} bytes it declares"
        )
    return _columns_of(data, header)


def _columns_of(data: bytes, header: PcdHeader) -> dict[str, np.ndarray]:
    """Read-only views of each field's column in a column-major buffer of ``header.points``."""
    n = header.points
    columns = {}
    offset = 0
    for f in header.fields:
        if not f.is_padding:
            if f.is_packed_color:
                column = np.frombuffer(data, np.uint8, 4 * n, offset).reshape(n, 4)
            else:
                column = np.frombuffer(data, f.dtype, n * f.count, offset)
                column = column if f.count == 1 else column.reshape(n, f.count)
            columns[f.name] = column
        offset += n * f.nbytes
    return columns


def _read_ascii(data: bytes, header: PcdHeader, path: Path) -> dict[str, np.ndarray]:
    """Columns of ``DATA ascii``, one line per point, values one space apart.

    Files with tabs, repeated or trailing spaces are made single-spaced and parsed again. Values
    separated by commas (not PCL's, but PDAL writes and reads them) are read too: one comma
    apart directly, otherwise with the commas made spaces. ``nan``, ``inf`` and ``-inf`` are
    accepted for floats.
    """
    n = header.points
    values_per_point = sum(f.count for f in header.fields)
    if n == 0:
        return _columns_of(b"", header)
    # Each value takes at least one character and one separator (the last may lack its newline).
    if 2 * n * values_per_point - 1 > len(data):
        raise FormatError(
            path,
            f"DATA ascii has {len(data)} bytes, too few for {n} points of {values_per_point} "
            f"values",
        )
    column_types = [_text_dtype(f) for f in header.fields for _ in range(f.count)]
    end = data.find(b"\n")
    first_line = data[: end if end >= 0 else len(data)]
    delimiter = "," if b"," in first_line else " "
    try:
        parsed = read_table(data, column_types, delimiter)
    except TableError:
        if delimiter == ",":
            data = data.translate(_COMMAS_TO_SPACES)
        try:
            parsed = read_table(single_spaced(data), column_types)
        except TableError as error:
            raise FormatError(path, f"DATA ascii: {error}") from None
    rows = len(parsed[0]) if parsed else 0
    if rows != n:
        raise FormatError(path, f"DATA ascii has {rows} rows but POINTS says {n}")
    columns = {}
    index = 0
    for f in header.fields:
        first, index = index, index + f.count
        if f.is_padding:
            continue
        parts = parsed[first:index]
        if f.is_packed_color:
            columns[f.name] = _packed_word_from_text(parts[0], f).view(np.uint8).reshape(n, 4)
        elif f.count == 1:
            columns[f.name] = parts[0]
        else:
            columns[f.name] = np.stack(parts, axis=1)
    return columns


_COMMAS_TO_SPACES = bytes.maketrans(b",", b" ")


def _text_dtype(f: PcdField) -> np.dtype | None:
    """The dtype a field's text is parsed as; None leaves padding unparsed."""
    if f.is_padding:
        return None
    if f.is_packed_color:
        return np.dtype(np.uint32) if f.type == "U" else np.dtype(np.float64)
    return f.dtype


def _packed_word_from_text(values: np.ndarray, f: PcdField) -> np.ndarray:
    """The uint32 0xAARRGGBB words of an ascii packed-colour column (see the module docstring)."""
    if f.type == "U":
        return values.astype("<u4", copy=False)
    whole = (
        np.isfinite(values).all()
        and (values == np.floor(values)).all()
        and values.min() >= 0
        and values.max() < 2**32
    )
    if whole:
        return values.astype("<u4")
    return values.astype("<f4").view("<u4")


def _assemble(
    columns: dict[str, np.ndarray], header: PcdHeader, path: Path
) -> PointCloud | Records:
    """Turn raw file columns into a PointCloud (or Records) with canonical fields."""
    packed = header.packed_color
    if packed is not None:
        alpha = packed.name.lower() == "rgba"
        columns = dict(
            ("colors", _unpack_colors(values, alpha)) if name == packed.name else (name, values)
            for name, values in columns.items()
        )
    points, fields = columns_to_cloud_parts(columns, path)
    # Every array handed out is the caller's own: contiguous, writable, not a view of a buffer.
    fields = {
        name: values if values.flags.c_contiguous and values.flags.writeable else values.copy()
        for name, values in fields.items()
    }
    metadata = {"encoding": header.encoding}
    if header.version is not None:
        metadata["version"] = header.version
    metadata["viewpoint"] = header.viewpoint
    metadata["comments"] = list(header.comments)
    if points is None:
        return Records(fields, metadata)
    shape = (header.height, header.width) if header.height > 1 else None
    return PointCloud(points, fields, shape, metadata)


def _unpack_colors(words: np.ndarray, alpha: bool) -> np.ndarray:
    """``(N, 4)`` packed-word bytes B G R A -> uint8 colours R G B, or R G B A when ``alpha``."""
    colors = np.empty((len(words), 4 if alpha else 3), np.uint8)
    colors[:, :3] = words[:, 2::-1]
    if alpha:
        colors[:, 3] = words[:, 3]
    return colors
