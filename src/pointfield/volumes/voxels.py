"""Voxel grids: space cut into cubes, each occupied cube stored with its own values.

A :class:`VoxelGrid` is sparse: the integer coordinates ``(i, j, k)`` of its occupied voxels and,
per voxel, any fields (``counts``: the points that fell in it; ``colors``; ``labels``; ...). The
grid itself is an ``origin`` (the minimum corner of voxel (0, 0, 0)) and a voxel ``size``: voxel
``(i, j, k)`` is the cube ``origin + [i, i+1) x [j, j+1) x [k, k+1) * size``, its centre
``origin + (ijk + 0.5) * size``. Coordinates are non-negative and sorted in lexicographic order
of ``(i, j, k)``, the order :mod:`pointfield.streaming.voxels` gives its keys, so that two grids
of the same voxels are equal array for array. ``shape`` is how many voxels the grid spans per
axis (at least one past the largest coordinate; a file may declare more).

Where grids come from:

- a cloud (:func:`voxelize_cloud`): the grid starts at the cloud's minimum corner, as
  :func:`pointfield.clouds.ops.voxel_downsample`'s does, and a point ``p`` falls in voxel
  ``floor((p - origin) / size)``; per voxel, ``counts``, the mean of each floating-point field
  (``normals`` renormalised), the mean colour (rounded back to the colours' dtype), and the most
  frequent value of every other integer field (labels: a voxel takes its majority class, ties to
  the smallest);
- a mesh (:func:`voxelize_mesh`): the voxels its surface passes through (trimesh's subdivision:
  triangles split until no edge is longer than half a voxel, then the voxels of the vertices),
  or with ``fill=True`` also every voxel whose centre the mesh encloses, by the generalized
  winding number ``w > 1/2`` (:mod:`pointfield.volumes.triangles`), which holds on meshes that
  are not quite closed where a ray-parity or flood fill leaks through the holes.

:meth:`VoxelGrid.dense` gives the occupancy (or a field) as a dense array, after checking that it
fits the memory it is allowed (:func:`check_dense_fits`, which names the voxel that would).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.mesh import Mesh
from pointfield.errors import PointfieldError
from pointfield.streaming.voxels import VoxelGrid as GridLayout

DEFAULT_DENSE_BYTES = 1 << 30
"""What :meth:`VoxelGrid.dense` may allocate unless told otherwise: 1 GiB."""
FILL_BYTES_PER_VOXEL = 9
"""A filled grid's cost per voxel of its bounding box: the occupancy byte and an int64 key for each inside voxel."""
SUBDIVISION_BYTES_PER_AREA = 4200
"""Bytes the surface subdivision takes per unit of mesh area at voxel 1 (it scales with 1 / size^2):
edges end between a quarter and half a voxel, about 21 triangles per voxel^2 of area, each about 200
bytes with its three unshared vertices and numpy's temporaries."""


