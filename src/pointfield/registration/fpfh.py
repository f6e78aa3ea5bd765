"""Fast Point Feature Histograms (Rusu, Blodow, Beetz, ICRA 2009): 33 numbers that describe a point's
neighbourhood, the same whatever the pose, so that points can be matched across two scans.

For a point pair (p_s, n_s), (p_t, n_t) at distance ``d = |p_t - p_s|``, with the source of the
pair the one whose normal makes the smaller angle with the line joining them, a Darboux frame
``u = n_s``, ``v = (p_t - p_s) x u / |...|``, ``w = u x v`` gives three angles::

    alpha = v . n_t     phi = u . (p_t - p_s) / d     theta = atan2(w . n_t, u . n_t)

Each point's SPFH is the three 11-bin histograms of those over its neighbours (each bin in
percent); its FPFH adds the neighbours' SPFHs weighted by one over their squared distance,
each histogram rescaled to 100. This is open3d's ``compute_fpfh_feature`` (same binning, same
weights), computed for all pairs at once in numpy.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import csr_matrix
from scipy.spatial import cKDTree

from pointfield.registration.scan import query_workers

BINS = 11


def neighbourhoods(points: np.ndarray, radius: float, max_nn: int, tree: cKDTree | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(index (N, K), squared distance (N, K), valid (N, K))``: up to ``max_nn`` neighbours within
    ``radius`` (open3d's hybrid search), each point first in its own row."""
    tree = tree or cKDTree(points)
    k = min(max_nn, len(points))
    distance, index = tree.query(points, k=k, distance_upper_bound=radius, workers=query_workers(len(points)))
    distance, index = distance.reshape(len(points), k), index.reshape(len(points), k)
    valid = np.isfinite(distance)
    index = np.where(valid, index, 0)
    return index, np.where(valid, distance**2, 0.0), valid


def pair_features(d: np.ndarray, n_s: np.ndarray, n_t: np.ndarray) -> tuple[np.ndarray, ...]:
    """``(theta, alpha, phi, ok)`` of P point pairs, each ``(P,)``, from ``(P, 3)`` offsets ``d = p_t - p_s``
    and normals; ``ok`` is False for coincident points or a line parallel to the normal (open3d
    counts those in no bin). ``d`` is overwritten."""
    length = np.sqrt(np.einsum("pi,pi->p", d, d))
    safe = np.maximum(length, 1e-300)
    angle_s = np.einsum("pi,pi->p", n_s, d) / safe
    angle_t = np.einsum("pi,pi->p", n_t, d) / safe
    swap = np.abs(angle_s) < np.abs(angle_t)  # acos(|a_s|) > acos(|a_t|): start from the better-aligned normal
    u = np.where(swap[:, None], n_t, n_s)
    other = np.where(swap[:, None], n_s, n_t)
    d[swap] *= -1
    phi = np.where(swap, -angle_t, angle_s)
    v = _cross(d, u)
    v_length = np.sqrt(np.einsum("pi,pi->p", v, v))
    v /= np.maximum(v_length, 1e-300)[:, None]
    w = _cross(u, v)
    alpha = np.einsum("pi,pi->p", v, other)
    theta = np.arctan2(np.einsum("pi,pi->p", w, other), np.einsum("pi,pi->p", u, other))
    return theta, alpha, phi, (length > 0) & (v_length > 0)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross products of ``(P, 3)`` arrays (np.cross is several times slower on long arrays)."""
    out = np.empty_like(a)
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


def compute_fpfh(points: np.ndarray, normals: np.ndarray, radius: float, max_nn: int = 100) -> np.ndarray:
    """``(N, 33)`` float64 FPFH of each point from its neighbours within ``radius`` (at most ``max_nn``).

    ``points`` and ``normals`` ``(N, 3)``; the normals' signs matter, and should agree between
    the two scans being matched. Bins: theta over [-pi, pi], alpha and phi over [-1, 1].
    """
    points, normals = np.asarray(points, np.float64), np.asarray(normals, np.float64)
    n = len(points)
    index, distance2, valid = neighbourhoods(points, radius, max_nn)
    valid[:, 0] = False  # the point itself
    rows, columns = np.nonzero(valid)
    others = index[rows, columns]
    # Offsets in float64 (UTM-sized coordinates), the angles in float32: bins of 1/11 need no more.
    offsets = (points[others] - points[rows]).astype(np.float32)
    unit = normals.astype(np.float32)
    theta, alpha, phi, ok = pair_features(offsets, unit[rows], unit[others])
    neighbours = np.bincount(rows, minlength=n)
    increment = 100.0 / np.maximum(neighbours, 1)
    spfh = np.zeros((n, 3 * BINS))
    counted = rows[ok]
    for offset, values, low, span in ((0, theta, -np.pi, 2 * np.pi), (BINS, alpha, -1.0, 2.0), (2 * BINS, phi, -1.0, 2.0)):
        bins = np.clip(np.floor(BINS * (values[ok] - low) / span).astype(np.int64), 0, BINS - 1)
        spfh += np.bincount(counted * 3 * BINS + offset + bins, weights=increment[counted],
                            minlength=n * 3 * BINS).reshape(n, 3 * BINS)
    distance2 = distance2[rows, columns]
    weighted = distance2 > 0
    weights = csr_matrix((1.0 / distance2[weighted], (rows[weighted], others[weighted])), shape=(n, n))
    fpfh = weights @ spfh
    sums = fpfh.reshape(n, 3, BINS).sum(axis=2, keepdims=True)
    scale = np.where(sums > 0, 100.0 / np.where(sums > 0, sums, 1.0), 0.0)
    return (fpfh.reshape(n, 3, BINS) * scale).reshape(n, 3 * BINS) + spfh
