"""Writing PCD in any of its three encodings (see the package docstring for what is written)."""

from __future__ import annotations

import struct
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import BinaryIO

import lzf
import numpy as np

from pointfield.clouds.cloud import PointCloud, Records
from pointfield.clouds.formats.ascii import write_rows
from pointfield.clouds.formats.binary import record_dtype
from pointfield.clouds.formats.columns import PCD_NAMES, cloud_to_columns
from pointfield.clouds.formats.pcd.header import (
    BANNER,
    DEFAULT_VIEWPOINT,
    DTYPES,
    ENCODINGS,
    TYPE_OF_KIND,
    PcdField,
)
from pointfield.errors import FormatError


def write_pcd(path: Path, cloud: PointCloud | Records, encoding: str | None = None) -> None:
    """Write ``cloud`` (a PointCloud, Mesh vertices, or Records) as PCD in ``encoding``.

    ``encoding`` is ``binary`` (default), ``binary_compressed`` or ``ascii``. See the module
    docstring for how fields are spelled and which ones PCD cannot hold.
    """
    encoding = encoding or ENCODINGS[0]
    if encoding not in ENCODINGS:
        raise FormatError(path, f"PCD has no encoding {encoding!r}; expected one of {ENCODINGS}")
    columns = _columns_to_write(cloud, ascii_text=encoding == "ascii")
    if not columns:
        raise FormatError(path, "nothing to write: the records have no field PCD can hold")
    n = len(cloud)
    fields = [_field_for(name, values) for name, values in columns.items()]
    shape = getattr(cloud, "shape", None) or (1, n)
    viewpoint = _viewpoint_to_write(cloud.metadata.get("viewpoint"), path)
    with open(path, "wb") as file:
        file.write(_header_text(fields, shape, n, viewpoint, encoding, cloud.metadata))
        if encoding == "binary":
            _write_binary(file, columns, fields, n)
        elif encoding == "binary_compressed":
            _write_compressed(file, columns, fields, n, path)
        else:
            _write_ascii(file, columns)


def _header_text(
    fields: list[PcdField],
    shape: tuple[int, int],
    points: int,
    viewpoint: tuple[float, ...],
    encoding: str,
    metadata: Mapping[str, object],
) -> bytes:
    """The header of ``points`` points of ``(HEIGHT, WIDTH)`` = ``shape``, with ``metadata``'s comments."""
    comments = metadata.get("comments", ())
    comments = [comments] if isinstance(comments, str) else comments
    lines = [BANNER]
    lines += [f"# {line}" for comment in comments for line in str(comment).splitlines()]
    lines += [
        "VERSION 0.7",
        "FIELDS " + " ".join(f.name for f in fields),
        "SIZE " + " ".join(str(f.size) for f in fields),
        "TYPE " + " ".join(f.type for f in fields),
        "COUNT " + " ".join(str(f.count) for f in fields),
        f"WIDTH {shape[1]}",
        f"HEIGHT {shape[0]}",
        "VIEWPOINT " + " ".join(_number_text(v) for v in viewpoint),
        f"POINTS {points}",
        f"DATA {encoding}",
    ]
    return ("\n".join(lines) + "\n").encode("utf-8")


def _columns_to_write(cloud: PointCloud | Records, ascii_text: bool) -> dict[str, np.ndarray]:
    """The file's columns in order, each ``(N,)`` or ``(N, K)`` little-endian numeric."""
    points = getattr(cloud, "points", None)
    columns = cloud_to_columns(points, {}, PCD_NAMES)
    skipped = []
    for name, values in cloud.fields.items():
        if name == "colors" and values.dtype == np.uint8 and values.shape[1:] in ((3,), (4,)):
            new = {"rgb" if values.shape[1] == 3 else "rgba": _pack_colors(values, ascii_text)}
        else:
            new = cloud_to_columns(None, {name: values}, PCD_NAMES)
        if columns.keys() & new.keys() or any(_unwritable(n, v) for n, v in new.items()):
            skipped.append(name)
            continue
        for column_name, column in new.items():
            if column.dtype == bool:
                warnings.warn(
                    f"PCD has no boolean type; field {name!r} is written as U1 (uint8)",
                    stacklevel=4,
                )
                column = column.view(np.uint8)
            columns[column_name] = column.astype(column.dtype.newbyteorder("<"), copy=False)
    if skipped:
        warnings.warn(
            f"PCD cannot hold field(s) {', '.join(map(repr, skipped))} (PCD fields are numeric, "
            f"(N,) or (N, K), with unique names without spaces); they were not written",
            stacklevel=4,
        )
    return columns


