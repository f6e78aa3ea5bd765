"""Cloud fields <-> E57 per-point elements, both ways (see the package docstring for the rules).

Reading turns the elements of every scan, merged into columns, into fields
(:func:`fields_from_elements`); writing turns fields into elements (:func:`elements_from_fields`)
and records in pointfield's field table (:func:`field_table`) what standard E57 cannot say, so
that reading gives back exactly the fields written.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from pointfield.clouds.cloud import PointCloud

CARTESIAN = ("cartesianX", "cartesianY", "cartesianZ")
SPHERICAL = ("sphericalRange", "sphericalAzimuth", "sphericalElevation")
COLORS = ("colorRed", "colorGreen", "colorBlue")
NORMALS = ("nor:normalX", "nor:normalY", "nor:normalZ")
NORMALS_URI = "http://www.libe57.org/E57_NOR_surface_normals.txt"
POINTFIELD_PREFIX = "pointfield"
# An E57 extension namespace only needs a unique URI; this one names the table's layout version.
POINTFIELD_URI = "urn:pointfield:e57-fields:1"
FIELD_TABLE = f"{POINTFIELD_PREFIX}:fields"

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


def smallest_integer(low: int, high: int) -> np.dtype:
    """The smallest integer dtype that holds ``low`` .. ``high`` (int64 when none does)."""
    for dtype in _SMALLEST_INTEGERS:
        info = np.iinfo(dtype)
        if info.min <= low and high <= info.max:
            return dtype
    return np.dtype(np.int64)


def integer_range(dtype: np.dtype) -> tuple[int, int]:
    """Minimum and maximum written for an integer element: the full range of its dtype, so that
    :func:`smallest_integer` of them reads the same dtype back."""
    if dtype.kind == "b":
        return 0, 1
    info = np.iinfo(dtype)
    return int(info.min), int(min(info.max, np.iinfo(np.int64).max))


# ---------------------------------------------------------------------------------------------
# Reading: elements -> fields


def fields_from_elements(
    columns: dict[str, np.ndarray], table: Mapping[str, Any], count: int
) -> tuple[dict[str, np.ndarray], tuple[int, int] | None]:
    """Canonical fields and the organised shape (or None) from the merged element columns.

    ``table`` is pointfield's field table, empty for files other writers made.
    """
    mapped = _mapped_elements(table, columns)
    parts: dict[str, dict[int | None, np.ndarray]] = {}  # field -> component -> values, in order
    for name, column in columns.items():
        if name in mapped:
            field_name, component, dtype = mapped[name]
            column = column.astype(dtype)
        elif name in COLORS and all(c in columns for c in COLORS):
            field_name, component = "colors", COLORS.index(name)
        elif name in NORMALS and all(n in columns for n in NORMALS):
            field_name, component = "normals", NORMALS.index(name)
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
# Writing: fields -> elements


@dataclass
class Column:
    """One element to write: its E57 name, values (N,), and the field it comes from."""

    element: str
    values: np.ndarray
    field_name: str
    component: int | None


def elements_from_fields(cloud: PointCloud, order: np.ndarray | None) -> list[Column]:
    """The elements for the cloud's fields (every field but ``scan_index``), rows in ``order``
    (None: as they are). Fields E57 cannot hold are left out with one warning."""
    columns: list[Column] = []
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
                element = f"{POINTFIELD_PREFIX}:f{extension}"
                extension += 1
            columns.append(Column(element, np.ascontiguousarray(part), name, component))
    if skipped:
        warnings.warn(f"E57 cannot hold these fields: {', '.join(skipped)}", stacklevel=4)
    return columns


def _standard_element(name: str, values: np.ndarray, component: int | None) -> str | None:
    """The E57 element a field (component) is written to, or None for a pointfield element."""
    if name == "colors" and component is not None and component < 3:
        return COLORS[component]
    if name == "normals" and component is not None and component < 3 and values.dtype.kind == "f":
        return NORMALS[component]
    if component is None and values.dtype.kind in _STANDARD_ELEMENTS.get(name, ""):
        return name
    return None


def field_table(
    columns: list[Column], scan_dtype: np.dtype | None, shape: tuple[int, int] | None
) -> dict[str, Any]:
    """What pointfield needs to read back exactly the fields it wrote; other readers ignore it.

    Every element's field, component and dtype; the dtype of ``scan_index`` (None: the cloud
    had none); the organised shape (None: not organised).
    """
    return {
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
        "shape": None if shape is None else list(shape),
    }
