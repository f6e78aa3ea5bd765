"""Mesh: a PointCloud of vertices plus faces, and area-weighted sampling of its surface."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pointfield.clouds.cloud import PointCloud


@dataclass(eq=False, repr=False)
class Mesh(PointCloud):
    """Vertices (the inherited ``points`` and per-vertex ``fields``) and polygonal faces.

    ``faces`` is ``(F, K)`` integer vertex indices when every face has K corners (triangles:
    K = 3), or a 1-D object array of integer arrays when faces have different sizes, as PLY and
    OFF allow. ``face_fields`` are per-face, first dimension F (e.g. ``colors`` from ``red green
    blue`` face properties, or PLY list properties such as ``texcoord``).

    Everything that takes a PointCloud takes a Mesh and sees its vertices.
    """

    faces: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int32))
    face_fields: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        super().__post_init__()
        self.faces = np.asarray(self.faces)
        if self.faces.dtype != object and (
            self.faces.ndim != 2 or not np.issubdtype(self.faces.dtype, np.integer)
        ):
            raise ValueError(
                f"faces must be an (F, K) integer array or an object array of index arrays, "
                f"got {self.faces.dtype} {self.faces.shape}"
            )
        self.face_fields = {name: np.asarray(v) for name, v in self.face_fields.items()}
        for name, values in self.face_fields.items():
            if values.ndim == 0 or len(values) != len(self.faces):
                raise ValueError(
                    f"face field {name!r} has shape {values.shape}; its first dimension must be "
                    f"the number of faces, {len(self.faces)}"
                )

    def triangles(self) -> np.ndarray:
        """``(T, 3)`` int64 vertex indices: polygons split into fans (v0, v_i, v_i+1)."""
        if self.faces.dtype != object:
            k = self.faces.shape[1]
            if k < 3:
                return np.zeros((0, 3), np.int64)
            fan = [self.faces[:, [0, i, i + 1]] for i in range(1, k - 1)]
            return np.concatenate(fan).astype(np.int64, copy=False)
        tris = [
            np.asarray(f)[[0, i, i + 1]] for f in self.faces for i in range(1, len(f) - 1)
        ]
        return np.array(tris, np.int64).reshape(-1, 3)

    def sample_surface(self, count: int, seed: int | None = None) -> PointCloud:
        """Sample ``count`` points uniformly over the surface area, with the faces' normals.

        A triangle (a, b, c) is chosen with probability proportional to its area
        ``0.5 * |(b - a) x (c - a)|``; inside it the point is ``a + u (b - a) + v (c - a)`` with
        (u, v) uniform on the unit triangle (reflected when ``u + v > 1``). Returns float32
        points and ``normals`` (unit face normals of the chosen triangles).
        """
        if count < 0:
            raise ValueError(f"count must be >= 0, got {count}")
        tris = self.triangles()
        if len(tris) and (tris.min() < 0 or tris.max() >= len(self.points)):
            raise ValueError(f"faces index vertices outside 0..{len(self.points) - 1}")
        corners = self.points.astype(np.float64)[tris]  # (T, 3 corners, xyz)
        cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        area = 0.5 * np.linalg.norm(cross, axis=1)
        area[~np.isfinite(area)] = 0.0
        total = area.sum()
        if total <= 0:
            raise ValueError("the mesh has no surface area to sample")
        rng = np.random.default_rng(seed)
        chosen = rng.choice(len(tris), size=count, p=area / total)
        u, v = rng.random(count), rng.random(count)
        flip = u + v > 1
        u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
        a, b, c = corners[chosen, 0], corners[chosen, 1], corners[chosen, 2]
        points = a + u[:, None] * (b - a) + v[:, None] * (c - a)
        normals = cross[chosen] / np.maximum(2 * area[chosen], 1e-30)[:, None]
        return PointCloud(points.astype(np.float32), {"normals": normals.astype(np.float32)})

    def __repr__(self) -> str:
        base = super().__repr__()
        return f"{base[:-1]}, {len(self.faces)} faces)"
