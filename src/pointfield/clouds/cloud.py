"""PointCloud: N points in R^3 with named per-point fields of any dtype.

Conventions shared by every reader and writer:

- ``points`` is ``(N, 3)``, float32 or float64, in the file's own precision (LAS / UTM coordinates
  stay float64). Points a sensor marked invalid are kept as NaN rows, so organised clouds keep
  their grid.
- ``fields`` maps a name to an array whose first dimension is N: ``(N,)`` for scalars, ``(N, K)``
  for fields with K components (PCD ``COUNT > 1``, PLY list properties of fixed length).
  Canonical names are used where a format has the concept:

  =============  ============================================================================
  ``colors``     ``(N, 3)`` RGB or ``(N, 4)`` RGBA, in the file's dtype (uint8 for most files,
                 uint16 for LAS, float for files that store float colours)
  ``normals``    ``(N, 3)``
  ``intensity``  ``(N,)``
  =============  ============================================================================

  Any other field keeps the name it has in the file.
- ``shape`` is ``(H, W)`` for organised clouds (row-major, ``H * W == N``), else ``None``.
- ``metadata`` holds what the file says about the cloud as a whole: ``format`` and ``encoding``
  of the file it was read from, PCD ``viewpoint``, LAS ``scales`` / ``offsets``, comments, ...
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass(eq=False)
class PointCloud:
    """An unordered set of N points with per-point fields.

    Example::

        >>> cloud = PointCloud(np.zeros((2, 3), np.float32), {"intensity": np.array([1, 2])})
        >>> cloud
        PointCloud(2 points, float32, fields: intensity int64)
    """

    points: np.ndarray
    fields: dict[str, np.ndarray] = field(default_factory=dict)
    shape: tuple[int, int] | None = None
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.points = np.asarray(self.points)
        if self.points.ndim != 2 or self.points.shape[1] != 3:
            raise ValueError(f"points must have shape (N, 3), got {self.points.shape}")
        if not np.issubdtype(self.points.dtype, np.floating):
            raise ValueError(f"points must be floating point, got {self.points.dtype}")
        self.fields = {name: np.asarray(values) for name, values in self.fields.items()}
        n = len(self.points)
        for name, values in self.fields.items():
            if values.ndim == 0 or len(values) != n:
                raise ValueError(
                    f"field {name!r} has shape {values.shape}; its first dimension must be the "
                    f"number of points, {n}"
                )
        if self.shape is not None:
            self.shape = (int(self.shape[0]), int(self.shape[1]))
            if self.shape[0] * self.shape[1] != n:
                raise ValueError(f"organised shape {self.shape} does not hold {n} points")

    def __len__(self) -> int:
        return len(self.points)

    @property
    def nan_count(self) -> int:
        """Number of points with a NaN coordinate (invalid returns of organised sensors)."""
        return int(np.isnan(self.points).any(axis=1).sum())

    def select(self, index: np.ndarray | slice) -> PointCloud:
        """The cloud of the points picked by a boolean mask, an index array or a slice.

        Fields follow their points; the organised shape is dropped because the grid is gone.
        """
        return PointCloud(
            self.points[index],
            {name: values[index] for name, values in self.fields.items()},
            None,
            dict(self.metadata),
        )

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """``(min, max)`` corners of the axis-aligned box of the finite points, each ``(3,)``.

        NaN for both when the cloud has no finite point.
        """
        finite = self.points[np.isfinite(self.points).all(axis=1)]
        if len(finite) == 0:
            nan = np.full(3, np.nan)
            return nan, nan.copy()
        return finite.min(axis=0), finite.max(axis=0)

    def __repr__(self) -> str:
        parts = [f"{len(self)} points", str(self.points.dtype)]
        if self.shape is not None:
            parts.append(f"organised {self.shape[0]}x{self.shape[1]}")
        if self.fields:
            parts.append("fields: " + ", ".join(_describe(n, v) for n, v in self.fields.items()))
        return f"{type(self).__name__}({', '.join(parts)})"


def _describe(name: str, values: np.ndarray) -> str:
    components = "" if values.ndim == 1 else f"[{'x'.join(map(str, values.shape[1:]))}]"
    return f"{name} {values.dtype}{components}"


def same_fields(a: Mapping[str, np.ndarray], b: Mapping[str, np.ndarray]) -> bool:
    """True when two field dicts have the same names, dtypes, shapes and values (NaN == NaN)."""
    if a.keys() != b.keys():
        return False
    for name in a:
        x, y = a[name], b[name]
        if x.dtype != y.dtype or x.shape != y.shape:
            return False
        if x.dtype == object:
            if not all(np.array_equal(p, q) for p, q in zip(x, y)):
                return False
        elif not np.array_equal(x, y, equal_nan=x.dtype.kind in "fc"):
            return False
    return True


@dataclass(eq=False)
class Records:
    """Per-record fields of a file that has no coordinates (a PCD file of feature descriptors).

    Same conventions as :class:`PointCloud` fields: every array's first dimension is the number
    of records.
    """

    fields: dict[str, np.ndarray]
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.fields = {name: np.asarray(values) for name, values in self.fields.items()}
        lengths = {len(values) for values in self.fields.values()}
        if len(lengths) > 1:
            raise ValueError(f"fields have different lengths {sorted(lengths)}")

    def __len__(self) -> int:
        return len(next(iter(self.fields.values()))) if self.fields else 0

    def __repr__(self) -> str:
        described = ", ".join(_describe(n, v) for n, v in self.fields.items())
        return f"Records({len(self)} records, fields: {described})"
