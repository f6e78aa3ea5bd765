"""Row and column reductions of ``(N, 3)`` points, written for speed on long chunks.

numpy reduces a C-ordered ``(N, 3)`` array along either axis an element at a time, which is
slow: on 2**20 float64 points (numpy 2.4, one AMD EPYC core), ``min(axis=0)`` takes 27 ms and
three column minima 1.6 ms; ``isfinite(p).all(axis=1)`` 15.6 ms and three column tests 1.9 ms.
Streaming runs these on every chunk, so they are written per column.
"""

from __future__ import annotations

import numpy as np


def finite_rows(points: np.ndarray) -> np.ndarray | None:
    """``(N,)`` bool of the rows whose coordinates are all finite; None when every row is."""
    if np.isfinite(points).all():
        return None
    mask = np.isfinite(points[:, 0])
    for axis in range(1, points.shape[1]):
        mask &= np.isfinite(points[:, axis])
    return mask


def corners(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(min, max)`` per column, float64 ``(3,)`` each; ``(inf, -inf)`` for no rows."""
    if len(points) == 0:
        return np.full(points.shape[1], np.inf), np.full(points.shape[1], -np.inf)
    low = np.array([points[:, axis].min() for axis in range(points.shape[1])], np.float64)
    high = np.array([points[:, axis].max() for axis in range(points.shape[1])], np.float64)
    return low, high


def finite_corners(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """``(min, max, count)`` of the rows with every coordinate finite."""
    mask = finite_rows(points)
    if mask is not None:
        points = points[mask]
    low, high = corners(points)
    return low, high, len(points)
