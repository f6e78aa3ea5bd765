"""Density clusters: DBSCAN (Ester et al. 1996), which with ``min_points = 1`` is PCL's Euclidean clusters.

A point is a core point when at least ``min_points`` points (itself included) lie within
``eps``; core points within ``eps`` of each other share a cluster (connected components of
that graph, scipy); a non-core point within ``eps`` of a core point joins the nearest such
point's cluster; the rest are noise (-1). Clusters are numbered by size, largest first.
:func:`clusters_beside_planes` takes the planes of :func:`~pointfield.segmentation.segment_planes`
out first, each as one cluster.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from pointfield.clouds.ops import finite_rows


def dbscan(points: np.ndarray, eps: float, min_points: int = 10, max_pairs: int = 4_000_000) -> np.ndarray:
    """``(N,)`` int32 cluster of each of ``(N, 3)`` points, largest cluster 0, noise and NaN points -1.

    Memory stays O(N + ``max_pairs``): neighbours are counted without listing them, the pairs of
    core points are found a block of core points at a time (at most about ``max_pairs`` per
    block), and each block's pairs are merged into the components found so far. A border point
    joins the cluster of its nearest core point. (Listing every pair at once took 4.4 GB for a
    307,200-point Kinect frame at eps 2.5 cm.)
    """
    points = np.asarray(points)
    labels = np.full(len(points), -1, np.int32)
    finite = np.flatnonzero(finite_rows(points))
    if len(finite) == 0:
        return labels
    valid = points[finite].astype(np.float64)
    tree = cKDTree(valid)
    neighbours = tree.query_ball_point(valid, eps, return_length=True, workers=-1)  # itself included
    core = np.flatnonzero(neighbours >= min_points)
    assigned = np.full(len(valid), -1, np.int64)
    if len(core) == 0:
        labels[finite] = assigned
        return labels
    core_tree = cKDTree(valid[core])
    # Components so far as a representative per core point; a block's pairs plus an edge from each
    # point to its representative give the components of everything seen.
    representative = np.arange(len(core))
    ends = np.searchsorted(np.cumsum(neighbours[core]), np.arange(max_pairs, neighbours[core].sum(), max_pairs))
    for block in np.split(np.arange(len(core)), np.unique(ends)):
        if len(block) == 0:
            continue
        pairs = cKDTree(valid[core[block]]).sparse_distance_matrix(core_tree, eps, output_type="ndarray")
        rows = np.concatenate([block[pairs["i"]], np.arange(len(core))])
        columns = np.concatenate([pairs["j"], representative])
        graph = coo_matrix((np.ones(len(rows), np.int8), (rows, columns)), shape=(len(core), len(core)))
        _, component = connected_components(graph, directed=False)
        _, first = np.unique(component, return_index=True)  # the lowest core point of each component
        representative = first[component]
    assigned[core] = representative
    border = np.flatnonzero((neighbours < min_points) & (neighbours > 1))
    distance, nearest = core_tree.query(valid[border], distance_upper_bound=eps)
    near = np.isfinite(distance)
    assigned[border[near]] = representative[nearest[near]]
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
