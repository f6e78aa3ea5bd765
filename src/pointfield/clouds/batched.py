"""Batched point operations in torch, on any device: the sampling and grouping of PointNet++.

``points`` is ``(B, N, 3)``, with an optional ``mask`` ``(B, N)`` bool marking real points in
padded batches (real points first). These run inside models: :func:`farthest_point_sample_batched`
(a batched torch loop on GPUs, fpsample per cloud on the CPU), :func:`knn`, :func:`ball_query`,
:func:`gather_points`. :func:`farthest_point_sample_reference` is the slow, obviously correct
version the tests hold the fast ones to. One cloud in numpy: :mod:`pointfield.clouds.ops`.
"""

from __future__ import annotations

import numpy as np
import torch

from pointfield.clouds.ops import farthest_point_sample

# Rows of queries handled at once by the brute-force neighbour searches: bounds their memory to
# about QUERY_CHUNK * N distances.
QUERY_CHUNK = 4096


def gather_points(values: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """Pick rows per cloud: ``values`` ``(B, N, C)``, ``index`` ``(B, *S)`` -> ``(B, *S, C)``."""
    batch, channels = values.shape[0], values.shape[-1]
    flat = index.reshape(batch, -1)
    picked = torch.gather(values, 1, flat.unsqueeze(-1).expand(-1, -1, channels))
    return picked.reshape(*index.shape, channels)


def masked_centroid(points: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """``(B, 3)`` mean of the real points of each cloud of a ``(B, N, 3)`` batch."""
    if mask is None:
        return points.mean(dim=1)
    weights = mask.to(points.dtype).unsqueeze(-1)
    return (points * weights).sum(dim=1) / weights.sum(dim=1).clamp_min(1)


def farthest_point_sample_batched(
    points: torch.Tensor,
    size: int,
    mask: torch.Tensor | None = None,
    start: torch.Tensor | None = None,
    backend: str | None = None,
) -> torch.Tensor:
    """``(B, size)`` int64 indices of a farthest point sample of each cloud of ``(B, N, 3)``.

    The greedy rule of :func:`farthest_point_sample` for every cloud. ``start`` ``(B,)``
    defaults to each cloud's real point farthest from its centroid. Padding points (``mask``
    False; real points come first) are never chosen; once a cloud's real points are
    exhausted the sample repeats its start point.

    ``backend``: ``"torch"`` runs ``size`` batched iterations of
    ``d(p) = min(d(p), |p - last|²)``, ``last = argmax d`` on the tensors' device (the GPU
    path); ``"fpsample"`` runs the compiled fpsample on each cloud (CPU, several times faster
    there). The default picks fpsample for CPU tensors and torch elsewhere. Both follow the
    same rule and are tested against :func:`farthest_point_sample_reference`; they can differ
    only in which of several exactly equidistant points they take.
    """
    if backend is None:
        backend = "fpsample" if points.device.type == "cpu" else "torch"
    if backend not in ("torch", "fpsample"):
        raise ValueError(f"backend must be 'torch' or 'fpsample', got {backend!r}")
    if start is None:
        centroid = masked_centroid(points, mask)
        spread = ((points - centroid[:, None]) ** 2).sum(-1)
        if mask is not None:
            spread = spread.masked_fill(~mask, -1.0)
        start = spread.argmax(dim=1)
    if backend == "fpsample":
        return _farthest_point_sample_fpsample(points, size, mask, start)
    return _farthest_point_sample_torch(points, size, mask, start)


def _farthest_point_sample_fpsample(
    points: torch.Tensor, size: int, mask: torch.Tensor | None, start: torch.Tensor
) -> torch.Tensor:
    array = points.detach().cpu().numpy()
    counts = mask.sum(dim=1).tolist() if mask is not None else [points.shape[1]] * len(points)
    chosen = np.stack([
        farthest_point_sample(array[b, :count], size, start=int(start[b]))
        for b, count in enumerate(counts)
    ])
    return torch.from_numpy(chosen).to(points.device)


def _farthest_point_sample_torch(
    points: torch.Tensor, size: int, mask: torch.Tensor | None, start: torch.Tensor
) -> torch.Tensor:
    batch, count, _ = points.shape
    rows = torch.arange(batch, device=points.device)
    chosen = torch.empty(batch, size, dtype=torch.long, device=points.device)
    distance = torch.full((batch, count), float("inf"), dtype=points.dtype, device=points.device)
    if mask is not None:
        distance = distance.masked_fill(~mask, -1.0)
    last = start
    for i in range(size):
        chosen[:, i] = last
        step = ((points - points[rows, last][:, None]) ** 2).sum(-1)
        distance = torch.minimum(distance, step)
        last = distance.argmax(dim=1)
        # When every real point is chosen all distances are 0 (padding -1): argmax would pick
        # index 0; repeat the start instead so exhausted clouds stay on a real point.
        exhausted = distance[rows, last] <= 0
        last = torch.where(exhausted, start, last)
    return chosen


def farthest_point_sample_reference(
    points: torch.Tensor, size: int, start: int
) -> torch.Tensor:
    """The definition of farthest point sampling, written plainly for one ``(N, 3)`` cloud.

    Slow (a Python loop over samples and a full distance recomputation each time) and meant
    only as the yardstick the fast versions are tested against. Returns ``(size,)`` int64
    indices; ``size`` must not exceed N.
    """
    chosen = [start]
    for _ in range(size - 1):
        to_chosen = torch.cdist(points, points[chosen]).min(dim=1).values
        chosen.append(int(to_chosen.argmax()))
    return torch.tensor(chosen, dtype=torch.long)


def square_distances(query: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """``(B, M, N)`` squared Euclidean distances between ``(B, M, 3)`` and ``(B, N, 3)``.

    Computed directly as ``sum((q - p)²)`` rather than ``|q|² + |p|² - 2 q·p``, which loses
    precision exactly where neighbourhoods are decided (small distances).
    One coordinate at a time, so the largest temporary is ``(B, M, N)``, not ``(B, M, N, 3)``.
    """
    distance = (query[:, :, None, 0] - points[:, None, :, 0]) ** 2
    for axis in (1, 2):
        distance = distance + (query[:, :, None, axis] - points[:, None, :, axis]) ** 2
    return distance


def knn(
    query: torch.Tensor, points: torch.Tensor, k: int, mask: torch.Tensor | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """The ``k`` nearest points to each query: ``(B, M, k)`` squared distances and indices.

    ``query`` ``(B, M, 3)``, ``points`` ``(B, N, 3)``; padding points (``mask`` False) are
    never returned. Exact brute force, nearest first, in chunks of queries to bound memory.
    ``k`` must not exceed the number of points.
    """
    distances, indices = [], []
    for lo in range(0, query.shape[1], QUERY_CHUNK):
        d = square_distances(query[:, lo : lo + QUERY_CHUNK], points)
        if mask is not None:
            d = d.masked_fill(~mask[:, None, :], float("inf"))
        nearest = torch.topk(d, k, dim=-1, largest=False, sorted=True)
        distances.append(nearest.values)
        indices.append(nearest.indices)
    return torch.cat(distances, dim=1), torch.cat(indices, dim=1)


def ball_query(
    centroids: torch.Tensor,
    points: torch.Tensor,
    radius: float,
    size: int,
    mask: torch.Tensor | None = None,
) -> torch.Tensor:
    """``(B, S, size)`` indices of up to ``size`` points within ``radius`` of each centroid.

    The ``size`` nearest points inside the ball, padded by repeating the nearest (a centroid
    taken from the cloud is its own nearest point, so every group is non-empty). PointNet++'s
    original CUDA kernel takes the first ``size`` in-ball points in storage order instead; the
    nearest ones are a ball query whose answer does not depend on the order of the points,
    which the model's permutation invariance needs.
    """
    count = points.shape[1]
    within = min(size, count)
    distance, index = knn(centroids, points, within, mask)
    outside = distance > radius * radius
    index = torch.where(outside, index[..., :1], index)
    if within < size:
        index = torch.cat([index, index[..., :1].expand(-1, -1, size - within)], dim=-1)
    return index
