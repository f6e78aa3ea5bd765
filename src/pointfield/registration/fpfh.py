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

The three angles of a pair need only five numbers, the same in both directions up to signs
(:func:`pair_scalars`), so each unordered pair of neighbours is gathered and multiplied once and
both directions are read off it (:func:`directed_features`): on the thinned fragments of
open3d's tutorial (2,900 points, 215,000 neighbour pairs) 45 ms per cloud against 90 ms for the
same histograms from every ordered pair.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.spatial import cKDTree

BINS = 11


def neighbour_pairs(points: np.ndarray, radius: float, max_nn: int, tree: cKDTree | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(i, j, keep_ij, keep_ji)``: the unordered pairs ``i < j`` of points closer than ``radius``, and
    whether j is among i's ``max_nn`` nearest within ``radius`` (itself counted, open3d's hybrid
    search) and i among j's. Each ``(P,)``.

    All pairs come from one ``query_pairs`` (a tree walk, no per-point heaps); only points with
    more than ``max_nn - 1`` neighbours ask the tree for their ``max_nn`` nearest, to know which to drop.
    """
    n = len(points)
    tree = tree or cKDTree(points)
    pairs = tree.query_pairs(radius * (1 - 1e-12), output_type="ndarray")  # < radius, as the hybrid search
    i, j = pairs[:, 0].astype(np.int64), pairs[:, 1].astype(np.int64)
    keep_ij, keep_ji = np.ones(len(i), bool), np.ones(len(i), bool)
    k = min(max_nn, n)
    crowded = np.flatnonzero(np.bincount(i, minlength=n) + np.bincount(j, minlength=n) >= k)
    if len(crowded) and len(i):
        _, nearest = tree.query(points[crowded], k=k, distance_upper_bound=radius)
        allowed = np.sort((crowded[:, None] * n + nearest.reshape(len(crowded), k)[:, 1:]).ravel())
        is_crowded = np.zeros(n, bool)
        is_crowded[crowded] = True
        for keep, a, b in ((keep_ij, i, j), (keep_ji, j, i)):
            check = np.flatnonzero(is_crowded[a])
            keys = a[check] * n + b[check]
            at = np.minimum(np.searchsorted(allowed, keys), len(allowed) - 1)
            keep[check] = allowed[at] == keys
    return i, j, keep_ij, keep_ji


def pair_scalars(points: np.ndarray, normals: np.ndarray, i: np.ndarray, j: np.ndarray
                 ) -> tuple[np.ndarray, ...]:
    """The five scalars of P point pairs from which both directions' features follow, each ``(P,)``.

    ``(length, d_i, d_j, c, t)`` for ``d = p_j - p_i``: ``|d|``, ``n_i . d``, ``n_j . d``,
    ``n_i . n_j`` and ``d . (n_i x n_j)``. Seen from j, ``d`` turns round: ``d_i, d_j`` become
    ``-d_j, -d_i`` and ``c``, ``t`` stay."""
    d = points[j] - points[i]
    n_i, n_j = normals[i], normals[j]
    length = np.sqrt(np.einsum("pi,pi->p", d, d))
    return (length, np.einsum("pi,pi->p", n_i, d), np.einsum("pi,pi->p", n_j, d),
            np.einsum("pi,pi->p", n_i, n_j), np.einsum("pi,pi->p", d, _cross(n_i, n_j)))


def directed_features(length: np.ndarray, d_s: np.ndarray, d_t: np.ndarray, c: np.ndarray, t: np.ndarray
                      ) -> tuple[np.ndarray, ...]:
    """``(theta, alpha, phi, ok)`` of P pairs from source s to target t, from :func:`pair_scalars`'.

    The pair starts from the better-aligned normal: swapped when ``|n_s . d| < |n_t . d|`` (then
    ``u = n_t``, the other normal ``n_s`` and ``d`` reversed). With ``v = d x u / |d x u|``,
    ``w = u x v`` and unit normals, ``|d x u| = sqrt(|d|^2 - (u . d)^2)``,
    ``alpha = v . n_other = d . (n_s x n_t) / |d x u|`` (the same either way),
    ``w . n_other = (d . n_other - (u . d) c) / |d x u|`` and ``phi = u . d / |d|``; ``ok`` is False
    for coincident points or a line along the normal (open3d counts those in no bin).
    """
    swap = np.abs(d_s) < np.abs(d_t)
    along = np.where(swap, d_t, d_s)
    across = np.sqrt(np.maximum(length**2 - along**2, 0.0))
    ok = (length > 0) & (across > 0)
    across = np.where(ok, across, 1.0)
    alpha = t / across
    phi = np.where(swap, -d_t, d_s) / np.where(length > 0, length, 1.0)
    theta = np.arctan2(np.where(swap, d_t * c - d_s, d_t - d_s * c) / across, c)
    return theta, alpha, phi, ok


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross products of ``(P, 3)`` arrays (np.cross is several times slower on long arrays)."""
    out = np.empty_like(a)
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


def compute_fpfh(points: np.ndarray, normals: np.ndarray, radius: float, max_nn: int = 100,
                 tree: cKDTree | None = None) -> np.ndarray:
    """``(N, 33)`` float64 FPFH of each point from its neighbours within ``radius`` (at most ``max_nn``,
    itself included, as open3d's hybrid search).

    ``points`` and ``normals`` ``(N, 3)`` (unit normals); the normals' signs matter, and should agree
    between the two scans being matched. Bins: theta over [-pi, pi], alpha and phi over [-1, 1].
    ``tree``: a k-d tree of ``points`` already built.
    """
    points, normals = np.asarray(points, np.float64), np.asarray(normals, np.float64)
    n = len(points)
    i, j, keep_ij, keep_ji = neighbour_pairs(points, radius, max_nn, tree)
    length, d_i, d_j, c, t = pair_scalars(points, normals, i, j)
    # Both directions of every pair, then the ones a crowded neighbourhood leaves out dropped.
    theta, alpha, phi, ok = (np.concatenate(halves) for halves in zip(directed_features(length, d_i, d_j, c, t),
                                                                      directed_features(length, -d_j, -d_i, c, t)))
    rows, others, kept = np.concatenate([i, j]), np.concatenate([j, i]), np.concatenate([keep_ij, keep_ji])
    increment = 100.0 / np.maximum(np.bincount(rows[kept], minlength=n), 1)
    spfh = np.zeros((n, 3 * BINS))
    ok &= kept
    counted = rows[ok]
    for offset, values, low, span in ((0, theta, -np.pi, 2 * np.pi), (BINS, alpha, -1.0, 2.0), (2 * BINS, phi, -1.0, 2.0)):
        bins = np.clip(np.floor(BINS * (values[ok] - low) / span).astype(np.int64), 0, BINS - 1)
        spfh += np.bincount(counted * 3 * BINS + offset + bins, weights=increment[counted],
                            minlength=n * 3 * BINS).reshape(n, 3 * BINS)
    squared = np.concatenate([length, length]) ** 2
    weighted = kept & (squared > 0)
    weights = coo_matrix((1.0 / squared[weighted], (rows[weighted], others[weighted])), shape=(n, n))
    fpfh = weights @ spfh
    sums = fpfh.reshape(n, 3, BINS).sum(axis=2, keepdims=True)
    scale = np.where(sums > 0, 100.0 / np.where(sums > 0, sums, 1.0), 0.0)
    return (fpfh.reshape(n, 3, BINS) * scale).reshape(n, 3 * BINS) + spfh
