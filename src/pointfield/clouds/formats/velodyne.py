"""Raw float32 LiDAR scans (``.bin``): KITTI, nuScenes, ScanNet.

A scan is nothing but N records of ``columns`` little-endian float32 values, with no header, so
the file cannot say how many columns it has: ``columns=`` does (``--columns`` on the command
line). Without it the layout is chosen between KITTI's 4 and nuScenes' 5 columns, on this
evidence, strongest first:

1. the file size: a whole number of 16-byte or of 20-byte records;
2. the values (of some 8,000 records at the start and as many in the middle): a layout fits
   when its x y z are finite numbers below 10**6, in each axis at most half of them non-zero
   whole numbers (coordinates are measurements, not counts; checked from 16 points on), its
   intensity column is finite and not negative, and, for 5 columns, its ring column holds
   whole numbers from 0 to 1023. Read under the wrong layout, a scan's columns interleave,
   coordinates land in the intensity and ring columns, and these checks fail;
3. the name: a ``.pcd.bin`` suffix or ``LIDAR_TOP`` in it (nuScenes' sweeps) says 5, else 4.

A single fitting layout is read (with a warning when the name said otherwise); two are decided
by the name; none is a FormatError that names ``columns=`` and the counts the size allows, so
a scan of another layout (ScanNet's 6 columns) is refused rather than read as garbage. The
guess reads two 160 KB blocks: on a 120,000-point KITTI scan, 0.5 ms on top of a 0.7 ms read
(one 2-core CPU, warm page cache); ``columns=`` skips it.

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
is read back surely only with the same ``columns=``; a warning says which.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.formats.binary import map_file, read_records
from pointfield.clouds.formats.chunked import ChunkWriter, RecordSource
from pointfield.clouds.formats.registry import Format, register
from pointfield.errors import FormatError

DEFAULT_COLUMNS = 4
NUSCENES_COLUMNS = 5
GUESSED_COLUMNS = (DEFAULT_COLUMNS, NUSCENES_COLUMNS)
LAYOUT_NAMES = {4: "KITTI's x y z intensity", 5: "nuScenes' x y z intensity ring"}
RECORD_DTYPE = np.dtype("<f4")

# What a layout's values must look like to be read without columns= (see the module docstring).
SAMPLE_RECORDS = 8192
MAX_COORDINATE = 1e6
MIN_RECORDS_FOR_COUNTS = 16
MAX_RING = 1023

# Column counts to suggest when a file's size does not fit the one asked for.
SUGGESTED_COLUMNS = range(3, 17)


def read_velodyne(path: Path, columns: int | None = None) -> PointCloud:
    """Read a raw float32 scan of ``columns`` values per point, or of the layout its size,
    values and name call for when ``columns`` is None (see the module docstring)."""
    if columns is None:
        columns = guess_columns(path)
    if isinstance(columns, bool) or not isinstance(columns, (int, np.integer)) or columns < 3:
        raise FormatError(path, f"columns={columns!r}; expected an integer >= 3 (x y z first)")
    columns = int(columns)
    size = path.stat().st_size
    if size == 0:
        raise FormatError(path, "empty file: a float32 scan holds at least one point")
    record = RECORD_DTYPE.itemsize * columns
    if size % record:
        raise FormatError(
            path,
            f"{size} bytes is not a whole number of {columns}-column float32 records "
            f"({record} bytes each){_dividing_hint(size)}",
        )
    # A read-only map of the file: each output array is copied out of it once, so memory holds
    # the output and nothing more.
    with open(path, "rb") as file:
        records = read_records(map_file(file), np.dtype((RECORD_DTYPE, columns)), size // record)
    return cloud_from_records(records)


def cloud_from_records(records: np.ndarray) -> PointCloud:
    """The cloud of ``(N, columns)`` float32 records, fields named by the table above."""
    columns = records.shape[1]
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
    return PointCloud(points, fields, None, {"encoding": "float32", "columns": columns})


def guess_columns(path: Path) -> int:
    """4 (KITTI) or 5 (nuScenes): the layout the file's size, values and name call for.

    Raises FormatError naming ``columns=`` when neither layout fits (see the module docstring).
    """
    size = path.stat().st_size
    if size == 0:
        raise FormatError(path, "empty file: a float32 scan holds at least one point")
    sized = [c for c in GUESSED_COLUMNS if size % (RECORD_DTYPE.itemsize * c) == 0]
    if not sized:
        raise FormatError(
            path,
            f"{size} bytes is a whole number of neither 4-column (KITTI) nor 5-column "
            f"(nuScenes) float32 records{_dividing_hint(size)}",
        )
    sample = _sample(path, size)
    reasons = {c: _implausible(sample, c) for c in sized}
    fitting = [c for c in sized if reasons[c] is None]
    named = NUSCENES_COLUMNS if _named_like_nuscenes(path) else DEFAULT_COLUMNS
    if not fitting:
        why = "; ".join(f"as {c} columns {reasons[c]}" for c in sized)
        raise FormatError(
            path,
            f"the values fit neither KITTI's 4 nor nuScenes' 5 float32 columns ({why}); give "
            f"the layout with columns= (--columns on the command line){_dividing_hint(size)}",
        )
    if named in fitting:
        return named
    chosen = fitting[0]
    told = "its name says nuScenes (5 columns), but " if named == NUSCENES_COLUMNS else ""
    warnings.warn(
        f"{path}: {told}its size and values fit {LAYOUT_NAMES[chosen]} only: read as "
        f"{chosen} float32 columns (columns= chooses)",
        stacklevel=4,
    )
    return chosen


def _named_like_nuscenes(path: Path) -> bool:
    return path.name.lower().endswith(".pcd.bin") or "LIDAR_TOP" in path.name


def _sample(path: Path, size: int) -> np.ndarray:
    """Float32 values of the first and the middle records, cut where both layouts' records end."""
    block = SAMPLE_RECORDS * RECORD_DTYPE.itemsize * 5  # whole records of 4 and of 5 columns
    with open(path, "rb") as file:
        head = file.read(block)
        middle = b""
        if size > 2 * block:
            file.seek((size // 2) // block * block)
            middle = file.read(block)
    return np.frombuffer(head + middle, RECORD_DTYPE).astype(np.float64)


def _implausible(values: np.ndarray, columns: int) -> str | None:
    """Why ``values`` read as ``columns``-column records are not a scan, or None if they may be."""
    records = values[: len(values) // columns * columns].reshape(-1, columns)
    # Column by column: numpy's reductions across a row of three are ten times slower, and this
    # runs on every .bin read without columns=.
    x, y, z = records[:, 0], records[:, 1], records[:, 2]
    measured = np.isfinite(x) & np.isfinite(y) & np.isfinite(z)  # NaN rows: no return
    if not measured.any():
        return None if len(records) else "no records"
    coordinates = [axis[measured] for axis in (x, y, z)]
    largest = max(np.abs(axis).max() for axis in coordinates)
    if largest >= MAX_COORDINATE:
        return f"gives coordinates of {largest:.3g}"
    if len(coordinates[0]) >= MIN_RECORDS_FOR_COUNTS and any(
        ((axis == np.round(axis)) & (axis != 0)).mean() > 0.5 for axis in coordinates
    ):
        return "gives coordinates that are mostly whole numbers (counts or colours?)"
    intensity = records[:, 3]
    if not np.isfinite(intensity).all() or intensity.min() < 0:
        return "gives negative or non-finite intensities"
    if columns == NUSCENES_COLUMNS:
        ring = records[:, 4]
        if not (np.isfinite(ring).all() and (ring == np.round(ring)).all()):
            return "gives ring numbers that are not whole numbers"
        if ring.min() < 0 or ring.max() > MAX_RING:
            return f"gives ring numbers from {ring.min():g} to {ring.max():g}"
    return None


def _dividing_hint(size: int) -> str:
    fitting = [c for c in SUGGESTED_COLUMNS if size % (RECORD_DTYPE.itemsize * c) == 0]
    if fitting:
        return f"; columns={', '.join(map(str, fitting))} would divide it"
    return "; no column count from 3 to 16 divides it, so it is not a float32 scan"


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


def open_velodyne_chunks(path: Path, columns: int | None = None) -> RecordSource:
    """The scan's float32 records as a :class:`RecordSource`; ``columns`` guessed as :func:`read_velodyne` does."""
    columns = guess_columns(path) if columns is None else columns
    size = path.stat().st_size
    record = RECORD_DTYPE.itemsize * columns if isinstance(columns, int) and columns >= 3 else 0
    if not record or size == 0 or size % record:
        read_velodyne(path, columns)  # raises the reader's own error for this file
    dtype = np.dtype((RECORD_DTYPE, columns))

    def convert(records: np.ndarray) -> PointCloud:
        return cloud_from_records(records.reshape(-1, columns))

    return RecordSource(path, dtype, 0, size // record, convert, "velodyne")


class VelodyneChunkWriter(ChunkWriter):
    """Raw float32 scans: no header, the records of each chunk appended by :func:`write_velodyne`."""

    def _begin(self, cloud: PointCloud) -> None:
        self.file = open(self.tmp, "wb")  # noqa: SIM115 -- open across write calls, closed in _finish

    def _write(self, cloud: PointCloud) -> None:
        if len(cloud):
            write_velodyne(self.file, cloud)  # its records go to the open file's end

    def _finish(self) -> None:
        self.file.close()
        if self.count == 0:
            raise FormatError(
                self.path, "a float32 scan cannot hold zero points (an empty .bin reads as an error)"
            )

    def _cleanup(self) -> None:
        if hasattr(self, "file"):
            self.file.close()


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
        open_chunks=open_velodyne_chunks,
        chunk_options=("columns",),
        chunk_writer=lambda encoding: VelodyneChunkWriter,
    )
)
