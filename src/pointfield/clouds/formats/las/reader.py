"""Reading LAS / LAZ / COPC: the records, then every dimension as a field (see the package
docstring)."""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from functools import partial
from pathlib import Path
from typing import Any, BinaryIO

import laspy
import numpy as np
from laspy.point import dims as laspy_dims

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.formats.binary import map_file, read_records
from pointfield.clouds.formats.columns import columns_to_cloud_parts, group_components
from pointfield.clouds.formats.las.dimensions import COLOR_DIMENSIONS, COORDINATES
from pointfield.clouds.formats.las.layout import (
    LASZIP_RECORD_ID,
    LASZIP_USER_ID,
    Layout,
    check_layout,
    laz_backends,
)
from pointfield.clouds.formats.las.library import library_errors, rust_panics_quiet
from pointfield.errors import FormatError

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
_REGENERATED_RECORDS = {(LASZIP_USER_ID, LASZIP_RECORD_ID), ("LASF_Spec", 4)}
_REGENERATED_USER_IDS = {"copc"}


def read_las(path: Path) -> PointCloud:
    """Read a LAS, LAZ or COPC file into a PointCloud with float64 points (see module doc)."""
    path = Path(path)
    size = path.stat().st_size
    with open(path, "rb") as file:
        layout = check_layout(path, file, size)
        if layout.compressed:
            header, records = _read_laz(path, file, layout, size)
        else:
            with library_errors(path, "laspy could not read it"):
                file.seek(0)
                header = laspy.LasReader(file, closefd=False).header
                records = _map_records(path, file, header, layout)
    points, fields = cloud_parts(records, header, path)
    # The fields are copies, so dropping the records releases the mapping of the file.
    del records
    return PointCloud(points, fields, None, _metadata(header, layout))


def _read_laz(
    path: Path, file: BinaryIO, layout: Layout, size: int
) -> tuple[laspy.LasHeader, np.ndarray]:
    """The header and point records of a LAZ file, by lazrs or, where it fails, by LASzip.

    A failure of every decompressor is one FormatError giving each one's reason; the report
    Rust prints when lazrs panics is kept off standard error (one capture for the whole read,
    chunk table included: each costs a temporary file and two dup2 calls).
    """
    failures = []
    with rust_panics_quiet():
        for backend in laz_backends(path, file, layout, size):
            name = "LASzip" if backend is laspy.LazBackend.Laszip else "lazrs"
            try:
                with library_errors(path, f"{name} could not read it"):
                    file.seek(0)
                    reader = laspy.LasReader(file, closefd=False, laz_backend=backend)
                    return reader.header, _decompress(path, reader, layout, size)
            except FormatError as error:
                failures.append(error.reason)
    raise FormatError(path, "; ".join(failures))


def _decompress(path: Path, reader: laspy.LasReader, layout: Layout, size: int) -> np.ndarray:
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
    path: Path, file: BinaryIO, header: laspy.LasHeader, layout: Layout
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


def cloud_parts(
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
        for axis, name in enumerate(COORDINATES)
    ]
    # laspy's table of which bits of which packed byte hold each bit field (LAS 1.4 tables 7, 15).
    bit_fields = laspy_dims.get_sub_fields_dict(point_format.id)
    color_names = _color_dimensions(point_format)
    columns: dict[str, np.ndarray] = {}
    for dimension in point_format.dimensions:
        name = dimension.name
        if name in COORDINATES or name in color_names[1:]:
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
    if not names.issuperset(COLOR_DIMENSIONS):
        return ()
    alpha = next((d for d in point_format.extra_dimensions if d.name == "alpha"), None)
    if alpha is not None and not alpha.is_scaled and point_format.dtype()["alpha"] == np.uint16:
        return (*COLOR_DIMENSIONS, "alpha")
    return COLOR_DIMENSIONS


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


def _metadata(header: laspy.LasHeader, layout: Layout) -> dict[str, Any]:
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
