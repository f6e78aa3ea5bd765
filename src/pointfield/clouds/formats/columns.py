"""Mapping between a file's named columns and the canonical fields of a PointCloud.

Readers hand :func:`columns_to_cloud_parts` the file's columns in file order; writers get them
back with :func:`cloud_to_columns`, spelled the way their format spells them. Keeping both
directions here is what makes every format agree on ``colors`` and ``normals``.
"""

from __future__ import annotations

import re
from collections.abc import Mapping

import numpy as np

from pointfield.errors import FormatError

# Canonical multi-component fields and the spellings of their components found in the wild.
GROUPS: dict[str, tuple[tuple[str, ...], ...]] = {
    "colors": (
        ("red", "green", "blue", "alpha"),
        ("red", "green", "blue"),
        ("r", "g", "b", "a"),
        ("r", "g", "b"),
        ("diffuse_red", "diffuse_green", "diffuse_blue", "diffuse_alpha"),
        ("diffuse_red", "diffuse_green", "diffuse_blue"),
    ),
    "normals": (("nx", "ny", "nz"), ("normal_x", "normal_y", "normal_z")),
}

# A component of a split (N, K) field: ``name[0]`` .. ``name[K-1]``.
_COMPONENT = re.compile(r"(.+)\[0\]")

# How each family of formats spells the components when writing.
PLY_NAMES = {"colors": ("red", "green", "blue", "alpha"), "normals": ("nx", "ny", "nz")}
PCD_NAMES = {"colors": ("red", "green", "blue", "alpha"), "normals": ("normal_x", "normal_y", "normal_z")}


def columns_to_cloud_parts(
    columns: Mapping[str, np.ndarray], path: object = "<memory>"
) -> tuple[np.ndarray | None, dict[str, np.ndarray]]:
    """Split named 1-D (or (N, K)) columns into ``points`` and canonical ``fields``.

    ``x y z`` (any case) become ``points`` ``(N, 3)`` in their common dtype, or None when the file
    has no coordinates. Component groups of one dtype become ``colors`` / ``normals``; a group
    whose components differ in dtype stays as separate fields. Every other column keeps its name.
    """
    lower = {name.lower(): name for name in columns}
    points = None
    used: set[str] = set()
    if all(axis in lower for axis in "xyz"):
        axes = [columns[lower[axis]] for axis in "xyz"]
        if any(a.ndim != 1 for a in axes):
            raise FormatError(path, "x, y and z must each have one component")
        dtype = np.result_type(*axes)
        if not np.issubdtype(dtype, np.floating):
            dtype = np.float64
        points = np.empty((len(axes[0]), 3), dtype)
        for i, a in enumerate(axes):
            points[:, i] = a
        used.update(lower[axis] for axis in "xyz")

    groups: dict[str, list[str]] = {}
    for canonical, spellings in GROUPS.items():
        if canonical in columns:
            continue
        for spelling in spellings:
            names = [lower.get(s) for s in spelling]
            if None in names or used.intersection(names):
                continue
            parts = [columns[n] for n in names]
            if len({p.dtype for p in parts}) == 1 and all(p.ndim == 1 for p in parts):
                groups[canonical] = names  # type: ignore[assignment]
                used.update(names)  # type: ignore[arg-type]
                break

    fields: dict[str, np.ndarray] = {}
    grouped_first = {names[0]: canonical for canonical, names in groups.items()}
    for name, values in columns.items():
        if name in grouped_first:
            canonical = grouped_first[name]
            fields[canonical] = np.stack([columns[n] for n in groups[canonical]], axis=1)
        elif name not in used:
            fields[name] = values
    return points, fields


def cloud_to_columns(
    points: np.ndarray | None,
    fields: Mapping[str, np.ndarray],
    names: Mapping[str, tuple[str, ...]],
) -> dict[str, np.ndarray]:
    """The inverse of :func:`columns_to_cloud_parts`: ordered columns named as a format names them.

    ``colors`` and ``normals`` are split into components named by ``names`` (e.g. PLY_NAMES);
    other fields pass through unchanged (still ``(N,)`` or ``(N, K)``).
    """
    columns: dict[str, np.ndarray] = {}
    if points is not None:
        for i, axis in enumerate("xyz"):
            columns[axis] = points[:, i]
    for name, values in fields.items():
        spelling = names.get(name)
        if spelling is not None and values.ndim == 2 and values.shape[1] <= len(spelling):
            for i in range(values.shape[1]):
                columns[spelling[i]] = values[:, i]
        else:
            columns[name] = values
    return columns


def group_components(
    columns: Mapping[str, np.ndarray], min_components: int = 1
) -> dict[str, np.ndarray]:
    """Join columns ``name[0]`` to ``name[K-1]``, consecutive and in that order, into one ``(N, K)``
    column ``name``: how formats without multi-component columns store ``(N, K)`` fields.

    A run is joined when it has at least ``min_components`` columns of one dtype and ``name`` is
    not a column already; every other column keeps its name. Order is kept.
    """
    grouped: dict[str, np.ndarray] = {}
    names = list(columns)
    start = 0
    while start < len(names):
        match = _COMPONENT.fullmatch(names[start])
        count = 0
        if match:
            base = match.group(1)
            while start + count < len(names) and names[start + count] == f"{base}[{count}]":
                count += 1
            parts = [columns[name] for name in names[start : start + count]]
            if (
                count >= min_components
                and base not in columns
                and base not in grouped
                and len({part.dtype for part in parts}) == 1
            ):
                grouped[base] = np.stack(parts, axis=1)
                start += count
                continue
        grouped[names[start]] = columns[names[start]]
        start += 1
    return grouped
