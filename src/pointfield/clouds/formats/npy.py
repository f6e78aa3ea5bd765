"""NumPy's ``.npy`` arrays and ``.npz`` archives of arrays.

``.npy`` holds one array:

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

``.npz`` is a zip of ``.npy`` members: ``points`` (or ``xyz`` / ``pos`` / ``positions``, or the
member named by ``points=``) ``(N, 3 + K)`` as above, or separate ``x``, ``y``, ``z`` members;
every other member whose first dimension is N is a field under its own name (members of other
shapes are skipped with a warning); ``__metadata__``, a JSON text, is the cloud's metadata.
Writing writes exactly that, ``stored`` (np.savez) or ``deflated`` (np.savez_compressed).

Nothing is ever unpickled: arrays of Python objects are a FormatError. Each header is parsed
and its declared shape checked against the bytes actually present (the file, or the zip
member's size, itself bounded by deflate's largest expansion of its compressed bytes) before
anything is allocated. A ``.npy`` is read through a read-only memory map, so memory holds the
output arrays and nothing more.
"""

from __future__ import annotations

import ast
import json
import math
import os
import warnings
import zipfile
import zlib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np

from pointfield.clouds.cloud import PointCloud, Records
from pointfield.clouds.formats.binary import check_size, map_file, read_records
from pointfield.clouds.formats.columns import columns_to_cloud_parts
from pointfield.clouds.formats.registry import Format, register
from pointfield.errors import FormatError

NPY_MAGIC = b"\x93NUMPY"
ZIP_MAGIC = b"PK\x03\x04"

POINT_KEYS = ("points", "xyz", "pos", "positions")
METADATA_KEY = "__metadata__"
FEATURES = "features"

# numpy's own headers are a few hundred bytes; a megabyte allows huge structured dtypes.
MAX_HEADER_BYTES = 1 << 20

# Deflate's densest code, a 258-byte match in 2 bits, expands at most 1032-fold: a member that
# claims more bytes than this per compressed byte is lying.
DEFLATE_MAX_EXPANSION = 1100

# An archive of more arrays than this is not a point cloud, and reading every header would be slow.
MAX_MEMBERS = 10_000

# Metadata that describes the file a cloud was read from, not the cloud.
FILE_METADATA = ("format", "encoding")


def looks_like_npy(head: bytes) -> bool:
    return head.startswith(NPY_MAGIC)


def looks_like_npz(head: bytes) -> bool:
    """A zip archive (no other point format is one; E57 and LAS have their own magic)."""
    return head.startswith(ZIP_MAGIC)


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


def _declared(header: ArrayHeader) -> str:
    return f"the header (a {header.dtype} array of shape {header.shape})"


# ----------------------------------------------------------------------------------------------
# .npy


def read_npy(path: Path) -> PointCloud | Records:
    """Read a ``.npy`` array as a cloud (see the module docstring for the layouts)."""
    size = path.stat().st_size
    with open(path, "rb") as file:
        header = read_array_header(file, path)
        available = size - header.size
        check_size(
            path, _declared(header), header.count, header.dtype.itemsize, available, unit="values"
        )
        values = read_records(map_file(file), header.dtype, header.count, header.size)
    array = values.reshape(header.shape, order="F" if header.fortran_order else "C")
    cloud = cloud_from_array(array, path, "the array")
    del array, values  # unmaps the file: every output array was copied out of it
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
            stacklevel=3,
        )
    shape = getattr(cloud, "shape", None) or (len(cloud),)
    records = np.empty(shape, np.dtype(layout))
    for name, values in values_of.items():
        records[name] = values.reshape(*shape, *values.shape[1:])
    with open(path, "wb") as file:
        np.lib.format.write_array(file, records, allow_pickle=False)


# ----------------------------------------------------------------------------------------------
# .npz


