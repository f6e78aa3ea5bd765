"""Reading E57: each scan's prototype, pose and records, merged into one cloud in the file's
frame (see the package docstring)."""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.formats.e57.elements import (
    CARTESIAN,
    FIELD_TABLE,
    NORMALS,
    POINTFIELD_PREFIX,
    POINTFIELD_URI,
    SPHERICAL,
    fields_from_elements,
    smallest_integer,
)
from pointfield.clouds.formats.e57.layout import check_file_header, check_record_counts
from pointfield.clouds.formats.e57.library import (
    BUFFER_DTYPES,
    LONG_LONG,
    library_errors,
    load_pye57,
)
from pointfield.errors import FormatError


@dataclass
class _Element:
    """One per-point element of a scan's prototype, and how it is read."""

    name: str
    dtype: np.dtype  # the field's natural dtype
    bits: int  # bits one value takes in the file, at least


@dataclass
class _Scan:
    """One scan of the file, described before its records are read."""

    node: Any
    count: int
    elements: dict[str, _Element]
    rotation: np.ndarray  # (3, 3)
    translation: np.ndarray  # (3,)
    metadata: dict[str, Any]  # what read_e57 reports about the scan

    @property
    def bits(self) -> int:
        """Bits one record takes in the file, at least."""
        return sum(element.bits for element in self.elements.values())


def read_e57(path: Path) -> PointCloud:
    """Read every scan of an E57 file into one PointCloud (see the package docstring)."""
    path = Path(path)
    pye57 = load_pye57(path)
    size = path.stat().st_size
    check_file_header(path, size)
    with library_errors(path, "libE57 could not open it"):
        e57 = pye57.E57(str(path), mode="r")
    try:
        with library_errors(path, "libE57 could not read it"):
            scans = [
                _describe_scan(path, pye57, e57.data3d[index], index)
                for index in range(e57.scan_count)
            ]
            table = _field_table(e57)
        check_record_counts(
            path, [scan.count for scan in scans], [scan.bits for scan in scans], size
        )
        columns, points = _read_scans(path, pye57, e57, scans)
    finally:
        e57.close()
    fields, shape = fields_from_elements(columns, table, len(points))
    metadata = {"encoding": "e57", "e57_scans": [scan.metadata for scan in scans]}
    return PointCloud(points, fields, shape, metadata)


def _describe_scan(path: Path, pye57: Any, node: Any, index: int) -> _Scan:
    """The elements, record count and pose of one scan, without reading its points."""
    libe57 = pye57.libe57
    points = node["points"]
    prototype = libe57.StructureNode(points.prototype())
    elements = {}
    for child in range(prototype.childCount()):
        element = _element(pye57.utils.get_node(prototype, child))
        if element is not None:
            elements[element.name] = element
    count = int(points.childCount())
    if count < 0:
        raise FormatError(path, f"scan {index} declares {count} records")
    rotation, translation, quaternion = _pose(pye57, node)
    coordinates = "cartesian" if all(n in elements for n in CARTESIAN) else "spherical"
    if coordinates == "spherical" and not all(n in elements for n in SPHERICAL):
        raise FormatError(
            path,
            f"scan {index} has neither cartesian nor spherical coordinates ({sorted(elements)})",
        )
    metadata = {
        "name": _string(node, "name"),
        "guid": _string(node, "guid"),
        "points": count,
        "coordinates": coordinates,
        "rotation": quaternion,
        "translation": [float(t) for t in translation],
    }
    return _Scan(node, count, elements, rotation, translation, metadata)


def _element(node: Any) -> _Element | None:
    """How to read one prototype element; None for element types that hold no number."""
    name = node.elementName()
    kind = type(node).__name__
    if kind == "FloatNode":
        single = node.precision().name.endswith("SINGLE")
        return _Element(name, np.dtype(np.float32 if single else np.float64), 32 if single else 64)
    if kind in ("IntegerNode", "ScaledIntegerNode"):
        low, high = int(node.minimum()), int(node.maximum())
        bits = max(high - low, 0).bit_length()
        if kind == "ScaledIntegerNode":
            return _Element(name, np.dtype(np.float64), bits)
        return _Element(name, smallest_integer(low, high), bits)
    return None


def _pose(pye57: Any, node: Any) -> tuple[np.ndarray, np.ndarray, list[float]]:
    """Rotation matrix, translation and quaternion (w, x, y, z) of a scan; identity when absent.

    R(q) for the unit quaternion q = (w, x, y, z):
        [[1 - 2(y² + z²), 2(xy - wz),     2(xz + wy)],
         [2(xy + wz),     1 - 2(x² + z²), 2(yz - wx)],
         [2(xz - wy),     2(yz + wx),     1 - 2(x² + y²)]]
    The quaternion is normalised first, as libE57's own tools do; a zero or non-finite one
    raises ValueError.
    """
    quaternion = np.array([1.0, 0.0, 0.0, 0.0])
    translation = np.zeros(3)
    if node.isDefined("pose"):
        pose = node["pose"]
        if pose.isDefined("rotation"):
            rotation = pose["rotation"]
            quaternion = np.array(
                [
                    _number(pye57, rotation, axis, default)
                    for axis, default in zip("wxyz", (1, 0, 0, 0), strict=True)
                ]
            )
        if pose.isDefined("translation"):
            offset = pose["translation"]
            translation = np.array([_number(pye57, offset, axis, 0.0) for axis in "xyz"])
    norm = np.linalg.norm(quaternion)
    if not np.isfinite(norm) or norm == 0 or not np.all(np.isfinite(translation)):
        raise ValueError(
            f"scan pose is not a rotation and translation: {quaternion}, {translation}"
        )
    w, x, y, z = quaternion / norm
    rotation_matrix = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )
    return rotation_matrix, translation, [float(q) for q in quaternion]


