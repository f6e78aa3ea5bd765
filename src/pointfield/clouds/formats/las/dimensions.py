"""Mapping a cloud's fields onto LAS dimensions for writing.

Fields named like a standard dimension of some point format go there, in its fixed type (the
point format is chosen to hold them); every other field becomes an extra bytes dimension of its
own dtype. See the package docstring for the rules.
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import laspy
import numpy as np
from laspy.point import dims as laspy_dims

from pointfield.clouds.formats.columns import cloud_to_columns

COORDINATES = ("X", "Y", "Z")
COLOR_DIMENSIONS = ("red", "green", "blue")
_NAMES = {"normals": ("nx", "ny", "nz")}
_EXTRA_BYTES_DTYPES = {
    np.dtype(t) for t in ("u1", "i1", "u2", "i2", "u4", "i4", "u8", "i8", "f4", "f8")
}
_EXTRA_NAME_BYTES = 32
_DESCRIPTION_BYTES = 32
# Names an extra dimension cannot take: the raw coordinates, laspy's scaled ones and the packed
# bytes laspy keeps bit fields in.
_RESERVED_NAMES = {
    *COORDINATES,
    "x",
    "y",
    "z",
    *laspy_dims.COMPOSED_FIELDS[0],
    *laspy_dims.COMPOSED_FIELDS[6],
}


@dataclass(frozen=True)
class _Dimension:
    """A standard dimension of a point format: the dtype laspy reads it as, and its range."""

    dtype: np.dtype
    low: float
    high: float


def _standard_dimensions(format_id: int) -> dict[str, _Dimension]:
    point_format = laspy.PointFormat(format_id)
    storage = point_format.dtype()
    dimensions = {}
    for dimension in point_format.standard_dimensions:
        if dimension.name in COORDINATES:
            continue
        if dimension.kind == laspy.DimensionKind.BitField:
            dimensions[dimension.name] = _Dimension(
                np.dtype(np.uint8), 0, 2**dimension.num_bits - 1
            )
            continue
        dtype = storage[dimension.name]
        if dtype.kind == "f":
            dimensions[dimension.name] = _Dimension(dtype, -np.inf, np.inf)
        else:
            info = np.iinfo(dtype)
            dimensions[dimension.name] = _Dimension(dtype, info.min, info.max)
    return dimensions


FORMATS = {format_id: _standard_dimensions(format_id) for format_id in range(11)}
_STANDARD_NAMES = set().union(*FORMATS.values())
_MIN_VERSION = {
    **dict.fromkeys(range(4), "1.2"),
    4: "1.3",
    5: "1.3",
    **dict.fromkeys(range(6, 11), "1.4"),
}



# A name's word boundaries: "pointSourceId" and PDAL's "PointSourceId" -> "point_source_id".
_CAMEL = re.compile(r"(?<=[a-z0-9])(?=[A-Z])")
# Characters a LAS extra-dimension name cannot hold: numpy's buffer protocol, through which laspy
# writes, refuses ':' in field names; the name is 32 bytes of ASCII.
_UNNAMEABLE = re.compile(r"[^\x20-\x7e]|:")


def las_field_names(fields: Mapping[str, np.ndarray], notes: list[str]) -> dict[str, np.ndarray]:
    """The fields under names LAS holds; each rename noted.

    A well-known spelling of a standard dimension becomes that dimension: a namespaced or
    camel-case name (E57's ``las:pointSourceId``, PDAL's ``PointSourceId``, ``GpsTime``) whose
    snake-case form is a LAS dimension (``point_source_id``). Every other name loses the
    characters a LAS name cannot hold (``:``, non-ASCII), each replaced by ``_``. A new name
    already taken gets a ``_2``, ``_3``, ... suffix.
    """
    renamed: dict[str, np.ndarray] = {}
    changes = []
    for name, values in fields.items():
        local = name.rsplit(":", 1)[-1]
        dimension = _CAMEL.sub("_", local).lower()
        if (
            dimension != name
            and values.ndim == 1
            and values.dtype.kind in "biuf"
            and dimension in _STANDARD_NAMES
            and dimension not in COLOR_DIMENSIONS
            and dimension not in fields
            and dimension not in renamed
        ):
            renamed[dimension] = values
            changes.append(f"{name!r} -> {dimension!r} (the LAS dimension)")
            continue
        new = _UNNAMEABLE.sub("_", name)
        if new != name:
            base, suffix = new, 2
            while new in fields or new in renamed:
                new, suffix = f"{base}_{suffix}", suffix + 1
            changes.append(f"{name!r} -> {new!r}")
        renamed[new] = values
    if changes:
        notes.append("renamed " + ", ".join(changes) + " (LAS names are ASCII without ':')")
    return renamed


def split_fields(
    fields: Mapping[str, np.ndarray], notes: list[str]
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Fields named like a standard dimension (colours split into red/green/blue), and the rest."""
    standard: dict[str, np.ndarray] = {}
    extra: dict[str, np.ndarray] = {}
    for name, values in fields.items():
        if name == "colors" and values.ndim == 2 and values.shape[1] in (3, 4):
            rgb = _colors_as_uint16(values, notes)
            standard.update(zip(COLOR_DIMENSIONS, rgb.T[:3], strict=True))
            if rgb.shape[1] == 4:
                extra["alpha"] = rgb[:, 3]
        elif name == "intensity" and _is_unit_float(values):
            notes.append(
                f"intensity {values.dtype} in [0, 1] -> uint16 (x65535){_nan_note(values)}"
            )
            standard[name] = _unit_to_uint16(values)
        elif name in _STANDARD_NAMES and values.ndim == 1 and values.dtype.kind in "biuf":
            standard[name] = values
        else:
            extra[name] = values
    return standard, extra


