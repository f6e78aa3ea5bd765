"""Signed distance fields: a mesh to a grid of signed distances, queried, differentiated and meshed again.

Convention: the signed distance is negative inside the surface and positive outside (as open3d,
mesh2sdf and DeepSDF have it); ``|f(x)|`` is the distance to the nearest triangle. An
:class:`SDFGrid` holds ``f`` at the *nodes* ``origin + (i, j, k) * spacing`` of a ``(X, Y, Z)``
grid (mesh2sdf's layout, whose nodes on ``[-1, 1]^3`` at ``size`` n are ``-1 + 2 i / n``), and in
between it is the trilinear interpolant of the eight nodes around a point:

    f(x) = sum_{a, b, c in {0, 1}} w_a(u) w_b(v) w_c(t) f[i + a, j + b, k + c],
    (i + u, j + v, k + t) = (x - origin) / spacing,   w_0(s) = 1 - s,  w_1(s) = s

whose gradient is the derivative of that polynomial (exact for the interpolant, not a finite
difference). Points outside the grid take the value at the nearest point of its box.

How :func:`mesh_to_sdf` signs a distance: by the generalized winding number ``w`` of the mesh at
the node (:mod:`pointfield.volumes.triangles`), inside where ``w > 1/2``, evaluated only where a
node's side cannot be copied from a coarser node nearer than the surface (:func:`inside_by_levels`). On a closed mesh that is
the exact inside; on one with holes it is the inside the surface nearly encloses, where a ray
parity (open3d's RaycastingScene) or a flood fill from outside (mesh2sdf) flips whole regions once a
hole lets the ray or the fill through. How open the mesh was is kept in ``metadata``: its open
edges (:func:`~pointfield.volumes.voxels.mesh_openness`) and the share of nodes whose ``w`` is
ambiguous (between 0.25 and 0.75, where a closed mesh has few: nodes on the surface itself).

Distances are exact (the nearest point of the nearest triangle) within ``EXACT_WITHIN`` voxels of
the surface and, further out, the distance to points sampled half a voxel apart on the triangles,
which overestimates by at most a sixteenth of a voxel there (:func:`triangles.unsigned_distances`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pointfield.atomic import atomic_path
from pointfield.clouds.mesh import Mesh
from pointfield.errors import FormatError, PointfieldError
from pointfield.volumes.voxels import DEFAULT_DENSE_BYTES, check_dense_fits, mesh_openness

EXACT_WITHIN = 2.0
"""Voxels from the surface within which distances are exact (module docstring)."""
SDF_BYTES_PER_NODE = 64
"""What building a grid costs per node while it runs: its float64 distances, winding numbers and
coordinates, and the query batches' temporaries."""


