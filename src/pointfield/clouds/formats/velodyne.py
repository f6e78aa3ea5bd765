"""Raw float32 LiDAR scans (``.bin``): KITTI, nuScenes, ScanNet.

A scan is nothing but N records of ``columns`` little-endian float32 values, with no header, so
the file cannot say how many columns it has: ``columns=`` does (KITTI's 4 by default).

=======  ========================  ==========================================================
columns  dataset                   fields
=======  ========================  ==========================================================
4        KITTI, SemanticKITTI      x y z, ``intensity`` (N,) (reflectance, 0..1)
5        nuScenes                  x y z, ``intensity`` (N,), ``ring`` (N,) (laser index)
6        ScanNet (mmdetection3d)   x y z, ``colors`` (N, 3) (r g b, 0..255 as float32)
3        --                        x y z only
other    --                        x y z, ``features`` (N, columns - 3)
=======  ========================  ==========================================================

Every value, points and fields, is float32: the format has no other type. The file size must be
a multiple of ``4 * columns`` bytes; if it is not, the FormatError lists the column counts that
would divide it. An empty file is a FormatError (a scan has points; an empty ``.bin`` is a failed
download far more often than an empty scan), so an empty cloud cannot be written either.

Writing picks the layout from the cloud's fields: ``intensity`` [+ ``ring``] -> 4 [5] columns;
else ``colors`` (N, 3) -> 6; else ``features`` (N, K) -> 3 + K (for K < 4 that reads back
under the names of the 4, 5 or 6 column layouts); else 3. Anything else is left out with a
warning. Every value is cast to float32; a warning says so when that changes a value
(float64 coordinates far from the origin lose digits). A layout other than KITTI's 4 columns
reads back only with the same ``columns=``; a warning says which.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.formats.binary import map_file, read_records
from pointfield.clouds.formats.registry import Format, register
from pointfield.errors import FormatError

DEFAULT_COLUMNS = 4
RECORD_DTYPE = np.dtype("<f4")

# Column counts to suggest when a file's size does not fit the one asked for.
SUGGESTED_COLUMNS = range(3, 17)


def read_velodyne(path: Path, columns: int = DEFAULT_COLUMNS) -> PointCloud:
    """Read a raw float32 scan of ``columns`` values per point (see the module docstring)."""
    if isinstance(columns, bool) or not isinstance(columns, (int, np.integer)) or columns < 3:
        raise FormatError(path, f"columns={columns!r}; expected an integer >= 3 (x y z first)")
    columns = int(columns)
    size = path.stat().st_size
    if size == 0:
        raise FormatError(path, "empty file: a float32 scan holds at least one point")
    record = RECORD_DTYPE.itemsize * columns
    if size % record:
        fitting = [c for c in SUGGESTED_COLUMNS if size % (RECORD_DTYPE.itemsize * c) == 0]
        hint = (
            f"; columns={', '.join(map(str, fitting))} would divide it"
            if fitting
            else "; no column count from 3 to 16 divides it, so it is not a float32 scan"
        )
        raise FormatError(
            path,
            f"{size} bytes is not a whole number of {columns}-column float32 records "
            f"({record} bytes each){hint}",
        )
    # A read-only map of the file: each output array is copied out of it once, so memory holds
    # the output and nothing more.
    with open(path, "rb") as file:
        records = read_records(map_file(file), np.dtype((RECORD_DTYPE, columns)), size // record)
    points = records[:, :3].astype(np.float32)
    fields = {}
    if columns == 4 or columns == 5:
        fields["intensity"] = records[:, 3].astype(np.float32)
    if columns == 5:
        fields["ring"] = records[:, 4].astype(np.float32)
    if columns == 6:
        fields["colors"] = records[:, 3:6].astype(np.float32)
    if columns > 6:
        fields["features"] = records[:, 3:].astype(np.float32)
    del records
    return PointCloud(points, fields, None, {"encoding": "float32", "columns": columns})


def write_velodyne(path: Path, cloud: PointCloud, encoding: str | None = None) -> None:
    """Write ``cloud`` as raw float32 records in the layout its fields call for."""
    if len(cloud) == 0:
        raise FormatError(
            path, "a float32 scan cannot hold zero points (an empty .bin reads as an error)"
        )
    parts = [("points", cloud.points)]
    fields = cloud.fields
    if _is_vector(fields.get("intensity")):
        parts.append(("intensity", fields["intensity"][:, None]))
        if _is_vector(fields.get("ring")):
            parts.append(("ring", fields["ring"][:, None]))
    elif _is_matrix(fields.get("colors"), 3):
        parts.append(("colors", fields["colors"]))
    elif _is_matrix(fields.get("features"), None):
        parts.append(("features", fields["features"]))
    written = {name for name, _ in parts}
    dropped = [name for name in fields if name not in written]
    if dropped:
        warnings.warn(
            f"a float32 scan holds x y z and one of intensity [ring], colors or features; "
            f"field(s) {', '.join(map(repr, dropped))} were not written",
            stacklevel=3,
        )
    records = np.empty((len(cloud), sum(values.shape[1] for _, values in parts)), RECORD_DTYPE)
    start = 0
    lossy = []
    for name, values in parts:
        stop = start + values.shape[1]
        records[:, start:stop] = values
        if values.dtype != RECORD_DTYPE and not np.array_equal(
            records[:, start:stop], values, equal_nan=True
        ):
            lossy.append(name)
        start = stop
    if lossy:
        warnings.warn(
            f"float32 scans hold float32 only; {', '.join(lossy)} changed when rounded to float32",
            stacklevel=3,
        )
    if records.shape[1] != DEFAULT_COLUMNS:
        warnings.warn(
            f"the scan is written with {records.shape[1]} columns per point; read it back with "
            f"columns={records.shape[1]}",
            stacklevel=3,
        )
    records.tofile(path)


def _is_vector(values: np.ndarray | None) -> bool:
    return values is not None and values.ndim == 1 and values.dtype.kind in "biuf"


def _is_matrix(values: np.ndarray | None, width: int | None) -> bool:
    return (
        values is not None
        and values.ndim == 2
        and (width is None or values.shape[1] == width)
        and values.dtype.kind in "biuf"
    )


register(
    Format(
        name="velodyne",
        description="raw float32 LiDAR scans (KITTI x y z intensity; nuScenes, ScanNet)",
        suffixes=(".bin",),
        read=read_velodyne,
        write=write_velodyne,
        encodings=("float32",),
        aliases={"binary": "float32"},
        signature=None,
    )
)