def _colors_as_uint16(colors: np.ndarray, notes: list[str]) -> np.ndarray:
    """LAS colours are uint16: uint8 * 257 (so 255 -> 65535), float [0, 1] * 65535."""
    if colors.dtype == np.uint16:
        return colors
    if colors.dtype == np.uint8:
        notes.append("colors uint8 -> uint16 (x257)")
        return colors.astype(np.uint16) * np.uint16(257)
    if _is_unit_float(colors):
        notes.append(f"colors {colors.dtype} in [0, 1] -> uint16 (x65535){_nan_note(colors)}")
        return _unit_to_uint16(colors)
    return fit("colors", colors, _Dimension(np.dtype(np.uint16), 0, 65535), notes)


def _is_unit_float(values: np.ndarray) -> bool:
    """True for float values in [0, 1] (NaN ignored): colours or intensity on a unit scale."""
    return values.dtype.kind == "f" and bool(
        np.nanmin(values, initial=0) >= 0 and np.nanmax(values, initial=0) <= 1
    )


def _nan_note(values: np.ndarray) -> str:
    """``", 3 NaN written as 0"`` for float values with NaN (LAS integers have no NaN), else ''."""
    nan = int(np.count_nonzero(np.isnan(values))) if values.dtype.kind == "f" else 0
    return f", {nan} NaN written as 0" if nan else ""


def _unit_to_uint16(values: np.ndarray) -> np.ndarray:
    return np.round(np.nan_to_num(values.astype(np.float64)) * 65535).astype(np.uint16)


def choose_point_format(standard: Mapping[str, np.ndarray], metadata: Mapping[str, Any]) -> int:
    """The point format for the fields: the LAS cloud's own if it still fits, else the smallest.

    Formats are ranked by: holding every dimension of the format the cloud was read with, the
    number of the cloud's standard-named fields they hold, the number of those whose values fit
    without loss, and finally the smaller id (0..10, which is also the smaller record for the
    same dimensions).
    """
    base = metadata.get("las_point_format")
    base_names = set(FORMATS[base]) if base in FORMATS else set()
    ranges = {name: _value_range(values) for name, values in standard.items()}

    def rank(format_id: int) -> tuple[bool, int, int, int]:
        dimensions = FORMATS[format_id]
        held = [name for name in standard if name in dimensions]
        fitting = sum(_fits(ranges[name], dimensions[name]) for name in held)
        return base_names <= dimensions.keys(), len(held), fitting, -format_id

    return max(FORMATS, key=rank)


