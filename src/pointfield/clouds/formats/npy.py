"""NumPy's ``.npy`` arrays, read and written as clouds.

A ``.npy`` file is a magic string, a header that is a Python dict literal
``{'descr': <dtype>, 'fortran_order': <bool>, 'shape': <tuple>}``, then the array's bytes. One
array is read as:

- a plain ``(N, 3 + K)`` array (float, or integer read as float64 points): the first three
  columns are ``points`` in the array's dtype, the other K, if any, the field ``features``
  ``(N, K)``. An ``(H, W, 3 + K)`` array is an organised cloud of shape ``(H, W)``.
- a structured array with fields ``x y z`` (any case) and any others: ``points`` and fields
  grouped by :func:`columns_to_cloud_parts` (``red green blue`` -> ``colors``, ...); a subarray
  field ``(K,)`` is an ``(N, K)`` field. A structured array of shape ``(H, W)`` is organised. One
  without ``x y z`` but with a ``(3,)`` field named ``points``, ``xyz``, ``pos`` or
  ``positions`` takes its points from there; with neither it reads as :class:`Records`.

Writing ``.npy`` writes a structured array ``x y z`` + one field per cloud field, with the
points' and fields' own dtypes (``(N, K)`` fields as ``(K,)`` subarrays), shaped ``(H, W)`` for
organised clouds: every name, dtype and bit round-trips.

Nothing is ever unpickled: arrays of Python objects are a FormatError. The header is parsed
(:func:`read_array_header`, which ``.npz`` members go through too) and its declared shape checked
against the bytes actually present before anything is allocated. A ``.npy`` is read through a
read-only memory map, so memory holds the output arrays and nothing more.
"""

from __future__ import annotations

import ast
import io
import math
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import numpy as np

from pointfield.clouds.cloud import PointCloud, Records
from pointfield.clouds.formats.binary import check_size, map_file, read_records
from pointfield.clouds.formats.chunked import BodyFirstWriter, RecordSource
from pointfield.clouds.formats.columns import columns_to_cloud_parts
from pointfield.clouds.formats.registry import Format, register
from pointfield.errors import FormatError

NPY_MAGIC = b"\x93NUMPY"

POINT_KEYS = ("points", "xyz", "pos", "positions")
FEATURES = "features"

# numpy's own headers are a few hundred bytes; a megabyte allows huge structured dtypes.
MAX_HEADER_BYTES = 1 << 20


def looks_like_npy(head: bytes) -> bool:
    return head.startswith(NPY_MAGIC)


@dataclass(frozen=True)
class ArrayHeader:
    """An ``.npy`` header: the array's dtype, shape and order, and the header's own size."""

    dtype: np.dtype
    shape: tuple[int, ...]
    fortran_order: bool
    size: int  # bytes from the magic to the first data byte

    @property
    def count(self) -> int:
        return math.prod(self.shape)

    @property
    def nbytes(self) -> int:
        return self.count * self.dtype.itemsize

    @property
    def declared(self) -> str:
        """What the header declares, for messages."""
        return f"the header (a {self.dtype} array of shape {self.shape})"


