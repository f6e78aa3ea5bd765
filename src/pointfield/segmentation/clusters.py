"""Density clusters: DBSCAN (Ester et al. 1996), which with ``min_points = 1`` is PCL's Euclidean clusters.

A point is a core point when at least ``min_points`` points (itself included) lie within
``eps``; core points within ``eps`` of each other share a cluster (connected components of
that graph, scipy); a non-core point within ``eps`` of a core point joins that point's
cluster; the rest are noise (-1). Clusters are numbered by size, largest first.
:func:`clusters_beside_planes` takes the planes of :func:`~pointfield.segmentation.segment_planes`
out first, each as one cluster.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from pointfield.clouds.ops import finite_rows


def dbscan(points: np.ndarray, eps: float, min_points: int = 10) -> np.ndarray:
    """``(N,)`` int32 cluster of each of ``(N, 3)`` points, largest cluster 0, noise and NaN points -1."""
    points = np.asarray(points)
    labels = np.full(len(points), -1, np.int32)
    finite = np.flatnonzero(finite_rows(points))
    if len(finite) == 0:
        return labels
    valid = points[finite].astype(np.float64)
    tree = cKDTree(valid)
    pairs = tree.query_pairs(eps, output_type="ndarray")
    neighbours = np.bincount(pairs.ravel(), minlength=len(valid)) + 1
    core = neighbours >= min_points
    both = core[pairs[:, 0]] & core[pairs[:, 1]]
    graph = coo_matrix((np.ones(both.sum()), (pairs[both, 0], pairs[both, 1])), shape=(len(valid), len(valid)))
    _, component = connected_components(graph, directed=False)
    assigned = np.where(core, component, -1)
    # border points: take the cluster of a core neighbour
    for a, b in ((0, 1), (1, 0)):
        border = ~core[pairs[:, a]] & core[pairs[:, b]]
        assigned[pairs[border, a]] = component[pairs[border, b]]
    labels[finite] = by_size(assigned)
    return labels


def by_size(labels: np.ndarray) -> np.ndarray:
    """``(N,)`` int32 ``labels`` renumbered 0, 1, ... from the largest cluster down; negative stays -1."""
    out = np.full(len(labels), -1, np.int32)
    clustered = labels >= 0
    if clustered.any():
        ids, inverse, sizes = np.unique(labels[clustered], return_inverse=True, return_counts=True)
        rank = np.empty(len(ids), np.int32)
        rank[np.argsort(-sizes, kind="stable")] = np.arange(len(ids), dtype=np.int32)
        out[clustered] = rank[inverse.reshape(-1)]
    return out


def clusters_beside_planes(points: np.ndarray, planes: np.ndarray, eps: float, min_points: int = 10) -> np.ndarray:
    """``(N,)`` int32: each plane of ``planes`` (``(N,)`` labels of :func:`~pointfield.segmentation.segment_planes`,
    -1 off every plane) one cluster, and :func:`dbscan` clusters of the points off them; all numbered by size.

    PCL's table-top pipeline: the supporting plane taken out first, as objects that stand on it
    would otherwise join it through the points where they touch.
    """
    planes = np.asarray(planes)
    off = planes < 0
    labels = np.where(off, -1, planes).astype(np.int64)
    found = dbscan(np.asarray(points)[off], eps, min_points)
    labels[np.flatnonzero(off)] = np.where(found >= 0, found + planes.max(initial=-1) + 1, -1)
    return by_size(labels)