def _value_range(values: np.ndarray) -> tuple[str, float, float, bool]:
    """(dtype kind, min, max, all finite integers) of a field, computed once per field."""
    if values.dtype.kind not in "biuf" or len(values) == 0:
        return values.dtype.kind, 0, 0, values.dtype.kind != "f" or len(values) == 0
    low, high = values.min(), values.max()
    integral = values.dtype.kind != "f" or bool(
        np.all(np.isfinite(values)) and np.all(values == np.round(values))
    )
    return values.dtype.kind, float(low), float(high), integral


def _fits(value_range: tuple[str, float, float, bool], dimension: _Dimension) -> bool:
    kind, low, high, integral = value_range
    if kind not in "biuf":
        return False
    if dimension.dtype.kind == "f":
        return True
    return integral and dimension.low <= low and high <= dimension.high


def fit(name: str, values: np.ndarray, dimension: _Dimension, notes: list[str]) -> np.ndarray:
    """``values`` in the dimension's dtype; converted (and noted) where they do not fit."""
    if values.dtype == dimension.dtype:
        return values
    if _fits(_value_range(values), dimension):
        notes.append(f"{name} {values.dtype} -> {dimension.dtype}")
        return values.astype(dimension.dtype)
    converted = np.clip(
        np.round(np.nan_to_num(values.astype(np.float64))), dimension.low, dimension.high
    )
    nan = np.isnan(values) if values.dtype.kind == "f" else np.zeros(values.shape, bool)
    changed = int(np.count_nonzero((converted != values) & ~nan))
    note = f"{name} {values.dtype} -> {dimension.dtype}{_nan_note(values)}"
    if changed or not nan.any():
        note += (
            f", {changed} values rounded or clipped to [{dimension.low:g}, {dimension.high:g}]"
        )
    notes.append(note)
    return converted.astype(dimension.dtype)


def extra_dimensions(
    extra: Mapping[str, np.ndarray],
    standard_names: set[str],
    metadata: Mapping[str, Any],
    notes: list[str],
) -> tuple[list[laspy.ExtraBytesParams], dict[str, np.ndarray]]:
    """Extra bytes dimensions, and the values to store in them, for the fields left over.

    A field read from LAS gets its original type, description, scales and offsets back; any
    other field an extra dimension of its own dtype. ``normals`` become ``nx ny nz``, ``(N, 2)``
    and ``(N, 3)`` fields 2- and 3-element types, wider ones K dimensions ``name[i]``.
    """
    known = metadata.get("las_extra_dimensions")
    known = known if isinstance(known, Mapping) else {}
    taken = standard_names | _RESERVED_NAMES
    params: list[laspy.ExtraBytesParams] = []
    stored: dict[str, np.ndarray] = {}
    skipped: list[str] = []
    for name, values in cloud_to_columns(None, extra, _NAMES).items():
        for column_name, column in _columns_of(name, values):
            reason = _unstorable(column_name, column, taken)
            if reason:
                skipped.append(f"{column_name} ({reason})")
                continue
            taken.add(column_name)
            param, stored[column_name] = _extra_dimension(
                column_name, column, known.get(column_name), notes
            )
            params.append(param)
    if skipped:
        warnings.warn(f"LAS cannot hold these fields: {', '.join(skipped)}", stacklevel=4)
    return params, stored


