"""Pair selection: exhaustive and sequential counts, and retrieval finding the images that share features."""

from __future__ import annotations

import numpy as np

from pointfield.scenes.sfm.pairs import (
    exhaustive_pairs,
    retrieval_pairs,
    sequential_pairs,
    similarity_scores,
    strongest_features,
)


def test_exhaustive_and_sequential_pairs():
    assert len(exhaustive_pairs(50)) == 50 * 49 // 2
    assert sequential_pairs(5, 2) == [(0, 1), (0, 2), (1, 2), (1, 3), (2, 3), (2, 4), (3, 4)]
    assert len(sequential_pairs(3, 10)) == 3


def shared_feature_images(count: int, shared: int, own: int, seed: int) -> list[np.ndarray]:
    """Images on a ring: image i shares ``shared`` features with each of i-1 and i+1 (slightly noisy)."""
    rng = np.random.default_rng(seed)
    links = [rng.random((shared, 128)).astype(np.float32) for _ in range(count)]  # link i: between i and i+1

    def noise(a: np.ndarray) -> np.ndarray:
        return a + 0.02 * rng.random(a.shape).astype(np.float32)

    images = []
    for i in range(count):
        images.append(
            np.concatenate([noise(links[i]), noise(links[i - 1]), rng.random((own, 128)).astype(np.float32)])
        )
    order = rng.permutation(count)  # shuffled, so that index order says nothing
    return [images[i] for i in order], order


def test_retrieval_pairs_each_image_with_the_ones_it_shares_features_with():
    images, order = shared_feature_images(count=24, shared=40, own=120, seed=0)
    position = {int(ring): index for index, ring in enumerate(order)}
    truth = {tuple(sorted((position[i], position[(i + 1) % 24]))) for i in range(24)}
    scores = similarity_scores(images)
    np.testing.assert_array_equal(scores, scores.T)
    assert all(scores[i, j] >= 30 for i, j in truth)  # 2 x 40 shared, most pass the ratio test
    unrelated = [scores[i, j] for i in range(24) for j in range(i + 1, 24) if (i, j) not in truth]
    assert max(unrelated) < 10
    assert set(retrieval_pairs(images, neighbours=2)) == truth


def test_retrieval_with_enough_neighbours_is_exhaustive_and_featureless_images_score_zero():
    images, _ = shared_feature_images(count=5, shared=10, own=10, seed=1)
    assert retrieval_pairs(images, neighbours=4) == exhaustive_pairs(5)
    scores = similarity_scores([*images, np.zeros((0, 128), np.float32)])
    assert not scores[-1].any() and not scores[:, -1].any()


def test_strongest_features_are_the_largest_scale_ones_in_both_keypoint_layouts():
    descriptors = np.arange(4 * 128, dtype=np.uint8).reshape(4, 128)
    four = np.array([[0, 0, 1.0, 0], [0, 0, 5.0, 0], [0, 0, 3.0, 0], [0, 0, 4.0, 0]])
    np.testing.assert_array_equal(strongest_features(four, descriptors, 2), descriptors[[1, 3]].astype(np.float32))
    # affine shape a11 a12 a21 a22 = scale * rotation: determinant scale^2
    six = np.array([[0, 0, s, 0, 0, s] for s in (2.0, 1.0, 6.0, 3.0)])
    np.testing.assert_array_equal(strongest_features(six, descriptors, 3), descriptors[[2, 3, 0]].astype(np.float32))