def read_npz(path: Path, points: str | None = None) -> PointCloud:
    """Read a ``.npz`` archive as a cloud; ``points`` names the member holding the points."""
    archive_size = path.stat().st_size
    try:
        with zipfile.ZipFile(path) as archive:
            members = _array_members(archive, path, archive_size)
            cloud = _cloud_from_members(archive, members, path, points)
            deflated = any(info.compress_type != zipfile.ZIP_STORED for info in members.values())
    except FormatError:
        raise
    except (
        zipfile.BadZipFile,
        zipfile.LargeZipFile,
        zlib.error,
        EOFError,
        OSError,
        RuntimeError,  # encrypted members
        NotImplementedError,  # compression methods zipfile lacks
        ValueError,
    ) as error:
        raise FormatError(path, f"not a readable .npz (zip) archive: {error}") from None
    cloud.metadata["encoding"] = "deflated" if deflated else "stored"
    return cloud


def _array_members(
    archive: zipfile.ZipFile, path: Path, archive_size: int
) -> dict[str, zipfile.ZipInfo]:
    """The archive's ``.npy`` members by name (without ``.npy``), their sizes checked."""
    if len(archive.infolist()) > MAX_MEMBERS:
        raise FormatError(
            path, f"{len(archive.infolist())} members; a point archive holds a few arrays"
        )
    members = {}
    for info in archive.infolist():
        if not info.filename.endswith(".npy"):
            continue
        expansion = 1 if info.compress_type == zipfile.ZIP_STORED else DEFLATE_MAX_EXPANSION
        limit = info.compress_size * expansion
        if info.compress_size > archive_size or info.file_size > limit:
            raise FormatError(
                path,
                f"member {info.filename!r} claims {info.file_size} bytes from "
                f"{info.compress_size} compressed bytes in a {archive_size}-byte file",
            )
        members[info.filename.removesuffix(".npy")] = info
    return members


def _cloud_from_members(
    archive: zipfile.ZipFile,
    members: Mapping[str, zipfile.ZipInfo],
    path: Path,
    points_key: str | None,
) -> PointCloud:
    """Points from the points member (or x, y, z members), fields from the per-point members."""
    lower = {name.lower(): name for name in members}
    if points_key is not None:
        if points_key not in members:
            raise FormatError(
                path, f"no member {points_key!r}; the archive holds {sorted(members)}"
            )
        key = points_key
    else:
        key = next((lower[k] for k in POINT_KEYS if k in lower), None)
    headers = {}
    for name, info in members.items():
        with archive.open(info) as stream:
            headers[name] = read_array_header(stream, path, name)
    cloud: PointCloud | None = None
    if key is not None:
        array = _read_member(archive, members[key], headers[key], path, key)
        found = cloud_from_array(array, path, f"member {key!r}")
        if not isinstance(found, PointCloud):
            raise FormatError(path, f"member {key!r} holds no x, y, z")
        cloud = found
        lead = cloud.shape or (len(cloud),)
    elif all(axis in lower for axis in "xyz"):
        lead = headers[lower["x"]].shape[:1]
    else:
        raise FormatError(
            path,
            f"no points: expected a member named {' / '.join(POINT_KEYS)} or members x, y, z; "
            f"the archive holds {sorted(members)} (name one with points='...')",
        )
    per_point = {
        name
        for name, h in headers.items()
        if name not in (key, METADATA_KEY) and h.shape[: len(lead)] == lead
    }
    columns = {}
    for name in members:
        if name in per_point:
            array = _read_member(archive, members[name], headers[name], path, name)
            flat = array.reshape(math.prod(lead), *array.shape[len(lead) :])
            columns[name] = np.ascontiguousarray(flat, flat.dtype.newbyteorder("="))
    if cloud is None:
        xyz, fields = columns_to_cloud_parts(columns, path)
        cloud = PointCloud(xyz, fields, None, {})  # type: ignore[arg-type]
    else:
        cloud.fields.update(columns)
    skipped = sorted(set(members) - per_point - {key, METADATA_KEY})
    if skipped:
        warnings.warn(
            f"{path}: member(s) {', '.join(map(repr, skipped))} are not one value per point; "
            f"they were not read",
            stacklevel=4,
        )
    if METADATA_KEY in members:
        cloud.metadata.update(
            _read_metadata(archive, members[METADATA_KEY], headers[METADATA_KEY], path)
        )
    return cloud


