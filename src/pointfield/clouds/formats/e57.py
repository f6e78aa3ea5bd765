"""ASTM E57 scans through pye57 (an optional dependency: ``pip install 'pointfield[e57]'``).

Reading
    All scans of the file become one cloud. Each scan's pose (unit quaternion ``q = (w, x, y, z)``
    and translation ``t``) is applied, ``p_world = R(q) p_scan + t``, so every point is in the
    file's one frame; normals are rotated with it, ``n_world = R(q) n_scan``. A ``scan_index``
    field (uint8, uint16 or uint32 as the number of scans needs) says which scan each point came
    from. ``points`` are float64 whatever the file stores (single or double floats, scaled
    integers). Scans with spherical coordinates only are converted to cartesian,
    ``x = r cos(el) cos(az)``, ``y = r cos(el) sin(az)``, ``z = r sin(el)``; a scan with
    neither is an error. Points whose ``cartesianInvalidState`` (``sphericalInvalidState`` for
    converted scans) is not 0 have no valid position and become NaN rows; the state is kept.
    Fields: ``colorRed/Green/Blue`` -> ``colors`` ``(N, 3)``, ``nor:normalX/Y/Z`` (the libE57
    normals extension) -> ``normals`` ``(N, 3)``, ``intensity``; every other per-point element
    (``rowIndex``, ``columnIndex``, ``timeStamp``, ``returnIndex``, ``cartesianInvalidState``,
    the spherical coordinates, extension elements as ``prefix:name``) keeps its E57 name.
    dtypes: single floats -> float32, double floats and scaled integers -> float64, integers ->
    the smallest integer type that holds the element's declared minimum and maximum (colours
    0..255 -> uint8). Scans that lack a field another scan has get NaN (floats) or 0 there.
    2D images are not read.

Writing (encoding ``"e57"``)
    One scan per ``scan_index`` value 0..max (points grouped by it, in a stable order), or one
    scan without that field; no pose, since the points are already in one frame. Coordinates are
    written as double floats for float64 points, single for float32 (NaN rows stay NaN);
    ``colors`` as ``colorRed/Green/Blue`` (integers over their dtype's range, or floats),
    ``normals`` as ``nor:normalX/Y/Z``, E57's own per-point elements under their names, and every
    other field as an element of a ``pointfield`` extension. A small table in the file maps the
    elements back to field names, components and dtypes, so pointfield reads back exactly the
    fields it wrote (``(N, K)`` fields, RGBA colours, bool, uint64 within int64, float16,
    the organised shape) while other E57 readers still see the standard elements.

Hostile files: the physical header (signature, page size, lengths) is checked before libE57
opens the file, libE57 checks every page's CRC, and each scan's declared record count is
checked against the bits its records need before anything is allocated. Every pye57 / libE57
failure becomes a :class:`FormatError` naming the file.
"""

from __future__ import annotations

import json
import struct
import uuid
import warnings
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.formats.registry import Format, register
from pointfield.errors import FormatError, PointfieldError

SIGNATURE = b"ASTM-E57"

# Physical file header (ASTM E2807 section 8): signature, version major / minor, physical file
# length, XML section offset, XML logical length, page size.
_FILE_HEADER = struct.Struct("<8sIIQQQQ")
_PAGE_SIZE = 1024  # E57 1.0 pages: 1020 bytes of data then a CRC-32C

_CARTESIAN = ("cartesianX", "cartesianY", "cartesianZ")
_SPHERICAL = ("sphericalRange", "sphericalAzimuth", "sphericalElevation")
_COLORS = ("colorRed", "colorGreen", "colorBlue")
_NORMALS = ("nor:normalX", "nor:normalY", "nor:normalZ")
_NORMALS_URI = "http://www.libe57.org/E57_NOR_surface_normals.txt"
_POINTFIELD_PREFIX = "pointfield"
# An E57 extension namespace only needs a unique URI; this one names the table's layout version.
_POINTFIELD_URI = "urn:pointfield:e57-fields:1"
_FIELD_TABLE = f"{_POINTFIELD_PREFIX}:fields"