def read_array_header(stream: IO[bytes], path: Path, member: str | None = None) -> ArrayHeader:
    """Parse the ``.npy`` header at the start of ``stream`` (versions 1, 2 and 3).

    The header is a Python dict literal ``{'descr': ..., 'fortran_order': ..., 'shape': ...}``
    parsed with ``ast.literal_eval`` (no code runs). Raises FormatError for anything malformed,
    for dtypes holding Python objects (which only pickle could restore) and for empty dtypes.
    ``member`` names the archive member being read, for the messages.
    """
    where = "" if member is None else f"member {member!r}: "
    prefix = stream.read(10)
    if len(prefix) < 10 or not prefix.startswith(NPY_MAGIC):
        raise FormatError(path, f"{where}not a NumPy array: no \\x93NUMPY header")
    major = prefix[6]
    if major == 1:
        length, start = int.from_bytes(prefix[8:10], "little"), 10
    elif major in (2, 3):
        more = stream.read(2)
        if len(more) < 2:
            raise FormatError(path, f"{where}the .npy header is cut short")
        length, start = int.from_bytes(prefix[8:10] + more, "little"), 12
    else:
        raise FormatError(path, f"{where}unknown .npy format version {major}.{prefix[7]}")
    if length > MAX_HEADER_BYTES:
        raise FormatError(path, f"{where}.npy header of {length} bytes; expected a few hundred")
    text = stream.read(length)
    if len(text) < length:
        raise FormatError(
            path, f"{where}the .npy header is cut short ({len(text)} of {length} bytes)"
        )
    try:
        header = ast.literal_eval(text.decode("utf-8" if major == 3 else "latin-1"))
    except (SyntaxError, ValueError, TypeError, MemoryError, RecursionError, UnicodeDecodeError):
        raise FormatError(path, f"{where}the .npy header is not a Python literal") from None
    if not isinstance(header, dict) or set(header) != {"descr", "fortran_order", "shape"}:
        raise FormatError(
            path, f"{where}the .npy header must hold exactly descr, fortran_order and shape"
        )
    shape, fortran_order = header["shape"], header["fortran_order"]
    if not (
        isinstance(shape, tuple)
        and all(isinstance(d, int) and not isinstance(d, bool) and d >= 0 for d in shape)
    ):
        raise FormatError(
            path, f"{where}shape {repr(shape)[:60]} is not a tuple of non-negative integers"
        )
    if not isinstance(fortran_order, bool):
        raise FormatError(
            path, f"{where}fortran_order {repr(fortran_order)[:20]} is not True or False"
        )
    try:
        dtype = np.lib.format.descr_to_dtype(header["descr"])
    except (
        TypeError,
        ValueError,
        KeyError,
        IndexError,
        OverflowError,
        MemoryError,
        RecursionError,
    ):
        descr = repr(header["descr"])[:60]
        raise FormatError(path, f"{where}{descr} is not a NumPy dtype") from None
    if dtype.hasobject:
        raise FormatError(
            path,
            f"{where}the array holds Python objects ({dtype}) that only pickle could read; "
            f"pointfield never unpickles files",
        )
    if dtype.itemsize == 0 or dtype.subdtype is not None:
        raise FormatError(path, f"{where}unsupported dtype {dtype}")
    return ArrayHeader(dtype, shape, fortran_order, start + length)


def read_array(path: Path) -> np.ndarray:
    """A ``.npy`` file's array, its declared size checked against the bytes present first.

    The array may view a memory map of the file (large files): copy what must outlive it.
    Also what scene readers use for ``.npy`` files (LLFF poses, depth maps).
    """
    size = path.stat().st_size
    with open(path, "rb") as file:
        header = read_array_header(file, path)
        available = size - header.size
        check_size(
            path, header.declared, header.count, header.dtype.itemsize, available, unit="values"
        )
        values = read_records(map_file(file), header.dtype, header.count, header.size)
    return values.reshape(header.shape, order="F" if header.fortran_order else "C")


def read_npy(path: Path) -> PointCloud | Records:
    """Read a ``.npy`` array as a cloud (see the module docstring for the layouts)."""
    array = read_array(path)
    cloud = cloud_from_array(array, path, "the array")
    del array  # unmaps the file: every output array was copied out of it
    cloud.metadata["encoding"] = "binary"
    return cloud


def cloud_from_array(array: np.ndarray, path: Path, what: str) -> PointCloud | Records:
    """A plain ``(N, 3+K)`` / ``(H, W, 3+K)`` array or a structured array as a cloud.

    Every array in the result is a new, native-byte-order copy, whatever ``array`` is (a memory
    map, a view of a buffer).
    """
    if array.dtype.names is None:
        return _cloud_from_plain(array, path, what)
    if array.ndim not in (1, 2):
        raise FormatError(
            path, f"{what}: a structured array of shape {array.shape}; expected (N,) or (H, W)"
        )
    n = math.prod(array.shape)
    columns = {
        name: _native_copy(array[name]).reshape(n, *array.dtype[name].shape)
        for name in array.dtype.names
    }
    points, fields = columns_to_cloud_parts(columns, path)
    if points is None:
        key = next(
            (
                name
                for name, values in columns.items()
                if name.lower() in POINT_KEYS
                and values.shape[1:] == (3,)
                and values.dtype.kind in "fiu"
            ),
            None,
        )
        if key is not None:
            points = _float_points(fields.pop(key))
    if points is None:
        return Records(fields, {})
    shape = array.shape if array.ndim == 2 else None
    return PointCloud(points, fields, shape, {})


