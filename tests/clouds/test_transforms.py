"""Transforms: honest reprs, seedable randomness, fields and normals that follow the points."""

from __future__ import annotations

import numpy as np
import pytest

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.transforms import (
    CanonicalSample,
    Centre,
    Compose,
    DropNonFinite,
    EstimateNormals,
    FarthestPointSample,
    NormaliseScale,
    RandomDropout,
    RandomJitter,
    RandomRotate,
    RandomScale,
    RandomShift,
    SamplePoints,
    Shuffle,
    VoxelDownsample,
)


def labelled_cloud(count: int = 200) -> PointCloud:
    rng = np.random.default_rng(0)
    normals = rng.normal(size=(count, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return PointCloud(
        (normals * 2 + 1).astype(np.float32),
        {"label": np.arange(count, dtype=np.int32), "normals": normals.astype(np.float32)},
    )


def test_reprs_show_the_settings():
    transform = Compose([NormaliseScale(), SamplePoints(1024), RandomJitter(0.01, clip=0.05),
                         RandomRotate(axis=None), VoxelDownsample(0.05)])
    assert repr(transform) == (
        "Compose([NormaliseScale(), SamplePoints(1024), RandomJitter(sigma=0.01, clip=0.05), "
        "RandomRotate(axis=None), VoxelDownsample(0.05)])"
    )
    assert repr(RandomScale(0.8, 1.25)) == "RandomScale(low=0.8, high=1.25, anisotropic=True)"


def test_a_seeded_transform_repeats_itself():
    cloud = labelled_cloud()
    a = Compose([RandomRotate(seed=3), RandomJitter(seed=4)])
    b = Compose([RandomRotate(seed=3), RandomJitter(seed=4)])
    np.testing.assert_array_equal(a(cloud).points, b(cloud).points)


def test_a_generator_passed_at_call_time_wins_over_the_own_seed():
    cloud = labelled_cloud()
    first = RandomShift(seed=1)(cloud, np.random.default_rng(9)).points
    second = RandomShift(seed=2)(cloud, np.random.default_rng(9)).points
    np.testing.assert_array_equal(first, second)


def test_transforms_leave_their_input_alone():
    cloud = labelled_cloud()
    before = cloud.points.copy()
    Compose([Centre(), RandomScale(seed=0), RandomDropout(seed=0), Shuffle(seed=0)])(cloud)
    np.testing.assert_array_equal(cloud.points, before)


def test_rotation_about_z_keeps_heights_and_turns_normals_with_the_points():
    directions = labelled_cloud().fields["normals"]
    cloud = PointCloud(directions, {"normals": directions})  # normals equal to their points
    turned = RandomRotate(180, "z", seed=0)(cloud)
    np.testing.assert_allclose(turned.points[:, 2], cloud.points[:, 2], rtol=1e-6)
    assert not np.allclose(turned.points, cloud.points)
    np.testing.assert_allclose(turned.fields["normals"], turned.points, atol=1e-6)


def test_uniform_rotation_is_a_proper_rotation():
    points = np.eye(3, dtype=np.float64)
    turned = RandomRotate(axis=None, seed=5)(PointCloud(points)).points
    np.testing.assert_allclose(turned @ turned.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(turned) == pytest.approx(1.0)


def test_anisotropic_scaling_keeps_normals_perpendicular_to_the_surface():
    rng = np.random.default_rng(0)
    plane = np.column_stack([rng.uniform(-1, 1, (50, 2)), np.zeros(50)])
    tilted = plane @ np.array([[1, 0, 0], [0, 0.8, 0.6], [0, -0.6, 0.8]])
    normal = np.array([0, -0.6, 0.8])
    cloud = PointCloud(tilted, {"normals": np.tile(normal, (50, 1))})
    stretched = RandomScale(0.5, 2.0, seed=1)(cloud)
    in_plane = stretched.points[1:] - stretched.points[0]
    np.testing.assert_allclose(in_plane @ stretched.fields["normals"][0], 0, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(stretched.fields["normals"], axis=1), 1.0)


def test_jitter_is_clipped():
    cloud = PointCloud(np.zeros((1000, 3), np.float32))
    jittered = RandomJitter(sigma=1.0, clip=0.05, seed=0)(cloud).points
    assert np.abs(jittered).max() <= 0.05 + 1e-7 and jittered.std() > 0.01


def test_sampling_dropout_and_shuffling_carry_the_fields_along():
    cloud = labelled_cloud()
    for transform in (SamplePoints(64, seed=0), SamplePoints(300, seed=0), Shuffle(seed=0),
                      RandomDropout(0.5, seed=0), FarthestPointSample(32), CanonicalSample(50)):
        out = transform(cloud)
        labels = out.fields["label"]
        np.testing.assert_array_equal(out.points, cloud.points[labels])


def test_dropout_keeps_the_point_count_and_replaces_dropped_points_by_a_kept_one():
    cloud = labelled_cloud()
    out = RandomDropout(0.8, seed=2)(cloud)
    assert len(out) == len(cloud)
    assert len(set(out.fields["label"].tolist())) < len(cloud)


def test_drop_non_finite_and_normalise():
    points = np.array([[0, 0, 0], [np.nan, 0, 0], [2, 0, 0], [0, np.inf, 0]], np.float64)
    out = Compose([DropNonFinite(), NormaliseScale()])(PointCloud(points))
    assert out.points.dtype == np.float32
    np.testing.assert_allclose(out.points, [[-1, 0, 0], [1, 0, 0]])


def test_estimate_normals_adds_a_normals_field():
    cloud = PointCloud(labelled_cloud().points)
    assert EstimateNormals(8)(cloud).fields["normals"].shape == (200, 3)
