"""RANSAC planes, largest first: PCL's ``SACMODEL_PLANE`` / open3d's ``segment_plane``, repeated.

A plane is ``a x + b y + c z + d = 0`` with ``(a, b, c)`` a unit normal. RANSAC draws three
points, takes the plane through them, and counts the points within ``distance`` of it;
hypotheses are drawn in batches and scored as arrays, and drawing stops once ``confidence``
says a sample of three inliers has been seen (``k = log(1 - confidence) / log(1 - w^3)``) or
after ``iterations``. The best plane is refitted to its inliers by least squares (the normal
is the smallest principal axis of their covariance, as PCL's ``optimizeModelCoefficients``)
and its inliers recounted, until they no longer change; they are removed before the next
plane is searched.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pointfield.clouds.ops import finite_rows


@dataclass(frozen=True)
class Plane:
    """``equation`` ``(4,)`` float64 ``(a, b, c, d)`` with unit ``(a, b, c)``; ``inliers`` ``(K,)`` int64 point indices."""

    equation: np.ndarray
    inliers: np.ndarray

    def as_dict(self) -> dict:
        return {"equation": [float(v) for v in self.equation], "points": len(self.inliers)}


def fit_plane(points: np.ndarray) -> np.ndarray:
    """``(4,)`` least-squares plane of ``(K, 3)`` points: through their mean, normal along their least spread."""
    centre = points.mean(axis=0)
    _, vectors = np.linalg.eigh(np.cov((points - centre).T))
    normal = vectors[:, 0]
    return np.append(normal, -normal @ centre)


def ransac_plane(points: np.ndarray, distance: float, iterations: int = 1000, confidence: float = 0.999,
                 rng: np.random.Generator | None = None, batch: int = 256, scored: int = 20_000) -> np.ndarray | None:
    """``(4,)`` the plane with most of ``(N, 3)`` float64 points within ``distance``, refitted; None below 3 points.

    Hypotheses are scored on at most ``scored`` points drawn at random (the share of inliers, which
    is all RANSAC compares, is estimated as well from them: 241,000 points of a table top took 77 s
    scored in full); the refit and its inliers use every point.
    """
    rng = rng or np.random.default_rng(0)
    if len(points) < 3:
        return None
    scoring = points if len(points) <= scored else points[rng.choice(len(points), scored, replace=False)]
    best, best_count, needed, drawn = None, 0, iterations, 0
    while drawn < min(needed, iterations):
        size = min(batch, iterations - drawn)
        drawn += size
        sample = points[rng.integers(0, len(points), (size, 3))]
        normals = np.cross(sample[:, 1] - sample[:, 0], sample[:, 2] - sample[:, 0])
        length = np.linalg.norm(normals, axis=1)
        usable = length > 1e-12
        normals = normals[usable] / length[usable, None]
        offsets = -(normals * sample[usable, 0]).sum(axis=1)
        for start in range(0, len(normals), 32):
            counts = (np.abs(scoring @ normals[start:start + 32].T + offsets[start:start + 32]) <= distance).sum(axis=0)
            top = int(np.argmax(counts)) if len(counts) else 0
            if len(counts) and counts[top] > best_count:
                best_count = int(counts[top])
                best = np.append(normals[start + top], offsets[start + top])
        if best_count >= 3:
            share = best_count / len(scoring)
            needed = int(np.ceil(np.log(1 - confidence) / np.log(max(1 - share**3, 1e-12))))
    if best is None:
        return None
    inliers = np.abs(points @ best[:3] + best[3]) <= distance
    for _ in range(10):  # refit until the inliers stop changing: the plane of its own inliers
        if inliers.sum() < 3:
            break
        best = fit_plane(points[inliers])
        again = np.abs(points @ best[:3] + best[3]) <= distance
        if np.array_equal(again, inliers):
            break
        inliers = again
    return best


def segment_planes(points: np.ndarray, count: int = 1, distance: float | None = None, min_points: int = 3,
                   iterations: int = 1000, seed: int = 0) -> tuple[list[Plane], np.ndarray]:
    """``(planes, labels)``: up to ``count`` planes taken out one after another, largest first.

    ``points`` ``(N, 3)``; ``labels`` ``(N,)`` int32, the index of each point's plane or -1 (no plane,
    or a NaN point). ``distance``: inlier distance (default: 1 % of the bounding-box diagonal).
    A plane with fewer than ``min_points`` inliers ends the search.
    """
    points = np.asarray(points)
    finite = np.flatnonzero(finite_rows(points))
    remaining = points[finite].astype(np.float64)
    if distance is None:
        distance = 0.01 * float(np.linalg.norm(np.ptp(remaining, axis=0))) if len(remaining) else 0.0
    labels = np.full(len(points), -1, np.int32)
    rng = np.random.default_rng(seed)
    planes: list[Plane] = []
    for _ in range(count):
        equation = ransac_plane(remaining, distance, iterations, rng=rng)
        if equation is None:
            break
        inside = np.abs(remaining @ equation[:3] + equation[3]) <= distance
        if inside.sum() < max(min_points, 3):
            break
        labels[finite[inside]] = len(planes)
        planes.append(Plane(equation, finite[inside]))
        finite, remaining = finite[~inside], remaining[~inside]
    return planes, labels