def _cloud_from_plain(array: np.ndarray, path: Path, what: str) -> PointCloud:
    if array.dtype.kind not in "fiu" or array.ndim not in (2, 3) or array.shape[-1] < 3:
        raise FormatError(
            path,
            f"{what} is {array.dtype} of shape {array.shape}; expected numbers of shape "
            f"(N, 3+K) or (H, W, 3+K), or a structured array with x, y, z",
        )
    shape = array.shape[:2] if array.ndim == 3 else None
    flat = array.reshape(-1, array.shape[-1])
    points = _float_points(flat[:, :3])
    fields = {}
    if flat.shape[1] > 3:
        fields[FEATURES] = _native_copy(flat[:, 3:])
    return PointCloud(points, fields, shape, {})


def _float_points(values: np.ndarray) -> np.ndarray:
    """Points keep a float dtype; integer coordinates become float64."""
    if values.dtype.kind == "f":
        return _native_copy(values)
    return values.astype(np.float64)


def _native_copy(values: np.ndarray) -> np.ndarray:
    return np.array(values, dtype=values.dtype.newbyteorder("="), order="C", copy=True)


def write_npy(path: Path, cloud: PointCloud | Records, encoding: str | None = None) -> None:
    """Write ``cloud`` as one structured array ``x y z`` + its fields, lossless."""
    dtype, values_of = _record_layout(cloud)
    shape = getattr(cloud, "shape", None) or (len(cloud),)
    records = np.empty(shape, dtype)
    for name, values in values_of.items():
        records[name] = values.reshape(*shape, *values.shape[1:])
    with open(path, "wb") as file:
        np.lib.format.write_array(file, records, allow_pickle=False)


def _record_layout(cloud: PointCloud | Records) -> tuple[np.dtype, dict[str, np.ndarray]]:
    """The record dtype of ``cloud`` (``x y z`` in the points' dtype, then each field it can hold)
    and the values of each of its names; the fields it cannot hold are named in a warning."""
    points = getattr(cloud, "points", None)
    layout = []
    values_of = {}
    if points is not None:
        for i, axis in enumerate("xyz"):
            layout.append((axis, points.dtype))
            values_of[axis] = points[:, i]
    skipped = []
    taken = set(values_of)
    for name, values in cloud.fields.items():
        if not isinstance(name, str) or not name or name.lower() in taken or values.dtype.hasobject:
            skipped.append(name)
            continue
        layout.append((name, values.dtype, values.shape[1:]))
        values_of[name] = values
        taken.add(name.lower())
    if skipped:
        warnings.warn(
            f".npy cannot hold field(s) {', '.join(map(repr, skipped))} (names must be unique "
            f"and not x/y/z, values not Python objects); they were not written",
            stacklevel=4,
        )
    return np.dtype(layout), values_of


def open_npy_chunks(path: Path) -> RecordSource | None:
    """The rows of an ``(N, 3+K)`` / ``(H, W, 3+K)`` array, or the records of a structured one, as a
    :class:`RecordSource`; None (read whole) for a Fortran-ordered array or another shape."""
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


class NpyChunkWriter(BodyFirstWriter):
    """A structured ``.npy``: the record layout :func:`write_npy` chooses, taken from the
    first chunk, then the records; the header (with the count) at the end."""

    def _begin(self, cloud: PointCloud) -> None:
        super()._begin(cloud)
        self.dtype, _ = _record_layout(cloud)

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


register(
    Format(
        name="npy",
        description="NumPy .npy: (N, 3+K) array or structured array with x y z",
        suffixes=(".npy",),
        read=read_npy,
        write=write_npy,
        encodings=("binary",),
        signature=looks_like_npy,
        holds_records=True,
        open_chunks=open_npy_chunks,
        chunk_writer=lambda encoding: NpyChunkWriter,
    )
)
