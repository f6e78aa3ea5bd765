"""Writing LAS / LAZ: point format, extra dimensions, quantised coordinates and the header
metadata of a LAS cloud (see the package docstring)."""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from datetime import date
from pathlib import Path
from typing import Any
from uuid import UUID

import laspy
import numpy as np
from laspy.header import GlobalEncoding
from laspy.vlrs.vlrlist import VLRList

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.formats.las.dimensions import (
    COORDINATES,
    FORMATS,
    choose_point_format,
    extra_dimensions,
    fit,
    las_field_names,
    split_fields,
    version_for,
)
from pointfield.clouds.formats.las.library import library_errors
from pointfield.errors import FormatError
from pointfield.version import __version__

_DEFAULT_SCALE = 0.001
_INT32_MAX = 2**31 - 1


def write_las(path: Path, cloud: PointCloud, encoding: str | None = None) -> None:
    """Write ``cloud`` as LAS (``encoding="las"``) or LAZ (``"laz"``, the default for .laz)."""
    path = Path(path)
    compress = encoding == "laz"
    metadata = cloud.metadata
    notes: list[str] = []
    points, fields = _finite_points(cloud)
    format_id, standard, extra_params, extra_values = las_dimensions(fields, metadata, notes)
    if notes:
        warnings.warn("LAS changes these fields: " + "; ".join(notes), stacklevel=3)

    header = laspy.LasHeader(
        point_format=laspy.PointFormat(format_id), version=version_for(format_id, metadata)
    )
    with library_errors(path, "laspy could not write it"):
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


def refuse_copc_output(path: Path) -> None:
    """Refuse a ``.copc.laz`` output: pointfield writes LAZ without the octree a COPC reader needs.

    A COPC file is a LAZ file whose points are ordered by an octree, with a ``copc info`` VLR first
    and the octree's hierarchy in an EVLR; written as plain LAZ under that name, a COPC reader
    (laspy's ``CopcReader``, PDAL, QGIS) would fail on it or, worse, trust a stale index.
    """
    if path.name.lower().endswith(".copc.laz"):
        raise FormatError(
            path,
            "pointfield cannot write COPC (the octree ordering and hierarchy a COPC reader needs); "
            "write .laz and convert it with PDAL's writers.copc or untwine",
        )


def las_dimensions(
    fields: Mapping[str, np.ndarray], metadata: Mapping[str, Any], notes: list[str], format_id: int | None = None
) -> tuple[int, dict[str, np.ndarray], list, dict[str, np.ndarray]]:
    """Fields as LAS stores them: ``(point format, standard dimensions fitted to their types,
    extra-bytes parameters, extra-bytes values)``; what had to change is appended to ``notes``.

    Names are mapped and sanitised (:func:`las_field_names`); the point format is the smallest
    that holds the standard dimensions, unless ``format_id`` is given (a chunked writer keeps
    the one its header was opened with); standard names the format lacks become extra bytes.
    """
    standard, extra = split_fields(las_field_names(fields, notes), notes)
    if format_id is None:
        format_id = choose_point_format(standard, metadata)
    dimensions = FORMATS[format_id]
    for name in list(standard):
        if name not in dimensions:
            extra[name] = standard.pop(name)
    standard = {name: fit(name, values, dimensions[name], notes) for name, values in standard.items()}
    extra_params, extra_values = extra_dimensions(extra, set(dimensions), metadata, notes)
    return format_id, standard, extra_params, extra_values


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


def coordinates_fit(low: np.ndarray, high: np.ndarray, metadata: Mapping[str, Any]) -> bool:
    """Whether points from ``low`` to ``high`` fit the int32 coordinates of ``metadata``'s LAS scales and
    offsets, so that :func:`write_las` keeps them: then any subset of those points is written with them."""
    scales, offsets = _three_floats(metadata.get("scales")), _three_floats(metadata.get("offsets"))
    if scales is None or offsets is None or not np.all(scales > 0):
        return False
    return _in_int32(low, high, scales, offsets)


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
    for axis, name in enumerate(COORDINATES):
        coordinate = points[:, axis].astype(np.float64)
        records[name] = np.round((coordinate - header.offsets[axis]) / header.scales[axis])
    for name, values in standard.items():
        records[name] = values  # laspy packs bit fields into their bytes
    for name, values in extra.items():
        records.array[name] = values
    return records
