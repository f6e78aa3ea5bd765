"""The arrays a registration works on, taken from a :class:`~pointfield.clouds.cloud.PointCloud` once.

A :class:`Scan` holds float64 points, and where the estimation needs them, unit normals, local
covariances (generalized ICP) and an intensity with its gradient on the tangent plane (coloured
ICP). What a cloud carries is used; what is missing is estimated here from the ``k`` nearest
neighbours, with the normals of :func:`pointfield.clouds.ops.estimate_normals`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.ops import estimate_normals, finite_rows, voxel_downsample


def query_workers(count: int) -> int:
    """scipy k-d tree ``workers`` for ``count`` queries: 1 below 50,000, else every core.

    Each threaded query starts and joins its threads; for small queries on a busy machine that
    cost more than the search (on the fragments of open3d's tutorial, half the time of a
    global registration went to joining threads).
    """
    return 1 if count < 50_000 else -1


def spatial_order(points: np.ndarray) -> np.ndarray:
    """``(N,)`` int64 permutation that puts ``(N, 3)`` points in Morton (Z-curve) order on a ``2^21`` grid.

    Neighbouring points then lie near each other in memory, and so do the k-d tree queries of
    consecutive points: on a 100,000-point KITTI pair, sampled in random order, small_gicp's
    point-to-plane ICP took half the CPU time with both clouds in this order (0.36 s against 0.77 s,
    the same 11 iterations and the same motion).
    """
    points = np.asarray(points, np.float64)
    if len(points) == 0:
        return np.zeros(0, np.int64)
    top = float(2**21 - 1)
    extent = max(float(np.ptp(points, axis=0).max()), 1e-300)
    cells = np.clip((points - points.min(axis=0)) * (top / extent), 0, top).astype(np.uint64)
    code = np.zeros(len(points), np.uint64)
    for axis in range(3):
        x = cells[:, axis]  # spread 21 bits to every third bit ("part 1 by 2")
        for shift, mask in ((32, 0x1F00000000FFFF), (16, 0x1F0000FF0000FF), (8, 0x100F00F00F00F00F),
                            (4, 0x10C30C30C30C30C3), (2, 0x1249249249249249)):
            x = (x | (x << np.uint64(shift))) & np.uint64(mask)
        code |= x << np.uint64(axis)
    return np.argsort(code, kind="stable")


@dataclass(eq=False)
class Scan:
    """``points`` ``(N, 3)`` float64; optional ``normals`` ``(N, 3)`` unit, ``intensity`` ``(N,)`` in [0, 1],
    ``covariances`` ``(N, 3, 3)``, ``gradients`` ``(N, 3)`` (d intensity / d position, in the tangent plane)."""

    points: np.ndarray
    normals: np.ndarray | None = None
    intensity: np.ndarray | None = None
    covariances: np.ndarray | None = None
    gradients: np.ndarray | None = None
    _tree: cKDTree | None = None

    @classmethod
    def from_cloud(cls, cloud: PointCloud) -> Scan:
        """The finite points of ``cloud`` with its normals (when finite and non-zero) and colours as intensity."""
        keep = finite_rows(cloud.points)
        normals = cloud.fields.get("normals")
        if normals is not None:
            normals = np.asarray(normals, np.float64)[keep]
            length = np.linalg.norm(normals, axis=1)
            normals = normals / np.maximum(length, 1e-12)[:, None] if np.all(np.isfinite(length) & (length > 0)) else None
        return cls(np.asarray(cloud.points, np.float64)[keep], normals, _intensity(cloud.fields.get("colors"), keep))

    @property
    def tree(self) -> cKDTree:
        """A k-d tree of the points, built on first use."""
        if self._tree is None:
            self._tree = cKDTree(self.points)
        return self._tree

    def __len__(self) -> int:
        return len(self.points)

    def downsample(self, voxel: float) -> Scan:
        """One point per voxel (the centroid; normals averaged and renormalised, intensity averaged):
        :func:`~pointfield.clouds.ops.voxel_downsample`'s voxels, in its order."""
        fields = {}
        if self.normals is not None:
            fields["normals"] = self.normals
        if self.intensity is not None:
            fields["intensity"] = self.intensity
        small = voxel_downsample(PointCloud(self.points, fields), voxel)
        return Scan(small.points, small.fields.get("normals"), small.fields.get("intensity"))

    def with_normals(self, neighbours: int = 20) -> Scan:
        """This scan with normals: its own, else PCA normals from ``neighbours`` nearest points,
        turned away from the centroid (a choice a rigid motion does not change, so that the two
        scans' normals agree wherever they see the same surface from the same side)."""
        if self.normals is not None:
            return self
        return replace(self, normals=estimate_normals(self.points, neighbours).astype(np.float64))

    def with_covariances(self, neighbours: int = 20, epsilon: float = 1e-3) -> Scan:
        """This scan with generalized ICP's plane-like covariances (Segal et al. 2009).

        The covariance of each point's ``neighbours`` nearest has eigenvectors ``u1, u2, u3`` by
        decreasing eigenvalue; it is replaced by ``U diag(1, 1, epsilon) U^T``: a unit disc in the
        local surface, thin along its normal, whatever the sampling density.
        """
        if self.covariances is not None:
            return self
        k = min(neighbours, len(self))
        _, index = self.tree.query(self.points, k=k, workers=query_workers(len(self)))
        groups = self.points[index.reshape(len(self), k)]
        deviations = groups - groups.mean(axis=1, keepdims=True)
        _, vectors = np.linalg.eigh(deviations.transpose(0, 2, 1) @ deviations / k)  # ascending
        shape = np.array([epsilon, 1.0, 1.0])
        return replace(self, covariances=(vectors * shape) @ vectors.transpose(0, 2, 1))

    def with_gradients(self, neighbours: int = 30) -> Scan:
        """This scan (normals needed) with the intensity gradient of Park et al. (2017) at every point.

        For point p with normal n and neighbours q, project each onto p's tangent plane,
        ``q' = q - ((q - p) . n) n``, and solve in least squares
        ``d . (q' - p) = I(q) - I(p)`` together with ``d . n = 0``: a 3-vector ``d`` in the plane.
        """
        if self.gradients is not None:
            return self
        scan = self.with_normals()
        k = min(neighbours, len(scan))
        _, index = scan.tree.query(scan.points, k=k, workers=query_workers(len(scan)))
        index = index.reshape(len(scan), k)
        offsets = scan.points[index] - scan.points[:, None]  # (N, k, 3)
        n = scan.normals
        offsets -= (offsets @ n[:, :, None]) * n[:, None, :]
        change = scan.intensity[index] - scan.intensity[:, None]
        a = offsets.transpose(0, 2, 1) @ offsets + k * n[:, :, None] * n[:, None, :]  # d . n = 0, weighted
        b = (offsets * change[:, :, None]).sum(axis=1)
        a += 1e-9 * np.eye(3)
        return replace(scan, gradients=np.linalg.solve(a, b[:, :, None])[:, :, 0])


def _intensity(colors: np.ndarray | None, keep: np.ndarray) -> np.ndarray | None:
    """``(N,)`` mean of R, G, B scaled to [0, 1] (uint8 by 255, uint16 by 65535, floats as they are)."""
    if colors is None or colors.ndim != 2 or colors.shape[1] < 3:
        return None
    rgb = np.asarray(colors[keep, :3])
    scale = float(np.iinfo(rgb.dtype).max) if np.issubdtype(rgb.dtype, np.integer) else (
        255.0 if rgb.size and float(np.nanmax(rgb)) > 1.0 else 1.0)
    return rgb.astype(np.float64).mean(axis=1) / scale
