"""Writing E57: one scan per ``scan_index`` value, its prototype and records through libE57
(see the package docstring)."""

from __future__ import annotations

import json
import uuid
from collections.abc import Mapping
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.formats.e57.elements import (
    CARTESIAN,
    COLORS,
    FIELD_TABLE,
    NORMALS_URI,
    POINTFIELD_PREFIX,
    POINTFIELD_URI,
    Column,
    elements_from_fields,
    field_table,
    integer_range,
)
from pointfield.clouds.formats.e57.library import (
    buffer_array,
    library_errors,
    load_pye57,
)
from pointfield.errors import FormatError


def write_e57(path: Path, cloud: PointCloud, encoding: str | None = None) -> None:
    """Write ``cloud`` as an E57 file, one scan per ``scan_index`` value (see the package
    docstring)."""
    path = Path(path)
    pye57 = load_pye57(path)
    order, scan_ranges, scan_dtype = _scan_split(path, cloud)
    points = cloud.points[order] if order is not None else cloud.points
    columns = elements_from_fields(cloud, order)
    shape = cloud.shape if len(scan_ranges) == 1 else None
    table = field_table(columns, scan_dtype, shape)
    names = [
        scan.get("name")
        for scan in cloud.metadata.get("e57_scans") or []
        if isinstance(scan, Mapping)
    ]

    with library_errors(path, "libE57 could not write it"):
        e57 = pye57.E57(str(path), mode="w")
    try:
        with library_errors(path, "libE57 could not write it"):
            libe57 = pye57.libe57
            imf = e57.image_file
            if any(c.element.startswith("nor:") for c in columns):
                imf.extensionsAdd("nor", NORMALS_URI)
            imf.extensionsAdd(POINTFIELD_PREFIX, POINTFIELD_URI)
            e57.root.set(FIELD_TABLE, libe57.StringNode(imf, json.dumps(table)))
            for index, rows in enumerate(scan_ranges):
                name = (
                    names[index]
                    if index < len(names) and isinstance(names[index], str)
                    else f"scan {index}"
                )
                _write_scan(libe57, e57, name, points[rows], [(c, c.values[rows]) for c in columns])
    except BaseException:
        e57.image_file.cancel()
        raise
    else:
        with library_errors(path, "libE57 could not finish it"):
            e57.close()


def _scan_split(
    path: Path, cloud: PointCloud
) -> tuple[np.ndarray | None, list[slice], np.dtype | None]:
    """Point order (None: as is), row ranges of the scans, and the dtype of ``scan_index``."""
    scan_index = cloud.fields.get("scan_index")
    count = len(cloud.points)
    if scan_index is None or scan_index.ndim != 1 or scan_index.dtype.kind not in "biu":
        return None, [slice(0, count)], None
    if count and scan_index.min() < 0:
        raise FormatError(path, "scan_index has negative values; E57 scans are numbered from 0")
    scans = int(scan_index.max()) + 1 if count else 1
    if scans > max(count, 1) and scans > 65536:
        raise FormatError(
            path, f"scan_index up to {scans - 1} would make {scans} mostly empty scans"
        )
    order = None
    if count and np.any(np.diff(scan_index.astype(np.int64)) < 0):
        order = np.argsort(scan_index, kind="stable")
        scan_index = scan_index[order]
    bounds = np.searchsorted(scan_index, np.arange(scans + 1))
    return order, [slice(int(a), int(b)) for a, b in pairwise(bounds)], scan_index.dtype


def _write_scan(
    libe57: Any, e57: Any, name: str, points: np.ndarray, columns: list[tuple[Column, np.ndarray]]
) -> None:
    """Append one scan: its header nodes, its prototype and its records."""
    imf = e57.image_file
    scan = libe57.StructureNode(imf)
    scan.set("guid", libe57.StringNode(imf, f"{{{uuid.uuid4()}}}"))
    scan.set("name", libe57.StringNode(imf, name))
    finite = points[np.isfinite(points).all(axis=1)]
    if len(finite):
        bounds = libe57.StructureNode(imf)
        lows, highs = finite.min(axis=0), finite.max(axis=0)
        for axis, low, high in zip("xyz", lows, highs, strict=True):
            bounds.set(f"{axis}Minimum", libe57.FloatNode(imf, float(low)))
            bounds.set(f"{axis}Maximum", libe57.FloatNode(imf, float(high)))
        scan.set("cartesianBounds", bounds)
    _set_color_limits(libe57, imf, scan, columns)

    prototype = libe57.StructureNode(imf)
    precision = libe57.E57_DOUBLE if points.dtype == np.float64 else libe57.E57_SINGLE
    arrays = []
    for axis, element in enumerate(CARTESIAN):
        prototype.set(element, _float_node(libe57, imf, precision))
        arrays.append((element, np.ascontiguousarray(points[:, axis], np.float64)))
    for column, values in columns:
        prototype.set(column.element, _node(libe57, imf, values.dtype))
        arrays.append((column.element, buffer_array(values)))
    compressed = libe57.CompressedVectorNode(imf, prototype, libe57.VectorNode(imf, True))
    scan.set("points", compressed)
    e57.data3d.append(scan)  # libE57 writes records only into a node already in the tree

    count = len(points)
    buffers = libe57.VectorSourceDestBuffer()
    for element, array in arrays:
        buffers.append(libe57.SourceDestBuffer(imf, element, array, max(count, 1), True, True))
    writer = compressed.writer(buffers)
    try:
        if count:
            writer.write(count)
    finally:
        writer.close()


def _set_color_limits(
    libe57: Any, imf: Any, scan: Any, columns: list[tuple[Column, np.ndarray]]
) -> None:
    """colorLimits, which readers scale colours by: the dtype's range for integer colours
    (0..255 for uint8), the values' range for float ones."""
    colors = [values for column, values in columns if column.element in COLORS]
    if len(colors) != 3:
        return
    limits = libe57.StructureNode(imf)
    if colors[0].dtype.kind == "f":
        finite = np.concatenate(colors)[np.isfinite(np.concatenate(colors))]
        low, high = (float(finite.min()), float(finite.max())) if len(finite) else (0.0, 1.0)
        make = libe57.FloatNode
    else:
        low, high = integer_range(colors[0].dtype)
        make = libe57.IntegerNode
    for element in COLORS:
        limits.set(f"{element}Minimum", make(imf, low))
        limits.set(f"{element}Maximum", make(imf, high))
    scan.set("colorLimits", limits)


def _float_node(libe57: Any, imf: Any, precision: Any) -> Any:
    if precision == libe57.E57_SINGLE:
        limit = float(np.finfo(np.float32).max)
        return libe57.FloatNode(imf, 0.0, precision, -limit, limit)
    return libe57.FloatNode(imf, 0.0, precision)


def _node(libe57: Any, imf: Any, dtype: np.dtype) -> Any:
    """The prototype node for values of ``dtype``: a float of its precision, or an integer
    spanning the dtype's range (so that reading gives the same dtype back)."""
    if dtype.kind == "f":
        return _float_node(
            libe57, imf, libe57.E57_SINGLE if dtype.itemsize <= 4 else libe57.E57_DOUBLE
        )
    low, high = integer_range(dtype)
    return libe57.IntegerNode(imf, max(low, 0) if low <= 0 <= high else low, low, high)