def _unwritable(name: str, values: np.ndarray) -> bool:
    if not name or name == "_" or any(c.isspace() for c in name):
        return True
    if values.ndim not in (1, 2) or (values.ndim == 2 and values.shape[1] == 0):
        return True
    pcd_type = (TYPE_OF_KIND.get(values.dtype.kind), values.dtype.itemsize)
    return values.dtype != bool and pcd_type not in DTYPES


def _pack_colors(colors: np.ndarray, ascii_text: bool) -> np.ndarray:
    """uint8 ``(N, 3|4)`` colours as the 0xAARRGGBB word PCL packs: little-endian bytes B G R A.

    ``(N, 3)`` gives a float32 ``rgb`` whose alpha byte is 0 (so the float is finite); in ascii
    text it stays a uint32, whose integer value survives printing. ``(N, 4)`` gives a uint32.
    """
    words = np.zeros((len(colors), 4), np.uint8)
    words[:, :3] = colors[:, 2::-1]
    if colors.shape[1] == 4:
        words[:, 3] = colors[:, 3]
    words = words.view("<u4").reshape(-1)
    return words if ascii_text or colors.shape[1] == 4 else words.view("<f4")


def _field_for(name: str, values: np.ndarray) -> PcdField:
    return PcdField(
        name,
        TYPE_OF_KIND[values.dtype.kind],
        values.dtype.itemsize,
        1 if values.ndim == 1 else values.shape[1],
    )


def _viewpoint_to_write(viewpoint: object, path: Path) -> tuple[float, ...]:
    if viewpoint is None:
        return DEFAULT_VIEWPOINT
    try:
        values = tuple(float(v) for v in viewpoint)  # type: ignore[attr-defined]
    except (TypeError, ValueError):
        values = ()
    if len(values) != 7:
        raise FormatError(
            path,
            f"metadata['viewpoint'] is {viewpoint!r}; expected 7 numbers tx ty tz qw qx qy qz",
        )
    return values


def _number_text(value: float) -> str:
    """Shortest text that reads back as the same float, without a needless ``.0``."""
    return repr(float(value)).removesuffix(".0")


def _write_binary(
    file: BinaryIO, columns: Mapping[str, np.ndarray], fields: list[PcdField], n: int
) -> None:
    """The points one after another, each its fields packed in order (np.dtype packs them)."""
    layout = record_dtype([(f.name, f.dtype, () if f.count == 1 else (f.count,)) for f in fields], "<")
    records = np.empty(n, layout)
    for f in fields:
        records[f.name] = columns[f.name]
    file.write(records.view(np.uint8))


def _write_compressed(
    file: BinaryIO, columns: Mapping[str, np.ndarray], fields: list[PcdField], n: int, path: Path
) -> None:
    """Size prefix, then one LZF block of the columns one after another (see the docstring)."""
    size = n * sum(f.nbytes for f in fields)
    if size >= 2**32:
        raise FormatError(
            path, f"binary_compressed holds at most 4 GiB of points; this cloud is {size} bytes"
        )
    if size == 0:
        file.write(struct.pack("<II", 0, 0))
        return
    buffer = np.empty(size, np.uint8)
    offset = 0
    for f in fields:
        column = np.ascontiguousarray(columns[f.name])
        buffer[offset : offset + column.nbytes] = column.reshape(-1).view(np.uint8)
        offset += column.nbytes
    buffer.flags.writeable = False  # python-lzf takes read-only buffers only
    # LZF's worst case adds one control byte per 32 literal bytes.
    compressed = lzf.compress(buffer, size + size // 32 + 16)
    if compressed is None:
        raise FormatError(path, "LZF could not compress the points into its worst-case bound")
    file.write(struct.pack("<II", len(compressed), size))
    file.write(compressed)


def _write_ascii(file: BinaryIO, columns: Mapping[str, np.ndarray]) -> None:
    """One line per point; floats in their shortest round-trip text for their own dtype."""
    components = [
        component
        for values in columns.values()
        for component in (values.T if values.ndim == 2 else [values])
    ]
    write_rows(file, components)