# E57's own per-point elements (ASTM E2807 table 23) that a field of the same name is written
# to, with the dtype kinds the standard allows for each.
_STANDARD_ELEMENTS = {
    "intensity": "biuf",
    "timeStamp": "biuf",
    "sphericalRange": "f",
    "sphericalAzimuth": "f",
    "sphericalElevation": "f",
    **dict.fromkeys(
        (
            "rowIndex",
            "columnIndex",
            "returnIndex",
            "returnCount",
            "cartesianInvalidState",
            "sphericalInvalidState",
            "isIntensityInvalid",
            "isColorInvalid",
            "isTimeStampInvalid",
        ),
        "biu",
    ),
}
_SMALLEST_INTEGERS = [np.dtype(t) for t in ("u1", "i1", "u2", "i2", "u4", "i4", "i8")]
# pye57 hands buffers to libE57 by their struct code and only knows b B h H q ? f d for
# numbers ('l' is taken for 32 bits), so wider integers travel as long long ('q').
_BUFFER_DTYPES = {np.dtype(t) for t in ("u1", "i1", "u2", "i2", "f4", "f8")}
_LONG_LONG = np.dtype("q")


def is_e57(head: bytes) -> bool:
    """True for E57 files: their physical header starts with ``ASTM-E57``."""
    return head.startswith(SIGNATURE)


def _pye57(path: Path) -> Any:
    """pye57, imported only when an E57 file is met, since it is an optional dependency."""
    try:
        import pye57
    except ImportError:
        raise PointfieldError(
            f"{path}: E57 files need pye57; install it with: pip install 'pointfield[e57]'"
        ) from None
    return pye57


@contextmanager
def _library_errors(path: Path, action: str) -> Iterator[None]:
    """Turn whatever pye57 / libE57 raise into a FormatError naming the file.

    libE57's messages carry several lines of debug context; the first line says what was wrong.
    """
    try:
        yield
    except (FormatError, PointfieldError):
        raise
    except Exception as error:
        lines = str(error).strip().splitlines()
        detail = lines[0][:200] if lines else type(error).__name__
        raise FormatError(path, f"{action}: {detail}") from error


# ---------------------------------------------------------------------------------------------
# Reading
# ---------------------------------------------------------------------------------------------


@dataclass
class _Element:
    """One per-point element of a scan's prototype, and how it is read."""

    name: str
    dtype: np.dtype  # the field's natural dtype
    bits: int  # bits one value takes in the file, at least


@dataclass
class _Scan:
    node: Any
    count: int
    elements: dict[str, _Element]
    rotation: np.ndarray  # (3, 3)
    translation: np.ndarray  # (3,)
    metadata: dict[str, Any]  # what read_e57 reports about the scan


def read_e57(path: Path) -> PointCloud:
    """Read every scan of an E57 file into one PointCloud (see module doc)."""
    path = Path(path)
    pye57 = _pye57(path)
    size = path.stat().st_size
    _check_file_header(path, size)
    with _library_errors(path, "libE57 could not open it"):
        e57 = pye57.E57(str(path), mode="r")
    try:
        with _library_errors(path, "libE57 could not read it"):
            scans = [
                _describe_scan(path, pye57, e57.data3d[index], index)
                for index in range(e57.scan_count)
            ]
            table = _field_table(e57)
        _check_record_counts(path, scans, size)
        columns, points = _read_scans(path, pye57, e57, scans)
    finally:
        e57.close()
    fields, shape = _fields(columns, table, len(points))
    metadata = {"encoding": "e57", "e57_scans": [scan.metadata for scan in scans]}
    return PointCloud(points, fields, shape, metadata)


def _check_file_header(path: Path, size: int) -> None:
    """Check the physical header before libE57 reads the file by it."""
    with open(path, "rb") as file:
        head = file.read(_FILE_HEADER.size)
    if not is_e57(head):
        raise FormatError(path, f"not an E57 file: expected the signature {SIGNATURE!r}")
    if len(head) < _FILE_HEADER.size:
        raise FormatError(
            path, f"truncated: {size} bytes, the E57 header alone needs {_FILE_HEADER.size}"
        )
    _, major, minor, length, xml_offset, xml_length, page_size = _FILE_HEADER.unpack(head)
    if major != 1:
        raise FormatError(path, f"unsupported E57 version {major}.{minor}; expected 1.x")
    if page_size != _PAGE_SIZE:
        raise FormatError(
            path, f"page size {page_size}; E57 1.0 files have {_PAGE_SIZE}-byte pages"
        )
    if length != size or size % _PAGE_SIZE:
        raise FormatError(
            path,
            f"header says the file is {length} bytes; it is {size} (whole {_PAGE_SIZE}-byte pages)",
        )
    if not _FILE_HEADER.size <= xml_offset < size or xml_length > size:
        raise FormatError(
            path,
            f"XML section ({xml_length} bytes at {xml_offset}) lies outside the {size}-byte file",
        )


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
    coordinates = "cartesian" if all(n in elements for n in _CARTESIAN) else "spherical"
    if coordinates == "spherical" and not all(n in elements for n in _SPHERICAL):
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
        return _Element(name, _smallest_integer(low, high), bits)
    return None


