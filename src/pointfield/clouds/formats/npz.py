"""NumPy's ``.npz`` archives: a zip of ``.npy`` members, one array per member.

``points`` (or ``xyz`` / ``pos`` / ``positions``, or the member named by ``points=``)
``(N, 3 + K)`` or structured, read as a ``.npy`` array is (see
:mod:`~pointfield.clouds.formats.npy`), or separate ``x``, ``y``, ``z`` members; every other
member whose first dimension is N is a field under its own name (members of other shapes are
skipped with a warning); ``__metadata__``, a JSON text, is the cloud's metadata. Writing writes
exactly that, ``stored`` (np.savez) or ``deflated`` (np.savez_compressed).

Nothing is ever unpickled. Each member's header is parsed as a ``.npy`` header is and its
declared shape checked against the member's size, itself checked against the compressed bytes
(deflate's largest expansion) and the archive, before anything is allocated.
"""

from __future__ import annotations

import json
import math
import os
import warnings
import zipfile
import zlib
from collections.abc import Collection, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.formats.binary import check_size
from pointfield.clouds.formats.columns import columns_to_cloud_parts
from pointfield.clouds.formats.npy import (
    POINT_KEYS,
    ArrayHeader,
    cloud_from_array,
    read_array_header,
)
from pointfield.clouds.formats.registry import Format, register
from pointfield.errors import FormatError

ZIP_MAGIC = b"PK\x03\x04"

METADATA_KEY = "__metadata__"

# Deflate's densest code, a 258-byte match in 2 bits, expands at most 1032-fold: a member that
# claims more bytes than this per compressed byte is lying.
DEFLATE_MAX_EXPANSION = 1100

# An archive of more arrays than this is not a point cloud, and reading every header would be slow.
MAX_MEMBERS = 10_000

# Metadata that describes the file a cloud was read from, not the cloud.
FILE_METADATA = ("format", "encoding")


def looks_like_npz(head: bytes) -> bool:
    """A zip archive (no other point format is one; E57 and LAS have their own magic)."""
    return head.startswith(ZIP_MAGIC)


# What zipfile raises for an archive it cannot read.
_ZIP_ERRORS = (
    zipfile.BadZipFile,
    zipfile.LargeZipFile,
    zlib.error,
    EOFError,
    OSError,
    RuntimeError,  # encrypted members
    NotImplementedError,  # compression methods zipfile lacks
    ValueError,
)


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
    except _ZIP_ERRORS as error:
        raise FormatError(path, f"not a readable .npz (zip) archive: {error}") from None
    cloud.metadata["encoding"] = "deflated" if deflated else "stored"
    return cloud


def read_member_headers(path: Path) -> dict[str, ArrayHeader]:
    """Each array member's ``.npy`` header by name (without ``.npy``), its sizes checked as
    :func:`read_npz` checks them; no array is read."""
    try:
        with zipfile.ZipFile(path) as archive:
            members = _array_members(archive, path, path.stat().st_size)
            return _member_headers(archive, members, path)
    except FormatError:
        raise
    except _ZIP_ERRORS as error:
        raise FormatError(path, f"not a readable .npz (zip) archive: {error}") from None


def points_members(names: Collection[str]) -> tuple[str, ...]:
    """The members that hold the points, any case: the first of :data:`POINT_KEYS` present, else
    ``x``, ``y`` and ``z``; ``()`` when there are none."""
    lower = {name.lower(): name for name in names}
    key = next((lower[key] for key in POINT_KEYS if key in lower), None)
    if key is not None:
        return (key,)
    return tuple(lower[axis] for axis in "xyz") if all(axis in lower for axis in "xyz") else ()


def _member_headers(
    archive: zipfile.ZipFile, members: Mapping[str, zipfile.ZipInfo], path: Path
) -> dict[str, ArrayHeader]:
    headers = {}
    for name, info in members.items():
        with archive.open(info) as stream:
            headers[name] = read_array_header(stream, path, name)
    return headers


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
    if points_key is not None and points_key not in members:
        raise FormatError(path, f"no member {points_key!r}; the archive holds {sorted(members)}")
    found = (points_key,) if points_key is not None else points_members(members)
    key = found[0] if len(found) == 1 else None
    headers = _member_headers(archive, members, path)
    cloud: PointCloud | None = None
    if key is not None:
        array = _read_member(archive, members[key], headers[key], path, key)
        read = cloud_from_array(array, path, f"member {key!r}")
        if not isinstance(read, PointCloud):
            raise FormatError(path, f"member {key!r} holds no x, y, z")
        cloud = read
        lead = cloud.shape or (len(cloud),)
    elif found:  # x, y, z members
        lead = headers[found[0]].shape[:1]
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
        f"member {name!r}: {header.declared}",
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