def _number(pye57: Any, structure: Any, name: str, default: float) -> float:
    if not structure.isDefined(name):
        return float(default)
    node = pye57.utils.get_node(structure, name)
    if type(node).__name__ == "ScaledIntegerNode":
        return float(node.scaledValue())
    return float(node.value())


def _string(structure: Any, name: str) -> str | None:
    if not structure.isDefined(name):
        return None
    node = structure[name]
    return node.value() if type(node).__name__ == "StringNode" else None


def _field_table(e57: Any) -> dict[str, Any]:
    """The table pointfield writes to map its elements back to fields; empty for other files."""
    imf = e57.image_file
    uris = {imf.extensionsPrefix(i): imf.extensionsUri(i) for i in range(imf.extensionsCount())}
    if uris.get(POINTFIELD_PREFIX) != POINTFIELD_URI or not e57.root.isDefined(FIELD_TABLE):
        return {}
    node = e57.root[FIELD_TABLE]
    if type(node).__name__ != "StringNode":
        return {}
    try:
        table = json.loads(node.value())
    except ValueError:
        return {}
    return table if isinstance(table, dict) else {}


def _read_scans(
    path: Path, pye57: Any, e57: Any, scans: list[_Scan]
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Every element of every scan, merged: ``(columns by element name, points (N, 3))``."""
    total = sum(scan.count for scan in scans)
    dtypes: dict[str, np.dtype] = {}
    for scan in scans:
        for name, element in scan.elements.items():
            if name not in CARTESIAN:
                dtypes[name] = np.result_type(dtypes.get(name, element.dtype), element.dtype)
    columns = {name: np.zeros(total, dtype) for name, dtype in dtypes.items()}
    for column in columns.values():
        if column.dtype.kind == "f":
            column.fill(np.nan)  # scans without the element
    columns["scan_index"] = np.empty(total, smallest_integer(0, max(len(scans) - 1, 0)))
    points = np.empty((total, 3), np.float64)
    start = 0
    for index, scan in enumerate(scans):
        rows = slice(start, start + scan.count)
        with library_errors(path, f"libE57 could not read scan {index}"):
            values = _read_records(path, pye57, e57, scan)
        for name, column in values.items():
            if name not in CARTESIAN:
                columns[name][rows] = column
        points[rows] = _scan_points(scan, values)
        if "nor:normalX" in scan.elements and all(n in values for n in NORMALS):
            normals = np.stack([values[n] for n in NORMALS], axis=1) @ scan.rotation.T
            for axis, name in enumerate(NORMALS):
                columns[name][rows] = normals[:, axis]
        columns["scan_index"][rows] = index
        start += scan.count
    return columns, points


def _read_records(path: Path, pye57: Any, e57: Any, scan: _Scan) -> dict[str, np.ndarray]:
    """All numeric elements of one scan: coordinates as float64, the rest in natural dtypes."""
    libe57 = pye57.libe57
    buffers = libe57.VectorSourceDestBuffer()
    arrays = {}
    for name, element in scan.elements.items():
        dtype = np.dtype(np.float64) if name in CARTESIAN + SPHERICAL else element.dtype
        array = np.empty(scan.count, dtype if dtype in BUFFER_DTYPES else LONG_LONG)
        arrays[name] = array
        if scan.count:
            buffers.append(
                libe57.SourceDestBuffer(e57.image_file, name, array, scan.count, True, True)
            )
    if scan.count:
        reader = scan.node["points"].reader(buffers)
        try:
            read = reader.read()
        finally:
            reader.close()
        if read != scan.count:
            raise FormatError(path, f"a scan holds {read} of the {scan.count} records it declares")
    return {
        name: array if array.dtype != LONG_LONG else array.astype(scan.elements[name].dtype)
        for name, array in arrays.items()
    }


def _scan_points(scan: _Scan, values: Mapping[str, np.ndarray]) -> np.ndarray:
    """Scan points ``(n, 3)`` float64 in the file's frame; NaN where the sensor had none."""
    if scan.metadata["coordinates"] == "cartesian":
        local = np.stack([values[n] for n in CARTESIAN], axis=1)
        state = values.get("cartesianInvalidState")
    else:
        distance, azimuth, elevation = (values[n] for n in SPHERICAL)
        across = distance * np.cos(elevation)
        local = np.stack(
            [across * np.cos(azimuth), across * np.sin(azimuth), distance * np.sin(elevation)],
            axis=1,
        )
        state = values.get("sphericalInvalidState")
    posed = scan.translation.any() or not np.array_equal(scan.rotation, np.eye(3))
    world = local @ scan.rotation.T + scan.translation if posed else local
    if state is not None:
        world[state != 0] = np.nan
    return world