def _smallest_integer(low: int, high: int) -> np.dtype:
    for dtype in _SMALLEST_INTEGERS:
        info = np.iinfo(dtype)
        if info.min <= low and high <= info.max:
            return dtype
    return np.dtype(np.int64)


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
    if uris.get(_POINTFIELD_PREFIX) != _POINTFIELD_URI or not e57.root.isDefined(_FIELD_TABLE):
        return {}
    node = e57.root[_FIELD_TABLE]
    if type(node).__name__ != "StringNode":
        return {}
    try:
        table = json.loads(node.value())
    except ValueError:
        return {}
    return table if isinstance(table, dict) else {}


def _check_record_counts(path: Path, scans: list[_Scan], size: int) -> None:
    """Each record needs at least the bits of its elements, and every bit is in the file.

    Records are bit-packed without entropy coding, so a scan of N records with B bits each
    takes at least N * B bits of the file. A record is counted as at least one bit, so that
    records of constant elements (zero bits) cannot claim unbounded counts either.
    """
    needed = sum(scan.count * max(1, sum(e.bits for e in scan.elements.values())) for scan in scans)
    if needed > 8 * size:
        counts = [scan.count for scan in scans]
        raise FormatError(
            path, f"scans declare {counts} records, more than the {size}-byte file can hold"
        )


