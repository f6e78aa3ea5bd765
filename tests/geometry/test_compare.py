"""Surface scores: known distances between known point sets."""

from __future__ import annotations

import numpy as np
import pytest

from pointfield.clouds.mesh import Mesh
from pointfield.errors import PointfieldError
from pointfield.geometry.compare import sample_mesh, surface_scores


def unit_square(z: float = 0.0) -> Mesh:
    points = np.array([[0, 0, z], [1, 0, z], [1, 1, z], [0, 1, z]], np.float64)
    return Mesh(points, {}, faces=np.array([[0, 1, 2], [0, 2, 3]]))


def test_mesh_samples_cover_the_surface_uniformly():
    samples = sample_mesh(unit_square(), 20_000, seed=1)
    assert samples.shape == (20_000, 3) and np.all(samples[:, 2] == 0)
    assert np.all((samples[:, :2] >= 0) & (samples[:, :2] <= 1))
    # uniform over the square: each quarter holds a quarter of the samples (both triangles alike)
    quarters = np.histogram2d(samples[:, 0], samples[:, 1], bins=2, range=[[0, 1], [0, 1]])[0] / len(samples)
    np.testing.assert_allclose(quarters, 0.25, atol=0.02)


def test_scores_of_a_shifted_surface_are_the_shift():
    truth = sample_mesh(unit_square(), 40_000, seed=2)
    shifted = sample_mesh(unit_square(0.01), 40_000, seed=3)
    scores = surface_scores(shifted, truth, threshold=0.02, unit=np.sqrt(2))
    # every point is 0.01 above the truth (plus the spacing of the samples, under 0.01)
    assert 0.01 <= scores["accuracy"] < 0.014 and 0.01 <= scores["completeness"] < 0.014
    assert scores["fscore"] > 0.99
    assert scores["chamfer_relative"] == pytest.approx(scores["chamfer"] / np.sqrt(2))
    far = surface_scores(sample_mesh(unit_square(0.05), 10_000), truth, threshold=0.02)
    assert far["precision"] == 0 and far["recall"] == 0 and far["fscore"] == 0


def test_half_a_surface_is_precise_but_incomplete():
    truth = sample_mesh(unit_square(), 40_000, seed=4)
    half = truth[truth[:, 0] < 0.5]
    scores = surface_scores(half, truth, threshold=0.01)
    assert scores["precision"] == 1.0 and scores["recall"] == pytest.approx(0.5, abs=0.02)
    with pytest.raises(PointfieldError, match="points on both sides"):
        surface_scores(np.zeros((0, 3)), truth, threshold=0.01)