def _unstorable(name: str, column: np.ndarray, taken: set[str]) -> str | None:
    """Why ``column`` cannot be an extra bytes dimension called ``name``, or None if it can."""
    if _extra_bytes_dtype(column.dtype) is None:
        return f"dtype {column.dtype}"
    if column.ndim > 2 or (column.ndim == 2 and column.shape[1] < 2):
        return f"shape {column.shape}"
    if name in taken:
        return "name taken by a LAS dimension"
    if not name.isascii() or len(name) > _EXTRA_NAME_BYTES:
        return f"name not ASCII or over {_EXTRA_NAME_BYTES} characters"
    return None


def _extra_dimension(
    name: str, column: np.ndarray, previous: Any, notes: list[str]
) -> tuple[laspy.ExtraBytesParams, np.ndarray]:
    """One extra bytes dimension and its values; as in the file the field came from, if any."""
    count = 1 if column.ndim == 1 else column.shape[1]
    description = ""
    if isinstance(previous, Mapping) and previous.get("count") == count:
        description = str(previous.get("description") or "")[:_DESCRIPTION_BYTES]
        rescaled = _rescaled(column, previous)
        if rescaled is not None:
            raw, scales, offsets = rescaled
            element = raw.dtype if count == 1 else np.dtype((raw.dtype, (count,)))
            return laspy.ExtraBytesParams(name, element, description, offsets, scales), raw
    dtype = _extra_bytes_dtype(column.dtype)
    if dtype != column.dtype:
        notes.append(f"{name} {column.dtype} -> {dtype}")
    element = dtype if count == 1 else np.dtype((dtype, (count,)))
    return laspy.ExtraBytesParams(name, element, description), column


def _rescaled(
    column: np.ndarray, previous: Mapping[str, Any]
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """``(raw, scales, offsets)`` storing a float field the way its LAS file did, if it still fits.

    Scaled extra dimensions read as ``raw * scale + offset``; this is the inverse,
    ``raw = round((value - offset) / scale)``, in the original integer type.
    """
    if previous.get("scales") is None or column.dtype.kind != "f":
        return None
    try:
        dtype = np.dtype(previous["dtype"])
        scales = np.asarray(previous["scales"], np.float64)
        offsets = np.asarray(previous["offsets"], np.float64)
        raw = np.round((column - offsets) / scales)
    except (KeyError, TypeError, ValueError):
        return None
    if dtype.kind not in "iu" or not np.all(np.isfinite(raw)):
        return None
    info = np.iinfo(dtype)
    if len(raw) and (raw.min() < info.min or raw.max() > info.max):
        return None
    return raw.astype(dtype), scales, offsets


def _columns_of(name: str, values: np.ndarray) -> list[tuple[str, np.ndarray]]:
    """A field as extra-dimension columns.

    ``(N,)``, ``(N, 2)``, ``(N, 3)`` and ``(N, K)`` uint8 (LAS's undocumented-bytes type) stay
    one column; other ``(N, K)`` fields become K ``(N,)`` columns ``name[i]``.
    """
    if values.ndim == 2 and values.shape[1] > 3 and values.dtype != np.uint8:
        return [(f"{name}[{i}]", values[:, i]) for i in range(values.shape[1])]
    return [(name, values)]  # (N, K, M) and (N, 1) are reported as not storable


def _extra_bytes_dtype(dtype: np.dtype) -> np.dtype | None:
    """The little-endian extra bytes type that holds ``dtype`` exactly, or None."""
    if dtype.kind == "b":
        return np.dtype(np.uint8)
    if dtype.kind == "f" and dtype.itemsize < 4:
        return np.dtype(np.float32)
    little = dtype.newbyteorder("<")
    return little if little in _EXTRA_BYTES_DTYPES else None


def version_for(format_id: int, metadata: Mapping[str, Any]) -> str:
    """The cloud's LAS version if it allows the point format, else the lowest that does."""
    version = metadata.get("las_version")
    if (
        version in laspy_dims.VERSION_TO_POINT_FMT
        and format_id in laspy_dims.VERSION_TO_POINT_FMT[version]
    ):
        return version
    return _MIN_VERSION[format_id]