def _read_member(
    archive: zipfile.ZipFile, info: zipfile.ZipInfo, header: ArrayHeader, path: Path, name: str
) -> np.ndarray:
    """One member's array, after checking its declared size against the member's bytes."""
    check_size(
        path,
        f"member {name!r}: {_declared(header)}",
        header.count,
        header.dtype.itemsize,
        info.file_size - header.size,
        unit="values",
    )
    array = np.empty(header.count, header.dtype)
    buffer = memoryview(array.view(np.uint8).reshape(-1))
    with archive.open(info) as stream:
        stream.seek(header.size)
        filled = 0
        while filled < header.nbytes:
            got = stream.readinto(buffer[filled:])
            if not got:
                raise FormatError(
                    path, f"member {name!r} ends after {filled} of {header.nbytes} bytes"
                )
            filled += got
    if header.fortran_order:
        return array.reshape(header.shape[::-1]).transpose()
    return array.reshape(header.shape)


def _read_metadata(
    archive: zipfile.ZipFile, info: zipfile.ZipInfo, header: ArrayHeader, path: Path
) -> dict[str, Any]:
    text = _read_member(archive, info, header, path, METADATA_KEY)
    if text.dtype.kind != "U" or text.shape != ():
        raise FormatError(
            path,
            f"member {METADATA_KEY!r} must be one JSON string, not {text.dtype} {text.shape}",
        )
    try:
        metadata = json.loads(str(text[()]))
    except (ValueError, RecursionError):
        raise FormatError(path, f"member {METADATA_KEY!r} is not valid JSON") from None
    if not isinstance(metadata, dict):
        raise FormatError(path, f"member {METADATA_KEY!r} must be a JSON object")
    return metadata


def write_npz(path: Path, cloud: PointCloud, encoding: str | None = None) -> None:
    """Write ``points``, one member per field and ``__metadata__``, as np.savez lays them out.

    ``encoding`` ``stored`` (np.savez, the default) or ``deflated`` (np.savez_compressed).
    Organised clouds are written as ``(H, W, ...)`` arrays, which read back organised.
    """
    if not isinstance(cloud, PointCloud):
        raise FormatError(path, ".npz needs points; write records without x/y/z as .npy")
    lead = cloud.shape or (len(cloud),)
    arrays = {"points": cloud.points.reshape(*lead, 3)}
    skipped = []
    for name, values in cloud.fields.items():
        reserved = name in arrays or name == METADATA_KEY or name.lower() in POINT_KEYS
        if not isinstance(name, str) or not name or reserved or values.dtype.hasobject:
            skipped.append(name)
            continue
        arrays[name] = values.reshape(*lead, *values.shape[1:])
    if skipped:
        warnings.warn(
            f".npz cannot hold field(s) {', '.join(map(repr, skipped))} (names must be unique "
            f"and not a points key, values not Python objects); they were not written",
            stacklevel=3,
        )
    metadata = {k: v for k, v in cloud.metadata.items() if k not in FILE_METADATA}
    if metadata:
        try:
            arrays[METADATA_KEY] = np.array(json.dumps(metadata, default=_jsonable, allow_nan=True))
        except (TypeError, ValueError) as error:
            warnings.warn(
                f"metadata is not JSON-serialisable ({error}); it was not written", stacklevel=3
            )
    compression = zipfile.ZIP_DEFLATED if encoding == "deflated" else zipfile.ZIP_STORED
    with zipfile.ZipFile(path, "w", compression=compression, allowZip64=True) as archive:
        for name, values in arrays.items():
            with archive.open(name + ".npy", "w", force_zip64=True) as member:
                np.lib.format.write_array(member, np.asanyarray(values), allow_pickle=False)


def _jsonable(value: object) -> object:
    """numpy scalars and arrays in metadata as plain JSON numbers and lists."""
    if isinstance(value, np.ndarray | np.generic):
        return value.tolist()
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    raise TypeError(f"{type(value).__name__} is not JSON-serialisable")


register(
    Format(
        name="npy",
        description="NumPy .npy: (N, 3+K) array or structured array with x y z",
        suffixes=(".npy",),
        read=read_npy,
        write=write_npy,
        encodings=("binary",),
        signature=looks_like_npy,
    )
)
register(
    Format(
        name="npz",
        description="NumPy .npz archive: points + one array per field + JSON metadata",
        suffixes=(".npz",),
        read=read_npz,
        write=write_npz,
        encodings=("stored", "deflated"),
        aliases={"binary": "stored", "compressed": "deflated"},
        signature=looks_like_npz,
    )
)
