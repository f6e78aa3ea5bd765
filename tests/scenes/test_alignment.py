"""Pose errors after alignment: zero for the same poses seen in another frame, exact for known errors."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pointfield.scenes.alignment import nearest_rotation, pose_errors


def random_poses(count: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    poses = np.zeros((count, 3, 4))
    poses[:, :, :3] = Rotation.random(count, random_state=seed).as_matrix()
    poses[:, :, 3] = rng.normal(size=(count, 3)) * 3
    return poses


def transformed(poses: np.ndarray, scale: float, rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """The same cameras in a world related by ``x' = scale * rotation @ x + translation``."""
    moved = poses.copy()
    moved[:, :, :3] = rotation @ poses[:, :, :3]
    moved[:, :, 3] = scale * poses[:, :, 3] @ rotation.T + translation
    return moved


def test_the_same_poses_in_another_world_frame_have_no_error_and_the_similarity_is_recovered():
    given = random_poses(20, seed=0)
    rotation = Rotation.from_euler("xyz", [30, -50, 110], degrees=True).as_matrix()
    # found = given seen in a world 0.25 times as large, rotated and shifted
    found = transformed(given, 0.25, rotation, np.array([1.0, -2.0, 0.5]))
    errors = pose_errors(found, given)
    assert errors.rotation_degrees.max() < 1e-6
    assert errors.centre_fraction.max() < 1e-9
    assert errors.scale == pytest.approx(4.0)
    np.testing.assert_allclose(errors.rotation, rotation.T, atol=1e-9)


def test_a_known_rotation_and_centre_error_on_one_camera_is_measured_exactly():
    given = random_poses(30, seed=1)
    found = given.copy()
    found[7, :, :3] = Rotation.from_euler("z", 2.0, degrees=True).as_matrix() @ given[7, :, :3]
    errors = pose_errors(found, given)
    # One camera of thirty barely moves the chordal mean: it keeps almost all of its 2 degrees.
    assert errors.rotation_degrees[7] == pytest.approx(2.0, abs=0.1)
    assert np.median(errors.rotation_degrees) < 0.1

    found = given.copy()
    extent = np.max(np.linalg.norm(given[:, None, :, 3] - given[None, :, :, 3], axis=-1))
    found[3, :, 3] += np.array([0.0, 0.0, 0.01 * extent])
    errors = pose_errors(found, given)
    assert errors.extent == pytest.approx(extent)
    assert errors.centre_fraction[3] == pytest.approx(0.01, rel=0.1)
    assert errors.median_centre_fraction < 0.001


def test_nearest_rotation_is_a_rotation_and_mismatched_frames_are_refused():
    rotation = nearest_rotation(np.random.default_rng(2).normal(size=(3, 3)))
    np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(rotation) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="same two or more frames"):
        pose_errors(random_poses(3, 0), random_poses(4, 0))