@dataclass(eq=False)
class SDFGrid:
    """Signed distances ``values`` ``(X, Y, Z)`` float32 at nodes ``origin + ijk * spacing`` (module docstring)."""

    values: np.ndarray
    origin: np.ndarray
    spacing: float
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.values = np.asarray(self.values, np.float32)
        if self.values.ndim != 3 or min(self.values.shape) < 2:
            raise ValueError(f"an SDF grid needs at least 2 nodes per axis, got shape {self.values.shape}")
        self.origin = np.asarray(self.origin, np.float64).reshape(3)
        self.spacing = float(self.spacing)

    @property
    def shape(self) -> tuple[int, int, int]:
        return self.values.shape  # type: ignore[return-value]

    def nodes(self) -> np.ndarray:
        """``(X, Y, Z, 3)`` float64 world positions of the nodes."""
        axes = [self.origin[a] + np.arange(n) * self.spacing for a, n in enumerate(self.shape)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)

    def _cells(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The lower corner node ``(N, 3)`` of each point's cell and its offset ``(N, 3)`` in [0, 1]."""
        local = (np.asarray(points, np.float64).reshape(-1, 3) - self.origin) / self.spacing
        top = np.asarray(self.shape) - 1
        local = np.clip(local, 0, top)
        corner = np.minimum(np.floor(local).astype(np.int64), top - 1)
        return corner, local - corner

    def _corners(self, corner: np.ndarray) -> np.ndarray:
        """``(N, 2, 2, 2)`` the values at the eight nodes of each cell."""
        i, j, k = (corner[:, a, None, None, None] + np.array([0, 1]).reshape(
            [2 if b == a else 1 for b in range(3)]) for a in range(3))
        return self.values[i, j, k].astype(np.float64)

    def query(self, points: np.ndarray) -> np.ndarray:
        """Trilinear signed distance ``(N,)`` float64 at ``points`` ``(N, 3)``.

        >>> grid = SDFGrid(np.arange(8.0).reshape(2, 2, 2), np.zeros(3), 1.0)
        >>> grid.query(np.array([[0.5, 0.5, 0.5], [1.0, 0.0, 1.0]])).tolist()
        [3.5, 5.0]
        """
        corner, offset = self._cells(points)
        u, v, t = offset.T
        f = self._corners(corner)
        fx = f[:, 0] * (1 - u)[:, None, None] + f[:, 1] * u[:, None, None]
        fxy = fx[:, 0] * (1 - v)[:, None] + fx[:, 1] * v[:, None]
        return fxy[:, 0] * (1 - t) + fxy[:, 1] * t

    def gradient(self, points: np.ndarray) -> np.ndarray:
        """``(N, 3)`` gradient of the trilinear interpolant at ``points`` (world units per unit).

        Inside a cell, d f / d u = sum over the corners of (the v, t weights) * (f[1, ...] - f[0, ...]),
        and likewise for v and t; divided by ``spacing`` for world units. Outside the grid the value
        is constant along the clamped axes, but this gives the gradient at the clamped point.
        """
        corner, offset = self._cells(points)
        u, v, t = offset.T
        f = self._corners(corner)
        wu, wv, wt = (np.stack([1 - s, s], axis=1) for s in (u, v, t))
        du = np.einsum("nbc,nb,nc->n", f[:, 1] - f[:, 0], wv, wt)
        dv = np.einsum("nac,na,nc->n", f[:, :, 1] - f[:, :, 0], wu, wt)
        dt = np.einsum("nab,na,nb->n", f[:, :, :, 1] - f[:, :, :, 0], wu, wv)
        return np.stack([du, dv, dt], axis=1) / self.spacing

    def to_mesh(self, level: float = 0.0) -> Mesh:
        """The level set ``f = level`` by marching cubes (scikit-image), faces counter-clockwise seen from outside."""
        from skimage.measure import marching_cubes

        if not (self.values.min() < level < self.values.max()):
            raise PointfieldError(f"the field never crosses {level}: it spans {self.values.min():g} to {self.values.max():g}")
        # "ascent": the field grows outwards, so faces turn their fronts to where f > level.
        vertices, faces, normals, _ = marching_cubes(self.values, level, spacing=(self.spacing,) * 3,
                                                     gradient_direction="ascent", allow_degenerate=False)
        # scikit-image winds its faces clockwise seen from where the field ascends; reversed, they face outwards.
        return Mesh(vertices.astype(np.float64) + self.origin, {"normals": normals.astype(np.float32)},
                    None, {"source": "sdf"}, faces=faces[:, ::-1].astype(np.int32))

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write an ``.npz`` of ``values``, ``origin``, ``spacing`` (atomically)."""
        import json

        with atomic_path(path) as tmp, open(tmp, "wb") as file:
            np.savez_compressed(file, sdf=self.values, origin=self.origin, spacing=np.float64(self.spacing),
                                __metadata__=np.asarray(json.dumps(self.metadata, default=str)))

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> SDFGrid:
        """Read :meth:`save`'s ``.npz``; a file without its members is a :class:`FormatError`."""
        import json

        path = Path(path)
        try:
            with np.load(path, allow_pickle=False) as archive:
                values, origin, spacing = archive["sdf"], archive["origin"], float(archive["spacing"])
                metadata = json.loads(str(archive["__metadata__"])) if "__metadata__" in archive.files else {}
        except (KeyError, ValueError, OSError, EOFError) as error:
            raise FormatError(path, f"not an SDF grid (expected sdf, origin, spacing members): {error}") from None
        try:
            return cls(values, origin, spacing, metadata)
        except ValueError as error:
            raise FormatError(path, str(error)) from None


def grid_over(mesh: Mesh, voxel: float, padding: float = 2.0) -> tuple[np.ndarray, tuple[int, int, int]]:
    """Origin and node counts of the grid of spacing ``voxel`` over ``mesh``'s box plus ``padding`` voxels."""
    points = np.asarray(mesh.points, np.float64)
    low = points.min(axis=0) - padding * voxel
    high = points.max(axis=0) + padding * voxel
    shape = tuple(int(n) for n in np.ceil((high - low) / voxel).astype(np.int64) + 1)
    return low, shape  # type: ignore[return-value]


def mesh_to_sdf(mesh: Mesh, voxel: float | None = None, resolution: int | None = None, padding: float = 2.0,
                origin: np.ndarray | None = None, shape: tuple[int, int, int] | None = None,
                max_bytes: int = DEFAULT_DENSE_BYTES, device: str | None = None) -> SDFGrid:
    """The signed distance field of ``mesh`` on a grid (module docstring).

    The grid: ``voxel`` spacing over the mesh's box plus ``padding`` voxels, or ``resolution``
    nodes along the box's longest side (default 64), or an explicit ``origin``, ``voxel`` and
    ``shape`` (to match another tool's nodes). Refused, naming the voxel that fits, when its work
    would take more than ``max_bytes``.
    """
    # torch is imported here: reading voxel files and the grid type itself do not need it.
    from pointfield.devices import pick_device
    from pointfield.volumes.triangles import TriangleClusters, unsigned_distances, winding_numbers

    triangles = mesh.triangles()
    vertices = np.asarray(mesh.points, np.float64)
    if not len(triangles):
        raise PointfieldError("the mesh has no faces: a signed distance needs a surface")
    if not np.isfinite(vertices).all():
        raise PointfieldError("the mesh has vertices that are not finite")
    if origin is None or shape is None or voxel is None:
        if voxel is None:
            extent = float((vertices.max(axis=0) - vertices.min(axis=0)).max())
            voxel = extent / (max(resolution or 64, 2) - 1 - 2 * padding)
        origin, shape = grid_over(mesh, voxel, padding)
    check_dense_fits(np.asarray(shape, np.float64) * voxel, voxel, max_bytes, SDF_BYTES_PER_NODE,
                     what="a signed distance grid")
    clusters = TriangleClusters.build(vertices, triangles, pick_device(device))
    grid = SDFGrid(np.zeros(shape, np.float32), origin, voxel)
    nodes = grid.nodes().reshape(-1, 3)
    samples = voxel / 2
    distance = unsigned_distances(nodes, clusters, spacing=samples, exact_within=EXACT_WITHIN * voxel).reshape(shape)
    # Lower bounds of the distances: beyond the exact band, a sample distance exceeds the true one by less than a spacing.
    lower = np.where(distance > EXACT_WITHIN * voxel, distance - samples, distance)
    inside, evaluated, ambiguous = inside_by_levels(lower, voxel, lambda points: winding_numbers(points, clusters),
                                                    grid.origin)
    grid.values = np.where(inside, -distance, distance).astype(np.float32)
    grid.metadata = {"source": mesh.metadata.get("path", ""), "openness": mesh_openness(mesh),
                     "winding_evaluated": evaluated, "ambiguous_nodes": ambiguous}
    return grid


def inside_by_levels(lower: np.ndarray, voxel: float, winding, origin: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Which nodes are inside (``w > 1/2``), the winding number evaluated only where it must be.

    ``lower`` ``(X, Y, Z)``: a lower bound of each node's distance to the surface. The nodes of
    every ``2^L``-th row form level L; levels are done coarsest first. A node whose nearest node
    of the next coarser level is nearer than its distance to the surface lies on the same side
    as that node: the segment between them stays inside a ball that no surface enters. It takes
    that node's answer; the others get ``winding(points) > 1/2``. Far from the surface almost
    every node copies, so the work goes with the surface's area, not the grid's volume.

    Returns the inside mask, the share of nodes where the winding number was evaluated, and the
    share of those where it was ambiguous (between 0.25 and 0.75: near a hole).
    """
    shape = np.asarray(lower.shape)
    inside = np.zeros(lower.shape, bool)
    top = max(0, int(np.log2(max(int(shape.min()) - 1, 1))) - 1)
    evaluated = ambiguous = 0
    for level in range(top, -1, -1):
        step = 1 << level
        axes = [np.arange(0, n, step) for n in shape]
        index = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        if level < top:
            index = index[(index % (2 * step)).any(axis=1)]  # the coarser level's nodes are done
            coarse = 2 * step
            last = (shape - 1) // coarse * coarse
            parent = np.minimum(np.rint(index / coarse).astype(np.int64) * coarse, last)
            gap = np.linalg.norm(index - parent, axis=1) * voxel
            copy = lower[tuple(index.T)] > gap
            inside[tuple(index[copy].T)] = inside[tuple(parent[copy].T)]
            index = index[~copy]
        if len(index):
            w = winding(origin + index * voxel)
            inside[tuple(index.T)] = w > 0.5
            evaluated += len(index)
            ambiguous += int(((w > 0.25) & (w < 0.75)).sum())
    return inside, evaluated / inside.size, ambiguous / max(evaluated, 1)
