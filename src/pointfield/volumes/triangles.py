"""Queries of a triangle soup: generalized winding numbers and distances to the nearest triangle.

Both are sums or minima over every triangle, done as Barill et al. (SIGGRAPH 2018, "Fast winding
numbers for soups and clouds") do: triangles are grouped into clusters (by the voxel their centroid
falls in, :class:`TriangleClusters`), each with a bounding sphere; a query treats a cluster near it
triangle by triangle and a cluster far from it as a whole.

Generalized winding number (Jacobson et al. 2013) of the oriented triangles at a point q::

    w(q) = 1/(4 pi) * sum_t Omega_t(q)

where Omega_t is the signed solid angle triangle t subtends at q (van Oosterom and Strackee 1983),
with a, b, c its corners minus q::

    tan(Omega / 2) = a . (b x c) / (|a||b||c| + (a . b)|c| + (b . c)|a| + (c . a)|b|)

For a closed mesh with outward normals (counter-clockwise seen from outside) w is 1 inside and 0
outside; for a mesh with holes it moves smoothly between them, which is why ``w > 1/2`` is a sign
that survives a mesh that is not quite closed. A cluster whose sphere (centre p, radius r) is at
least ``BETA * r`` from q contributes its dipole term instead, the first term of Barill's
expansion::

    w_cluster(q) ~= A . (p - q) / (4 pi |p - q|^3),   A = sum_t area_t n_t (the area vector)

Distance to the nearest triangle. An upper bound U(q) first: the distance to the nearest of points
sampled on the triangles (a scipy KD-tree). Only clusters whose sphere comes within U(q) of q can
hold a nearer triangle; their triangles get the exact point-triangle distance (Ericson,
"Real-Time Collision Detection", 5.1.5: the closest point found by the Voronoi region of the
triangle that q projects into).

Shapes: queries ``(Q, 3)``, vertices ``(V, 3)``, triangles ``(T, 3)`` vertex indices. Work is done
in torch float64 on the device given (one place chooses it: :mod:`pointfield.devices`), in
batches of queries so that memory stays bounded whatever Q is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial import cKDTree

BETA = 2.0
"""A cluster at least ``BETA`` of its radii from a query is summed as one dipole (Barill et al.'s default)."""
TRIANGLES_PER_CLUSTER = 8
MAX_SAMPLE_STEPS = 2048
"""Samples along a triangle's longest edge at most (about two million on the triangle)."""
PAIRS_PER_BATCH = 1 << 22
"""Query-triangle pairs evaluated at once: about 1 GB of float64 temporaries at most."""


@dataclass
class TriangleClusters:
    """Triangles sorted by cluster, and each cluster's bounding sphere and area vector.

    ``corners`` ``(T, 3, 3)`` float64, in cluster order; ``start``/``count`` ``(K,)`` the range of
    each cluster's triangles in it; ``centre`` ``(K, 3)`` the area-weighted centroid, ``radius``
    ``(K,)`` the largest distance from it to a corner; ``area_vector`` ``(K, 3)``: sum of
    ``0.5 (b - a) x (c - a)`` over the cluster's triangles. ``order`` maps back to the input rows.
    ``triangle_centre`` ``(T, 3)`` and ``triangle_radius`` ``(T,)``: each triangle's own sphere
    (centroid, farthest corner), for pruning distance candidates.
    """

    corners: torch.Tensor
    start: torch.Tensor
    count: torch.Tensor
    centre: torch.Tensor
    radius: torch.Tensor
    area_vector: torch.Tensor
    order: np.ndarray
    triangle_centre: torch.Tensor
    triangle_radius: torch.Tensor

    @classmethod
    def build(cls, vertices: np.ndarray, triangles: np.ndarray, device: torch.device | str = "cpu") -> TriangleClusters:
        """Cluster ``triangles`` by a grid over their centroids, about ``TRIANGLES_PER_CLUSTER`` each."""
        corners = np.asarray(vertices, np.float64)[np.asarray(triangles, np.int64)]
        t = len(corners)
        if t == 0:
            raise ValueError("no triangles")
        centroids = corners.mean(axis=1)
        low, high = centroids.min(axis=0), centroids.max(axis=0)
        extent = np.maximum(high - low, 1e-12)
        # Cells of equal side such that the occupied ones hold about TRIANGLES_PER_CLUSTER each;
        # surfaces fill cells as area, so the side goes with sqrt(area per cluster).
        side = max(float(np.sqrt(extent @ np.roll(extent, 1) * 2 * TRIANGLES_PER_CLUSTER / t)), 1e-12)
        cells = np.minimum(np.floor((centroids - low) / side), 2**20).astype(np.int64)
        keys = (cells[:, 0] << 42) | (cells[:, 1] << 21) | cells[:, 2]
        order = np.argsort(keys, kind="stable")
        keys = keys[order]
        corners = corners[order]
        first = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
        count = np.diff(np.r_[first, t])
        cluster = np.repeat(np.arange(len(first)), count)
        double_area = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        area = 0.5 * np.linalg.norm(double_area, axis=1)
        weight = np.add.reduceat(area, first)
        centre = np.add.reduceat(centroids[order] * area[:, None], first) / np.maximum(weight, 1e-300)[:, None]
        # Clusters of zero area (degenerate triangles only): their plain centroid.
        flat = weight <= 0
        centre[flat] = np.add.reduceat(centroids[order], first)[flat] / count[flat, None]
        reach = np.linalg.norm(corners - centre[cluster][:, None, :], axis=2).max(axis=1)
        radius = np.maximum.reduceat(reach, first)
        area_vector = np.add.reduceat(0.5 * double_area, first)

        def tensor(a: np.ndarray) -> torch.Tensor:
            return torch.as_tensor(a, device=device)

        own_centre = corners.mean(axis=1)
        own_radius = np.linalg.norm(corners - own_centre[:, None], axis=2).max(axis=1)
        return cls(tensor(corners), tensor(first), tensor(count), tensor(centre), tensor(radius),
                   tensor(area_vector), order, tensor(own_centre), tensor(own_radius))

    def __len__(self) -> int:
        return len(self.start)


def _expand(pairs_query: torch.Tensor, pairs_cluster: torch.Tensor, clusters: TriangleClusters
            ) -> tuple[torch.Tensor, torch.Tensor]:
    """(query, triangle) rows for every (query, cluster) pair: each cluster's triangles in turn."""
    count = clusters.count[pairs_cluster]
    query = torch.repeat_interleave(pairs_query, count)
    offset = torch.arange(len(query), device=query.device) - torch.repeat_interleave(torch.cumsum(count, 0) - count, count)
    triangle = torch.repeat_interleave(clusters.start[pairs_cluster], count) + offset
    return query, triangle


def _pair_batches(query: torch.Tensor, cluster: torch.Tensor, clusters: TriangleClusters):
    """The (query, triangle) rows of the pairs, at most about ``PAIRS_PER_BATCH`` at a time."""
    sizes = torch.cumsum(clusters.count[cluster], 0)
    at = 0
    while at < len(query):
        base = int(sizes[at - 1]) if at else 0
        stop = int(torch.searchsorted(sizes, base + PAIRS_PER_BATCH, right=True))
        stop = max(stop, at + 1)
        yield _expand(query[at:stop], cluster[at:stop], clusters)
        at = stop


def solid_angle(a: torch.Tensor, b: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
    """Signed solid angle ``(P,)`` of triangles whose corners relative to the query are ``a, b, c`` ``(P, 3)``.

    van Oosterom and Strackee's formula (module docstring); positive when the triangle is
    counter-clockwise seen from the query's side opposite its normal, i.e. from inside.

    >>> o = torch.tensor([[1.0, 0, 0]]), torch.tensor([[0, 1.0, 0]]), torch.tensor([[0, 0, 1.0]])
    >>> float(solid_angle(*o) / (4 * math.pi))  # an octant
    0.125
    """
    la, lb, lc = a.norm(dim=1), b.norm(dim=1), c.norm(dim=1)
    numerator = (a * torch.cross(b, c, dim=1)).sum(dim=1)
    denominator = la * lb * lc + (a * b).sum(dim=1) * lc + (b * c).sum(dim=1) * la + (c * a).sum(dim=1) * lb
    return 2 * torch.atan2(numerator, denominator)


def winding_numbers(queries: np.ndarray, clusters: TriangleClusters, batch: int = 4096) -> np.ndarray:
    """Generalized winding number ``(Q,)`` float64 of the clustered triangles at ``queries`` ``(Q, 3)``."""
    device = clusters.centre.device
    points = torch.as_tensor(np.asarray(queries, np.float64), device=device)
    out = torch.zeros(len(points), dtype=torch.float64, device=device)
    for at in range(0, len(points), batch):
        q = points[at : at + batch]
        offset = clusters.centre[None] - q[:, None]  # (B, K, 3)
        distance = offset.norm(dim=2)
        near = distance < BETA * clusters.radius[None]
        far = (offset * clusters.area_vector[None]).sum(dim=2) / distance.clamp_min(1e-300) ** 3
        w = torch.where(near, 0.0, far).sum(dim=1) / (4 * math.pi)
        pair_query, pair_cluster = near.nonzero(as_tuple=True)
        for query, triangle in _pair_batches(pair_query, pair_cluster, clusters):
            corners = clusters.corners[triangle] - q[query][:, None, :]
            angle = solid_angle(corners[:, 0], corners[:, 1], corners[:, 2])
            w.index_add_(0, query, angle / (4 * math.pi))
        out[at : at + batch] = w
    return out.cpu().numpy()


def closest_on_triangles(p: torch.Tensor, a: torch.Tensor, b: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
    """The point ``(P, 3)`` of each triangle ``(a, b, c)`` nearest ``p``, all ``(P, 3)`` (Ericson 5.1.5).

    >>> z, x, y = torch.tensor([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=torch.float64).split(1)
    >>> closest_on_triangles(torch.tensor([[0.25, 0.5, 5.0]], dtype=torch.float64), z, x, y).tolist()
    [[0.25, 0.5, 0.0]]
    """
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = (ab * ap).sum(1), (ac * ap).sum(1)
    bp = p - b
    d3, d4 = (ab * bp).sum(1), (ac * bp).sum(1)
    cp = p - c
    d5, d6 = (ab * cp).sum(1), (ac * cp).sum(1)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    tiny = 1e-300
    # Inside the face: barycentric (u, v, w) from the signed areas va, vb, vc.
    total = (va + vb + vc)
    v = vb / torch.where(total.abs() > tiny, total, torch.full_like(total, tiny))
    w = vc / torch.where(total.abs() > tiny, total, torch.full_like(total, tiny))
    result = a + ab * v[:, None] + ac * w[:, None]

    def choose(mask: torch.Tensor, point: torch.Tensor) -> None:
        nonlocal result
        result = torch.where(mask[:, None], point, result)

    # Regions in reverse order of Ericson's tests, so that the first test that holds wins.
    bc_edge = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
    t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6)).clamp_min(tiny)
    choose(bc_edge, b + (c - b) * t_bc[:, None])
    ac_edge = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
    choose(ac_edge, a + ac * (d2 / (d2 - d6).clamp_min(tiny))[:, None])
    choose((d6 >= 0) & (d5 <= d6), c)
    ab_edge = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
    choose(ab_edge, a + ab * (d1 / (d1 - d3).clamp_min(tiny))[:, None])
    choose((d3 >= 0) & (d4 <= d3), b)
    choose((d1 <= 0) & (d2 <= 0), a)
    return result


def surface_samples(clusters: TriangleClusters, spacing: float) -> np.ndarray:
    """Points on every triangle about ``spacing`` apart, its corners included (for distance bounds)."""
    corners = clusters.corners.cpu().numpy()
    longest = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(axis=1)
    steps = np.clip(np.ceil(longest / spacing), 1, MAX_SAMPLE_STEPS).astype(np.int64)
    points = [corners.reshape(-1, 3)]
    for n in np.unique(steps):
        # A triangular lattice of barycentric weights (i, j, n - i - j) / n on the triangles with n steps.
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        keep = i + j <= n
        weights = np.stack([i[keep], j[keep], n - i[keep] - j[keep]], axis=1) / n
        points.append(np.einsum("wk,tkd->twd", weights, corners[steps == n]).reshape(-1, 3))
    return np.concatenate(points)


def unsigned_distances(queries: np.ndarray, clusters: TriangleClusters, spacing: float | None = None,
                       exact_within: float = math.inf, batch: int = 4096) -> np.ndarray:
    """Distance ``(Q,)`` float64 from each query ``(Q, 3)`` to the nearest clustered triangle.

    ``spacing`` of the bounding samples (module docstring): default a fiftieth of the triangles'
    bounding box; smaller bounds are tighter, so fewer clusters are visited per query. Queries
    whose bound U exceeds ``exact_within`` keep U, the distance to the nearest sample: a sample
    lies within ``rho <= spacing`` of every surface point, so U overestimates the distance d by
    at most ``sqrt(d^2 + rho^2) - d <= rho^2 / (2 d)`` where the nearest surface point is inside
    a face (a sliver of a voxel when ``exact_within`` is a few samples' spacing), and at most rho
    in any case.
    """
    device = clusters.centre.device
    corners = clusters.corners
    if spacing is None:
        flat = corners.reshape(-1, 3)
        spacing = float((flat.max(0).values - flat.min(0).values).norm()) / 50 or 1.0
    tree = cKDTree(surface_samples(clusters, spacing))
    queries = np.asarray(queries, np.float64)
    bound, _ = tree.query(queries, workers=-1)
    exact = np.flatnonzero(bound <= exact_within)
    points = torch.as_tensor(queries[exact], device=device)
    upper = torch.as_tensor(bound[exact], device=device)
    for at in range(0, len(points), batch):
        q, u = points[at : at + batch], upper[at : at + batch]
        reach = (clusters.centre[None] - q[:, None]).norm(dim=2) - clusters.radius[None]
        pair_query, pair_cluster = (reach <= u[:, None] * (1 + 1e-9) + 1e-12).nonzero(as_tuple=True)
        best = u.clone()
        for query, triangle in _pair_batches(pair_query, pair_cluster, clusters):
            # The triangle's own bounding sphere first: most of a near cluster's triangles are too far.
            p = q[query]
            keep = (p - clusters.triangle_centre[triangle]).norm(dim=1) - clusters.triangle_radius[triangle] <= u[query]
            query, triangle, p = query[keep], triangle[keep], p[keep]
            tri = corners[triangle]
            d = (closest_on_triangles(p, tri[:, 0], tri[:, 1], tri[:, 2]) - p).norm(dim=1)
            best.scatter_reduce_(0, query, d, reduce="amin")
        bound[exact[at : at + batch]] = best.cpu().numpy()
    return bound