@dataclass(eq=False)
class VoxelGrid:
    """Occupied voxels ``coords`` ``(N, 3)`` int64 of a grid at ``origin`` ``(3,)`` with side ``size``.

    ``fields`` are per voxel, first dimension N; ``shape`` the voxels per axis the grid spans
    (default: one past the largest coordinate); ``metadata`` says where the grid came from.
    """

    coords: np.ndarray
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    size: float = 1.0
    fields: dict[str, np.ndarray] = field(default_factory=dict)
    shape: tuple[int, int, int] | None = None
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        coords = np.asarray(self.coords, np.int64).reshape(-1, 3)
        if len(coords) and coords.min() < 0:
            raise ValueError("voxel coordinates must be non-negative: move the origin to the grid's minimum corner")
        self.origin = np.asarray(self.origin, np.float64).reshape(3)
        self.size = float(self.size)
        if not (self.size > 0 and math.isfinite(self.size)):
            raise ValueError(f"voxel size must be positive and finite, got {self.size}")
        fields = {name: np.asarray(v) for name, v in self.fields.items()}
        for name, values in fields.items():
            if values.ndim == 0 or len(values) != len(coords):
                raise ValueError(f"voxel field {name!r} has shape {values.shape}; its first dimension must be {len(coords)}")
        spans = tuple(int(v) + 1 for v in coords.max(axis=0)) if len(coords) else (0, 0, 0)
        if self.shape is None:
            self.shape = spans  # type: ignore[assignment]
        else:
            self.shape = tuple(int(v) for v in self.shape)  # type: ignore[assignment]
            if any(s < n for s, n in zip(self.shape, spans)):
                raise ValueError(f"voxel coordinates reach {spans}, beyond the grid's shape {self.shape}")
        order = np.lexsort((coords[:, 2], coords[:, 1], coords[:, 0]))
        if len(order) and not np.array_equal(order, np.arange(len(order))):
            coords = coords[order]
            fields = {name: v[order] for name, v in fields.items()}
        self.coords = coords
        self.fields = fields

    def __len__(self) -> int:
        return len(self.coords)

    def __repr__(self) -> str:
        fields = ", ".join(f"{n}: {v.dtype}{list(v.shape[1:]) or ''}" for n, v in self.fields.items())
        return (f"VoxelGrid({len(self):,} voxels of {self.size:g} in {'x'.join(map(str, self.shape))} "
                f"from {np.round(self.origin, 6).tolist()}{'; ' + fields if fields else ''})")

    def centres(self) -> np.ndarray:
        """``(N, 3)`` float64 centres of the occupied voxels, ``origin + (ijk + 0.5) * size``."""
        return self.origin + (self.coords + 0.5) * self.size

    def to_cloud(self) -> PointCloud:
        """The voxel centres as a cloud with the voxel fields (how viewers and renderers draw a grid)."""
        metadata = {**self.metadata, "voxel_size": self.size, "voxel_origin": self.origin.tolist(),
                    "voxel_shape": list(self.shape)}
        return PointCloud(self.centres(), dict(self.fields), None, metadata)

    def dense(self, name: str | None = None, max_bytes: int = DEFAULT_DENSE_BYTES) -> np.ndarray:
        """The grid as a dense ``shape`` array: occupancy (bool) or, with ``name``, that field.

        Empty voxels of a field are 0. Raises :class:`PointfieldError` when the array would take
        more than ``max_bytes`` (the message gives the size needed and the voxel that fits).
        """
        values = None if name is None else self.fields[name]
        itemsize = 1 if values is None else values.dtype.itemsize * int(np.prod(values.shape[1:], dtype=np.int64))
        extent = np.asarray(self.shape, np.float64) * self.size
        check_dense_fits(extent, self.size, max_bytes, itemsize, what="a dense copy of the grid")
        if values is None:
            out = np.zeros(self.shape, bool)
            out[tuple(self.coords.T)] = True
            return out
        out = np.zeros((*self.shape, *values.shape[1:]), values.dtype)
        out[tuple(self.coords.T)] = values
        return out

    @classmethod
    def from_dense(cls, occupancy: np.ndarray, origin: np.ndarray | None = None, size: float = 1.0,
                   fields: dict[str, np.ndarray] | None = None) -> VoxelGrid:
        """The occupied (non-zero) voxels of a dense ``(X, Y, Z)`` array; ``fields`` dense too."""
        occupancy = np.asarray(occupancy)
        if occupancy.ndim != 3:
            raise ValueError(f"a dense grid has 3 dimensions, got shape {occupancy.shape}")
        coords = np.argwhere(occupancy != 0)
        picked = {name: np.asarray(v)[tuple(coords.T)] for name, v in (fields or {}).items()}
        return cls(coords, np.zeros(3) if origin is None else origin, size, picked, occupancy.shape)