def _read_scans(
    path: Path, pye57: Any, e57: Any, scans: list[_Scan]
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Every element of every scan, merged: ``(columns by element name, points (N, 3))``."""
    total = sum(scan.count for scan in scans)
    dtypes: dict[str, np.dtype] = {}
    for scan in scans:
        for name, element in scan.elements.items():
            if name not in _CARTESIAN:
                dtypes[name] = np.result_type(dtypes.get(name, element.dtype), element.dtype)
    columns = {name: np.zeros(total, dtype) for name, dtype in dtypes.items()}
    for column in columns.values():
        if column.dtype.kind == "f":
            column.fill(np.nan)  # scans without the element
    columns["scan_index"] = np.empty(total, _smallest_integer(0, max(len(scans) - 1, 0)))
    points = np.empty((total, 3), np.float64)
    start = 0
    for index, scan in enumerate(scans):
        rows = slice(start, start + scan.count)
        with _library_errors(path, f"libE57 could not read scan {index}"):
            values = _read_records(path, pye57, e57, scan)
        for name, column in values.items():
            if name not in _CARTESIAN:
                columns[name][rows] = column
        points[rows] = _scan_points(scan, values)
        if "nor:normalX" in scan.elements and all(n in values for n in _NORMALS):
            normals = np.stack([values[n] for n in _NORMALS], axis=1) @ scan.rotation.T
            for axis, name in enumerate(_NORMALS):
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
        dtype = np.dtype(np.float64) if name in _CARTESIAN + _SPHERICAL else element.dtype
        array = np.empty(scan.count, dtype if dtype in _BUFFER_DTYPES else _LONG_LONG)
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
        name: array if array.dtype != _LONG_LONG else array.astype(scan.elements[name].dtype)
        for name, array in arrays.items()
    }


def _scan_points(scan: _Scan, values: Mapping[str, np.ndarray]) -> np.ndarray:
    """Scan points ``(n, 3)`` float64 in the file's frame; NaN where the sensor had none."""
    if scan.metadata["coordinates"] == "cartesian":
        local = np.stack([values[n] for n in _CARTESIAN], axis=1)
        state = values.get("cartesianInvalidState")
    else:
        distance, azimuth, elevation = (values[n] for n in _SPHERICAL)
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


def _fields(
    columns: dict[str, np.ndarray], table: Mapping[str, Any], count: int
) -> tuple[dict[str, np.ndarray], tuple[int, int] | None]:
    """Canonical fields from the merged element columns (see module doc)."""
    mapped = _mapped_elements(table, columns)
    parts: dict[str, dict[int | None, np.ndarray]] = {}  # field -> component -> values, in order
    for name, column in columns.items():
        if name in mapped:
            field_name, component, dtype = mapped[name]
            column = column.astype(dtype)
        elif name in _COLORS and all(c in columns for c in _COLORS):
            field_name, component = "colors", _COLORS.index(name)
        elif name in _NORMALS and all(n in columns for n in _NORMALS):
            field_name, component = "normals", _NORMALS.index(name)
        else:
            field_name, component = name, None
        parts.setdefault(field_name, {})[component] = column
    fields = {
        name: components[None]
        if None in components
        else np.stack([components[i] for i in sorted(components)], axis=1)
        for name, components in parts.items()
    }
    if "scan_index_dtype" in table:  # written by pointfield: scan_index only if the cloud had it
        scan_dtype = _dtype(table["scan_index_dtype"])
        scan_index = fields.pop("scan_index")
        if scan_dtype is not None:
            fields["scan_index"] = scan_index.astype(scan_dtype)
    shape = table.get("shape")
    if (
        isinstance(shape, list)
        and len(shape) == 2
        and all(isinstance(side, int) and side > 0 for side in shape)
        and shape[0] * shape[1] == count
    ):
        return fields, (shape[0], shape[1])
    return fields, None


def _mapped_elements(
    table: Mapping[str, Any], columns: Mapping[str, np.ndarray]
) -> dict[str, tuple[str, int | None, np.dtype]]:
    """element -> (field, component or None, dtype) from the table, for elements it describes well.

    A field is taken from the table only if all its components are present, numbered 0..K-1.
    """
    entries = table.get("elements")
    if not isinstance(entries, list):
        return {}
    by_field: dict[str, list[tuple[str, int | None, np.dtype]]] = {}
    for entry in entries:
        if not isinstance(entry, dict) or entry.get("element") not in columns:
            continue
        field_name, component, dtype = (
            entry.get("field"),
            entry.get("component"),
            _dtype(entry.get("dtype")),
        )
        if (
            isinstance(field_name, str)
            and dtype is not None
            and (component is None or isinstance(component, int))
        ):
            by_field.setdefault(field_name, []).append((entry["element"], component, dtype))
    mapped = {}
    for field_name, parts in by_field.items():
        components = sorted(c for _, c, _ in parts if c is not None)
        whole = len(parts) == 1 and parts[0][1] is None
        if whole or components == list(range(len(parts))):
            for element, component, dtype in parts:
                mapped[element] = (field_name, component, dtype)
    return mapped


def _dtype(text: Any) -> np.dtype | None:
    try:
        dtype = np.dtype(text) if isinstance(text, str) else None
    except TypeError:
        return None
    return dtype if dtype is not None and dtype.kind in "biuf" else None


# ---------------------------------------------------------------------------------------------
# Writing
# ---------------------------------------------------------------------------------------------


@dataclass
class _Column:
    """One element to write: its E57 name, values (N,), and the field it comes from."""

    element: str
    values: np.ndarray
    field_name: str
    component: int | None


def write_e57(path: Path, cloud: PointCloud, encoding: str | None = None) -> None:
    """Write ``cloud`` as an E57 file, one scan per ``scan_index`` value (see module doc)."""
    path = Path(path)
    pye57 = _pye57(path)
    order, scan_ranges, scan_dtype = _scan_split(path, cloud)
    points = cloud.points[order] if order is not None else cloud.points
    columns = _columns(cloud, order)
    # What pointfield needs to read back exactly the fields it wrote; other readers ignore it.
    table: dict[str, Any] = {
        "elements": [
            {
                "element": c.element,
                "field": c.field_name,
                "component": c.component,
                "dtype": c.values.dtype.str,
            }
            for c in columns
        ],
        "scan_index_dtype": None if scan_dtype is None else scan_dtype.str,
        "shape": None if cloud.shape is None or len(scan_ranges) > 1 else list(cloud.shape),
    }
    names = [
        scan.get("name")
        for scan in cloud.metadata.get("e57_scans") or []
        if isinstance(scan, Mapping)
    ]

    with _library_errors(path, "libE57 could not write it"):
        e57 = pye57.E57(str(path), mode="w")
    try:
        with _library_errors(path, "libE57 could not write it"):
            libe57 = pye57.libe57
            imf = e57.image_file
            if any(c.element.startswith("nor:") for c in columns):
                imf.extensionsAdd("nor", _NORMALS_URI)
            imf.extensionsAdd(_POINTFIELD_PREFIX, _POINTFIELD_URI)
            e57.root.set(_FIELD_TABLE, libe57.StringNode(imf, json.dumps(table)))
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
        with _library_errors(path, "libE57 could not finish it"):
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


def _columns(cloud: PointCloud, order: np.ndarray | None) -> list[_Column]:
    """The elements for the cloud's fields (every field but ``scan_index``)."""
    columns: list[_Column] = []
    skipped = []
    extension = 0
    for name, values in cloud.fields.items():
        if name == "scan_index" and values.ndim == 1 and values.dtype.kind in "biu":
            continue
        if values.dtype.kind not in "biuf" or values.ndim > 2:
            skipped.append(f"{name} ({values.dtype}, shape {values.shape})")
            continue
        if values.dtype == np.uint64 and len(values) and values.max() > np.iinfo(np.int64).max:
            skipped.append(f"{name} (uint64 values above E57's int64 range)")
            continue
        values = values[order] if order is not None else values
        parts = [values] if values.ndim == 1 else [values[:, i] for i in range(values.shape[1])]
        for component, part in enumerate(parts):
            component = component if values.ndim == 2 else None
            element = _standard_element(name, part, component)
            if element is None:
                element = f"{_POINTFIELD_PREFIX}:f{extension}"
                extension += 1
            columns.append(_Column(element, np.ascontiguousarray(part), name, component))
    if skipped:
        warnings.warn(f"E57 cannot hold these fields: {', '.join(skipped)}", stacklevel=4)
    return columns


def _standard_element(name: str, values: np.ndarray, component: int | None) -> str | None:
    """The E57 element a field (component) is written to, or None for a pointfield element."""
    if name == "colors" and component is not None and component < 3:
        return _COLORS[component]
    if name == "normals" and component is not None and component < 3 and values.dtype.kind == "f":
        return _NORMALS[component]
    if component is None and values.dtype.kind in _STANDARD_ELEMENTS.get(name, ""):
        return name
    return None


def _integer_range(dtype: np.dtype) -> tuple[int, int]:
    """Minimum and maximum written for an integer element: the full range of its dtype."""
    if dtype.kind == "b":
        return 0, 1
    info = np.iinfo(dtype)
    return int(info.min), int(min(info.max, np.iinfo(np.int64).max))


def _write_scan(
    libe57: Any, e57: Any, name: str, points: np.ndarray, columns: list[tuple[_Column, np.ndarray]]
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
    for axis, element in enumerate(_CARTESIAN):
        prototype.set(element, _float_node(libe57, imf, precision))
        arrays.append((element, np.ascontiguousarray(points[:, axis], np.float64)))
    for column, values in columns:
        prototype.set(column.element, _node(libe57, imf, values.dtype))
        arrays.append((column.element, _buffer_array(values)))
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
    libe57: Any, imf: Any, scan: Any, columns: list[tuple[_Column, np.ndarray]]
) -> None:
    """colorLimits, which readers scale colours by: the dtype's range for integer colours
    (0..255 for uint8), the values' range for float ones."""
    colors = [values for column, values in columns if column.element in _COLORS]
    if len(colors) != 3:
        return
    limits = libe57.StructureNode(imf)
    if colors[0].dtype.kind == "f":
        finite = np.concatenate(colors)[np.isfinite(np.concatenate(colors))]
        low, high = (float(finite.min()), float(finite.max())) if len(finite) else (0.0, 1.0)
        make = libe57.FloatNode
    else:
        low, high = _integer_range(colors[0].dtype)
        make = libe57.IntegerNode
    for element in _COLORS:
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
    low, high = _integer_range(dtype)
    return libe57.IntegerNode(imf, max(low, 0) if low <= 0 <= high else low, low, high)


def _buffer_array(values: np.ndarray) -> np.ndarray:
    """``values`` in a dtype pye57 passes to libE57 intact (see _BUFFER_DTYPES)."""
    if values.dtype.kind == "f":
        dtype = np.float32 if values.dtype.itemsize <= 4 else np.float64
        return np.ascontiguousarray(values, dtype)
    if values.dtype in _BUFFER_DTYPES:
        return np.ascontiguousarray(values)
    array = np.empty(len(values), _LONG_LONG)
    array[...] = values
    return array


register(
    Format(
        name="e57",
        description="ASTM E57 3D imaging data (pye57, optional)",
        suffixes=(".e57",),
        read=read_e57,
        write=write_e57,
        encodings=("e57",),
        aliases={"binary": "e57"},
        signature=is_e57,
    )
)
