"""Which image pairs to match: every pair, neighbours in time, or the pairs that look alike.

Matching dominates the time of structure from motion on a CPU: all-against-all is N(N-1)/2
pairs of full SIFT matching (1,225 pairs for 50 photos, 4,950 for 100). Most of those pairs see
nothing in common. COLMAP's answer is retrieval with a vocabulary tree, but its trees are files
downloaded at run time, which pointfield does not do. Instead, ``retrieval_pairs`` scores every
pair cheaply from the features already extracted:

1. per image, the ``features_per_image`` keypoints of largest scale (the most repeatable ones)
   and their SIFT descriptors, scaled to unit length;
2. for every image pair (i, j), the number of those features of i whose nearest neighbour among
   j's passes Lowe's ratio test (distance to the best below ``ratio`` times the distance to the
   second best), plus the same count from j to i;
3. each image is paired with its ``neighbours`` best-scoring partners.

That is one ``(K, N*K)`` matrix product per image (K features, N images), a second or two for a
hundred images, and the full matcher then runs on about ``N * neighbours / 2`` pairs only.

``sequential_pairs`` is the classic choice for video: each frame with the next ``overlap`` ones.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch


def exhaustive_pairs(count: int) -> list[tuple[int, int]]:
    """Every pair ``(i, j)`` with ``i < j < count``."""
    return [(i, j) for i in range(count) for j in range(i + 1, count)]


def sequential_pairs(count: int, overlap: int) -> list[tuple[int, int]]:
    """Each index with the next ``overlap`` ones: ``(i, j)`` for ``i < j <= i + overlap``."""
    return [(i, j) for i in range(count) for j in range(i + 1, min(count, i + overlap + 1))]


def similarity_scores(descriptors: Sequence[np.ndarray], ratio: float = 0.8) -> np.ndarray:
    """``(N, N)`` symmetric scores: ratio-test nearest-neighbour counts between images, both ways.

    ``descriptors[i]`` is ``(K_i, D)`` float (any scale; rows are normalised here). An image with
    fewer than two features scores 0 against everything (the ratio test needs a second best).
    """
    count = len(descriptors)
    longest = max((len(d) for d in descriptors), default=0)
    if count == 0 or longest == 0:
        return np.zeros((count, count), np.float64)
    width = np.asarray(descriptors[0]).shape[1]
    # Pad every image to the same number of features; a padded feature's dot product is -3,
    # below any real one (unit vectors give [-1, 1]), so it is never a best or second best.
    padded = torch.zeros(count, longest, width)
    real = torch.zeros(count, longest, dtype=torch.bool)
    for i, d in enumerate(descriptors):
        padded[i, : len(d)] = torch.from_numpy(_unit_rows(d))
        real[i, : len(d)] = True
    scores = torch.zeros(count, count, dtype=torch.float64)
    for i in range(count):
        query = padded[i, real[i]]
        if len(query) == 0:
            continue
        dots = torch.einsum("kd,njd->knj", query, padded).masked_fill_(~real, -3.0)
        # For unit vectors |a - b|^2 = 2 - 2 a.b, so the two best matches are the two largest
        # dot products; squared distances keep the ratio test exact without square roots.
        best_two = dots.topk(2, dim=2).values
        distance_best = (2 - 2 * best_two[..., 0]).clamp_min(0)
        distance_second = (2 - 2 * best_two[..., 1]).clamp_min(0)
        passes = (distance_best < ratio**2 * distance_second) & (best_two[..., 1] > -2)
        scores[i] = passes.sum(dim=0).double()
        scores[i, i] = 0
    scores = scores.numpy()
    return scores + scores.T


def retrieval_pairs(descriptors: Sequence[np.ndarray], neighbours: int, ratio: float = 0.8) -> list[tuple[int, int]]:
    """Pairs ``(i, j)``, ``i < j``: each image with its ``neighbours`` best-scoring partners.

    Scores come from :func:`similarity_scores`. With ``neighbours >= N - 1`` this is every pair.
    """
    count = len(descriptors)
    if neighbours >= count - 1:
        return exhaustive_pairs(count)
    scores = similarity_scores(descriptors, ratio)
    np.fill_diagonal(scores, -1)
    chosen: set[tuple[int, int]] = set()
    for i in range(count):
        # Stable sort on the negated scores: ties go to the nearer index, deterministically.
        for j in np.argsort(-scores[i], kind="stable")[:neighbours]:
            chosen.add((min(i, int(j)), max(i, int(j))))
    return sorted(chosen)


def strongest_features(keypoints: np.ndarray, descriptors: np.ndarray, count: int) -> np.ndarray:
    """The descriptors of the ``count`` keypoints of largest scale, float32 ``(min(count, K), D)``.

    ``keypoints`` are COLMAP's ``(K, 4)`` (x, y, scale, orientation) or ``(K, 6)`` (x, y, a11,
    a12, a21, a22: the affine shape, whose determinant is the squared scale).
    """
    if keypoints.shape[1] == 4:
        scale = np.abs(keypoints[:, 2])
    else:
        scale = np.abs(keypoints[:, 2] * keypoints[:, 5] - keypoints[:, 3] * keypoints[:, 4])
    order = np.argsort(-scale, kind="stable")[:count]
    return descriptors[order].astype(np.float32)


def _unit_rows(values: np.ndarray) -> np.ndarray:
    values = np.asarray(values, np.float32)
    norms = np.linalg.norm(values, axis=1, keepdims=True)
    return values / np.maximum(norms, 1e-12)