def human_bytes(count: float) -> str:
    """``1536`` -> ``"1.5 KiB"``: sizes in messages."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if count < 1024 or unit == "PiB":
            return f"{count:.3g} {unit}" if unit != "B" else f"{int(count)} B"
        count /= 1024
    return f"{count:.3g} PiB"


def dense_bytes(extent: np.ndarray, size: float, bytes_per_voxel: int) -> tuple[tuple[int, ...], int]:
    """The voxels per axis a box of ``extent`` ``(3,)`` needs at ``size``, and their dense bytes."""
    shape = tuple(max(1, math.ceil(float(e) / size - 1e-9)) for e in extent)
    return shape, int(np.prod(np.asarray(shape, np.float64)) * bytes_per_voxel)


def fitting_voxel(extent: np.ndarray, max_bytes: int, bytes_per_voxel: int) -> float:
    """The smallest voxel whose dense grid over ``extent`` takes at most ``max_bytes`` (3 significant digits, rounded up)."""
    extent = np.maximum(np.asarray(extent, np.float64), 1e-300)
    size = float((np.prod(extent) * bytes_per_voxel / max(max_bytes, 1)) ** (1 / 3))
    for _ in range(64):  # ceil() of thin axes makes the first guess a little small
        if dense_bytes(extent, size, bytes_per_voxel)[1] <= max_bytes:
            break
        size *= 1.01
    digits = 10 ** (math.floor(math.log10(size)) - 2)
    return math.ceil(size / digits) * digits


def check_dense_fits(extent: np.ndarray, size: float, max_bytes: int, bytes_per_voxel: int, what: str) -> None:
    """Raise one line naming the bytes ``what`` needs and the voxel that fits, when it exceeds ``max_bytes``."""
    shape, needed = dense_bytes(extent, size, bytes_per_voxel)
    if needed > max_bytes:
        fits = fitting_voxel(extent, max_bytes, bytes_per_voxel)
        raise PointfieldError(
            f"a voxel of {size:g} makes {what} of {' x '.join(map(str, shape))} voxels, {human_bytes(needed)}, "
            f"more than the {human_bytes(max_bytes)} allowed: a voxel of {fits:g} or larger fits (or give more --memory)"
        )


def _finite_points(cloud: PointCloud) -> tuple[np.ndarray, np.ndarray]:
    points = np.asarray(cloud.points, np.float64)
    finite = np.isfinite(points).all(axis=1)
    return points[finite], finite


def voxelize_cloud(cloud: PointCloud, size: float) -> VoxelGrid:
    """The voxels of side ``size`` that ``cloud``'s finite points fall in, with per-voxel fields (module docstring).

    >>> grid = voxelize_cloud(PointCloud(np.array([[0.0, 0, 0], [0.1, 0, 0], [1.0, 0, 0]])), 0.5)
    >>> grid.coords.tolist(), grid.fields["counts"].tolist()
    ([[0, 0, 0], [2, 0, 0]], [2, 1])
    """
    points, finite = _finite_points(cloud)
    if not len(points):
        raise PointfieldError("the cloud has no finite points to voxelize")
    layout = GridLayout.covering(points.min(axis=0), points.max(axis=0), size)
    cells = layout.cells(points)
    keys = layout.keys(cells)
    order = np.argsort(keys, kind="stable")
    keys = keys[order]
    first = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
    counts = np.diff(np.r_[first, len(keys)])
    fields: dict[str, np.ndarray] = {"counts": counts.astype(np.int64)}
    for name, values in cloud.fields.items():
        if name == "counts":
            continue
        values = np.asarray(values)[finite][order]
        if np.issubdtype(values.dtype, np.floating) or name == "colors":
            mean = np.add.reduceat(values.astype(np.float64), first, axis=0) / counts.reshape(-1, *[1] * (values.ndim - 1))
            if name == "normals":
                mean /= np.maximum(np.linalg.norm(mean, axis=1, keepdims=True), 1e-12)
            if not np.issubdtype(values.dtype, np.floating):
                mean = np.rint(mean)
            fields[name] = mean.astype(values.dtype)
        elif values.ndim == 1 and (np.issubdtype(values.dtype, np.integer) or values.dtype == bool):
            fields[name] = _majority(keys, values, first)
    return VoxelGrid(cells[order][first], layout.origin, size, fields, layout.shape,
                     {"source": cloud.metadata.get("path", ""), "points": len(points)})


def _majority(sorted_keys: np.ndarray, values: np.ndarray, first: np.ndarray) -> np.ndarray:
    """Per run of equal ``sorted_keys`` (runs starting at ``first``), its most frequent value; ties to the smallest."""
    order = np.lexsort((values, sorted_keys))
    k, v = sorted_keys[order], values[order]
    starts = np.flatnonzero(np.r_[True, (k[1:] != k[:-1]) | (v[1:] != v[:-1])])
    lengths = np.diff(np.r_[starts, len(k)])
    run_key = k[starts]
    # Longest run per key; lexsort's last key is primary, so -lengths then value break ties to the smallest.
    best = np.lexsort((v[starts], -lengths, run_key))
    leader = np.r_[True, run_key[best][1:] != run_key[best][:-1]]
    chosen = v[starts][best][leader]
    assert len(chosen) == len(first)
    return chosen


def mesh_openness(mesh: Mesh) -> dict[str, int]:
    """How closed a mesh is: its edges, and those used by one face (``boundary``) or by more than two.

    A closed (watertight) surface has every edge shared by exactly two faces. Vertices at the same
    position count as one (ModelNet's files repeat them), and degenerate triangles are left out.
    """
    _, same = np.unique(np.asarray(mesh.points), axis=0, return_inverse=True)
    triangles = same.reshape(-1)[mesh.triangles()]
    triangles = triangles[(triangles[:, 0] != triangles[:, 1]) & (triangles[:, 1] != triangles[:, 2])
                          & (triangles[:, 2] != triangles[:, 0])]
    edges = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
    _, uses = np.unique(edges, axis=0, return_counts=True)
    return {"edges": len(uses), "boundary": int((uses == 1).sum()), "nonmanifold": int((uses > 2).sum())}


def openness_text(openness: dict[str, int]) -> str:
    """One phrase: ``"closed"`` or how many edges are open, for messages."""
    if openness["boundary"] == 0 and openness["nonmanifold"] == 0:
        return "closed (every edge shared by two faces)"
    share = 100 * openness["boundary"] / max(openness["edges"], 1)
    text = f"not closed: {openness['boundary']:,} of {openness['edges']:,} edges ({share:.1f} %) bound a hole"
    if openness["nonmanifold"]:
        text += f", {openness['nonmanifold']:,} shared by more than two faces"
    return text


def voxelize_mesh(mesh: Mesh, size: float, fill: bool = False, max_bytes: int = DEFAULT_DENSE_BYTES,
                  device: str | None = None) -> VoxelGrid:
    """The voxels of side ``size`` that ``mesh``'s surface passes through, and with ``fill`` its inside.

    The grid starts at the mesh's minimum corner. ``fill`` evaluates the winding number at every
    voxel centre of the bounding grid, so that grid's bool occupancy must fit ``max_bytes`` (its
    temporaries take about 60 bytes a voxel, done in slabs). ``metadata["openness"]`` says how
    closed the mesh was (:func:`mesh_openness`).
    """
    # Imported here, not at the top: torch and trimesh take seconds to import, and reading a
    # voxel file or voxelizing a cloud needs neither.
    import trimesh.remesh

    from pointfield.devices import pick_device
    from pointfield.volumes.triangles import TriangleClusters, winding_numbers

    triangles = mesh.triangles()
    if not len(triangles):
        raise PointfieldError("the mesh has no faces to voxelize")
    vertices = np.asarray(mesh.points, np.float64)
    if not np.isfinite(vertices).all():
        raise PointfieldError("the mesh has vertices that are not finite")
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    layout = GridLayout.covering(low, high, size)
    corners = vertices[triangles]
    area = 0.5 * float(np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1).sum())
    del corners
    needed = SUBDIVISION_BYTES_PER_AREA * area / size**2
    if needed > max_bytes:
        fits = math.sqrt(SUBDIVISION_BYTES_PER_AREA * area / max_bytes)
        raise PointfieldError(
            f"a voxel of {size:g} on a surface of area {area:.4g} needs about {human_bytes(needed)} to find "
            f"its voxels, more than the {human_bytes(max_bytes)} allowed: a voxel of {fits:.3g} or larger fits "
            "(or give more --memory)"
        )
    if fill:
        check_dense_fits(high - low, size, max_bytes, FILL_BYTES_PER_VOXEL, what="the filled grid")
    # Subdivide to edges of half a voxel at most; sample the edges of sliver triangles too by
    # taking the voxels of every vertex of the subdivided mesh (trimesh's "subdivide" voxelizer).
    fine, _ = trimesh.remesh.subdivide_to_size(vertices, triangles, max_edge=size / 2, max_iter=64)
    cells = np.minimum(layout.cells(fine), np.asarray(layout.shape) - 1)
    occupied = np.unique(layout.keys(cells))
    openness = mesh_openness(mesh)
    if fill:
        clusters = TriangleClusters.build(vertices, triangles, pick_device(device))
        nx, ny, nz = layout.shape
        inside = []
        slab = max(1, (1 << 20) // max(ny * nz, 1))
        j, k = np.meshgrid(np.arange(ny), np.arange(nz), indexing="ij")
        for first in range(0, nx, slab):
            i = np.arange(first, min(first + slab, nx))
            cells_slab = np.stack(np.broadcast_arrays(i[:, None, None], j[None], k[None]), axis=-1).reshape(-1, 3)
            w = winding_numbers(layout.centres(cells_slab), clusters)
            inside.append(layout.keys(cells_slab[w > 0.5]))
        occupied = np.union1d(occupied, np.concatenate(inside))
    nyz = layout.shape[1] * layout.shape[2]
    coords = np.stack([occupied // nyz, (occupied // layout.shape[2]) % layout.shape[1], occupied % layout.shape[2]], axis=1)
    return VoxelGrid(coords, layout.origin, size, {}, layout.shape,
                     {"source": mesh.metadata.get("path", ""), "filled": bool(fill), "openness": openness})
