"""A watertight mesh through oriented points: Poisson surface reconstruction (Kazhdan et al. 2006) on a grid.

The surface is a level set of an indicator function chi whose gradient matches the points'
normals: smeared onto a grid they make a vector field V, and chi solves the Poisson equation

    laplacian(chi) = div(V)

Here on a regular grid of ``2^depth`` cells across the points' box grown by ``scale`` (open3d's and
PoissonRecon's ``depth`` and ``scale``: the finest cell is the same), solved exactly by the FFT
with the grid's own finite differences -- central differences for the divergence, the 7-point
Laplacian -- as eigenvalues:

    chi^(k) = sum_a i sin(k_a h) / h * V^_a(k)  /  sum_a (2 cos(k_a h) - 2) / h^2

The FFT's domain is periodic, so the grid is padded by an eighth on every side for the copies not
to meet. V is each point's normal splatted trilinearly onto the eight nodes around it, then
smoothed by a Gaussian of one cell (the role of PoissonRecon's B-spline kernel). The surface is
chi's level at the mean of chi over the points (Kazhdan's choice), by marching cubes: closed,
because chi is defined everywhere in a box that the level set does not reach (degenerate
triangles, where the level passes exactly through a node, are dropped: kept, they make edges of
four faces).

What this is not: screened Poisson (Kazhdan and Hoppe 2013), which adds ``alpha * sum_i (chi(p_i) -
iso)^2`` to pull the surface onto the points, and its octree, which refines only near them.
The benchmark (``benchmarks/bench_poisson.py``) says what that costs against open3d's.
"""

from __future__ import annotations

import warnings

import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.mesh import Mesh
from pointfield.clouds.ops import estimate_normals
from pointfield.errors import PointfieldError
from pointfield.volumes.sdf import SDFGrid
from pointfield.volumes.voxels import check_dense_fits

POISSON_BYTES_PER_NODE = 64
"""Three float32 components, their complex spectra, chi and the solve's temporaries."""


def _splat(grid: np.ndarray, local: np.ndarray, values: np.ndarray) -> None:
    """Add ``values`` ``(N, C)`` trilinearly at fractional node coordinates ``local`` ``(N, 3)`` of ``grid`` ``(X, Y, Z, C)``."""
    base = np.floor(local).astype(np.int64)
    frac = local - base
    for corner in range(8):
        offset = np.array([(corner >> 2) & 1, (corner >> 1) & 1, corner & 1])
        weight = np.prod(np.where(offset, frac, 1 - frac), axis=1)
        index = base + offset
        np.add.at(grid, (index[:, 0], index[:, 1], index[:, 2]), values * weight[:, None])


def _sample(grid: np.ndarray, local: np.ndarray) -> np.ndarray:
    """Trilinear values ``(N,)`` of ``grid`` ``(X, Y, Z)`` at fractional node coordinates ``local``."""
    base = np.floor(local).astype(np.int64)
    frac = local - base
    out = np.zeros(len(local))
    for corner in range(8):
        offset = np.array([(corner >> 2) & 1, (corner >> 1) & 1, corner & 1])
        index = base + offset
        out += np.prod(np.where(offset, frac, 1 - frac), axis=1) * grid[index[:, 0], index[:, 1], index[:, 2]]
    return out


def poisson_surface(cloud: PointCloud, depth: int = 8, scale: float = 1.1, max_bytes: int = 4 << 30) -> Mesh:
    """A closed mesh through ``cloud``'s points, from their ``normals`` (module docstring).

    A cloud without normals gets them from :func:`~pointfield.clouds.ops.estimate_normals`, oriented
    away from its centroid, with a warning saying so: right for closed, roughly convex objects,
    wrong in deep concavities (orient them yourself and pass them in the ``normals`` field).
    """
    points = np.asarray(cloud.points, np.float64)
    finite = np.isfinite(points).all(axis=1)
    if finite.sum() < 16:
        raise PointfieldError(f"Poisson reconstruction needs at least 16 finite points, got {int(finite.sum())}")
    if "normals" in cloud.fields:
        normals = np.asarray(cloud.fields["normals"], np.float64)
        finite &= np.isfinite(normals).all(axis=1)
        normals = normals[finite]
        points = points[finite]
    else:
        points = points[finite]
        normals = estimate_normals(points).astype(np.float64)
        warnings.warn("the cloud has no normals: estimated them by PCA of 16 neighbours, oriented away from the "
                      "centroid (right for closed, roughly convex objects; pass oriented normals for others)",
                      stacklevel=2)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = normals / np.maximum(length, 1e-12)
    if not 1 <= depth <= 10:
        raise PointfieldError(f"depth must be 1..10 (2^depth cells across), got {depth}")
    cells = 1 << depth
    pad = max(2, cells // 8)
    size = cells + 2 * pad
    low, high = points.min(axis=0), points.max(axis=0)
    extent = float((high - low).max()) * scale
    if not extent > 0:
        raise PointfieldError("the points span no volume")
    h = extent / cells
    check_dense_fits(np.full(3, size * h), h, max_bytes, POISSON_BYTES_PER_NODE, what="the Poisson grid")
    origin = (low + high) / 2 - extent / 2 - pad * h
    local = (points - origin) / h

    field = np.zeros((size, size, size, 3), np.float32)
    _splat(field, local, normals.astype(np.float32))
    k = 2 * np.pi * np.fft.fftfreq(size)  # radians per node
    kr = 2 * np.pi * np.fft.rfftfreq(size)
    kx, ky, kz = k[:, None, None], k[None, :, None], kr[None, None, :]
    smooth = np.exp(-0.5 * (kx**2 + ky**2 + kz**2))  # a Gaussian of one cell
    divergence = sum(1j * np.sin(kk) / h * np.fft.rfftn(field[..., a]) for a, kk in enumerate((kx, ky, kz)))
    del field
    laplacian = ((2 * np.cos(kx) - 2) + (2 * np.cos(ky) - 2) + (2 * np.cos(kz) - 2)) / h**2
    laplacian[0, 0, 0] = 1.0
    spectrum = divergence * smooth / laplacian
    spectrum[0, 0, 0] = 0.0
    chi = np.fft.irfftn(spectrum, s=(size, size, size), axes=(0, 1, 2)).astype(np.float32)
    del spectrum, divergence
    iso = float(_sample(chi, local).mean())
    # Faces front the way the points' normals point: chi - iso taken as a signed distance (growing outwards,
    # which SDFGrid.to_mesh's marching cubes faces) where chi grows along the normals, iso - chi where it falls.
    along = float(np.mean(_sample(chi, local + normals) - _sample(chi, local - normals)))
    mesh = SDFGrid((chi - iso) if along > 0 else (iso - chi), origin, h).to_mesh()
    mesh.metadata = {"source": "poisson", "depth": depth, "iso": iso}
    return mesh
