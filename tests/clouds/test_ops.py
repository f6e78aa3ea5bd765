"""Point operations: centring, sampling, farthest points, voxels, normals, neighbourhoods."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pointfield.clouds import batched, ops
from pointfield.clouds.cloud import PointCloud

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def random_cloud(count: int = 500, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=(count, 3)).astype(np.float32)


def test_centre_moves_the_mean_to_the_origin_and_keeps_the_dtype():
    points = random_cloud() + 5
    centred = ops.centre(points)
    assert centred.dtype == np.float32
    np.testing.assert_allclose(centred.mean(axis=0), 0, atol=1e-5)


def test_normalise_keeps_utm_sized_coordinates_exact_relative_to_each_other():
    offsets = np.array([[0.0, 0.0, 0.0], [0.001, 0.0, 0.0], [0.0, 0.002, 0.0]])
    points = np.array([637000.0, 852000.0, 100.0]) + offsets
    normalised = ops.normalise_to_unit_sphere(points)
    assert normalised.dtype == np.float32
    assert np.isclose(np.linalg.norm(normalised, axis=1).max(), 1.0)
    distances = np.linalg.norm(normalised[1] - normalised[0]) / np.linalg.norm(
        normalised[2] - normalised[0]
    )
    assert distances == pytest.approx(0.5, rel=1e-5)


def test_unit_sphere_frame_of_coincident_points_has_radius_one():
    centre, radius = ops.unit_sphere_frame(np.ones((4, 3)))
    np.testing.assert_array_equal(centre, 1.0)
    assert radius == 1.0


def test_random_sample_without_replacement_when_there_are_enough_points():
    index = ops.random_sample(100, 40, np.random.default_rng(0))
    assert len(index) == 40 and len(set(index.tolist())) == 40


def test_random_sample_pads_with_repeats_and_keeps_every_point():
    index = ops.random_sample(5, 12, np.random.default_rng(0))
    assert len(index) == 12 and set(index.tolist()) == set(range(5))


def test_random_sample_of_nothing_is_an_error():
    with pytest.raises(ValueError, match="empty"):
        ops.random_sample(0, 4, np.random.default_rng(0))


def test_canonical_sample_does_not_depend_on_point_order():
    points = random_cloud(300)
    shuffled = points[np.random.default_rng(1).permutation(300)]
    a = points[ops.canonical_sample(points, 64)]
    b = shuffled[ops.canonical_sample(shuffled, 64)]
    np.testing.assert_array_equal(a, b)


def test_canonical_sample_treats_negative_zero_as_zero():
    points = np.array([[0.0, 1.0, 2.0], [3.0, 4.0, 5.0]])
    flipped = points.copy()
    flipped[0, 0] = -0.0
    np.testing.assert_array_equal(ops.canonical_sample(points, 2), ops.canonical_sample(flipped, 2))


def test_canonical_sample_larger_than_the_cloud_returns_every_point():
    assert sorted(ops.canonical_sample(random_cloud(10), 50).tolist()) == list(range(10))


def test_fpsample_agrees_with_the_reference_definition():
    points = random_cloud(400)
    fast = ops.farthest_point_sample(points, 64, start=7)
    slow = batched.farthest_point_sample_reference(torch.from_numpy(points), 64, start=7)
    np.testing.assert_array_equal(fast, slow.numpy())


def test_the_bucketed_subset_is_as_well_spread_as_a_farthest_point_sample():
    from scipy.spatial import cKDTree

    points = random_cloud(20_000)
    exact = ops.farthest_point_sample(points, 2_000)
    subset = ops.farthest_point_subset(points, 2_000)
    assert len(np.unique(subset)) == 2_000 and (np.diff(subset) > 0).all()
    np.testing.assert_array_equal(subset, ops.farthest_point_subset(points, 2_000))  # the same every time

    def covering_radius(sample):  # how far the worst-served point is from the sample
        return cKDTree(points[sample]).query(points)[0].max()

    assert covering_radius(subset) <= 1.01 * covering_radius(exact)
    assert covering_radius(subset) < 0.5 * covering_radius(np.arange(2_000))  # an arbitrary 2,000 are far worse
    assert ops.farthest_point_subset(points[:6], 9).tolist() == list(range(6))


@pytest.mark.parametrize("backend", ["torch", "fpsample"])
def test_batched_fps_agrees_with_the_reference_for_every_cloud(backend):
    points = torch.from_numpy(np.stack([random_cloud(300, seed) for seed in range(3)]))
    start = torch.tensor([0, 5, 299])
    sample = batched.farthest_point_sample_batched(points, 48, start=start, backend=backend)
    for b in range(3):
        reference = batched.farthest_point_sample_reference(points[b], 48, int(start[b]))
        torch.testing.assert_close(sample[b], reference)


@pytest.mark.parametrize("backend", ["torch", "fpsample"])
def test_fps_starts_at_the_point_farthest_from_the_centroid_in_every_version(backend):
    points = random_cloud(200)
    expected = ops.farthest_point_start(points)
    assert ops.farthest_point_sample(points, 5)[0] == expected
    sample = batched.farthest_point_sample_batched(torch.from_numpy(points)[None], 5, backend=backend)
    assert int(sample[0, 0]) == expected


def test_fps_is_order_independent_by_default():
    points = random_cloud(200)
    order = np.random.default_rng(3).permutation(200)
    a = points[ops.farthest_point_sample(points, 32)]
    b = points[order][ops.farthest_point_sample(points[order], 32)]
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("backend", ["torch", "fpsample"])
def test_fps_asking_for_more_points_than_there_are_repeats_the_start(backend):
    points = random_cloud(6)
    chosen = ops.farthest_point_sample(points, 9, start=2)
    assert sorted(set(chosen.tolist())) == list(range(6)) and (chosen[6:] == 2).all()
    sample = batched.farthest_point_sample_batched(torch.from_numpy(points)[None], 9,
                                                   start=torch.tensor([2]), backend=backend)
    assert sample[0].tolist() == chosen.tolist()


@pytest.mark.parametrize("backend", ["torch", "fpsample"])
def test_batched_fps_never_chooses_padding(backend):
    real = torch.from_numpy(random_cloud(50))
    padded = torch.cat([real, torch.full((30, 3), 100.0)])[None]
    mask = torch.arange(80)[None] < 50
    chosen = batched.farthest_point_sample_batched(padded, 60, mask, backend=backend)
    assert chosen.max() < 50
    unpadded = batched.farthest_point_sample_batched(real[None], 60, backend=backend)
    torch.testing.assert_close(chosen, unpadded)


def test_voxel_downsample_averages_points_and_float_fields_and_keeps_first_labels():
    points = np.array([[0.1, 0.1, 0.1], [0.3, 0.3, 0.3], [1.5, 0.2, 0.2]], np.float32)
    cloud = PointCloud(points, {
        "intensity": np.array([1.0, 3.0, 5.0], np.float32),
        "label": np.array([7, 8, 9], np.int32),
        "normals": np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1]], np.float32),
    })
    down = ops.voxel_downsample(cloud, 1.0)
    np.testing.assert_allclose(down.points, [[0.2, 0.2, 0.2], [1.5, 0.2, 0.2]], rtol=1e-6)
    np.testing.assert_allclose(down.fields["intensity"], [2.0, 5.0])
    assert down.fields["label"].tolist() == [7, 9] and down.fields["label"].dtype == np.int32
    np.testing.assert_allclose(np.linalg.norm(down.fields["normals"], axis=1), 1.0, rtol=1e-6)


def test_voxel_downsample_of_an_array_drops_nan_and_returns_centroids():
    points = np.array([[0.1, 0.1, 0.1], [np.nan, 0, 0], [0.3, 0.1, 0.1]])
    np.testing.assert_allclose(ops.voxel_downsample(points, 0.5), [[0.2, 0.1, 0.1]])


def test_normals_of_a_plane_are_perpendicular_to_it():
    rng = np.random.default_rng(0)
    plane = np.column_stack([rng.uniform(-1, 1, (400, 2)), np.zeros(400)])
    normals = ops.estimate_normals(plane, neighbours=10, viewpoint=np.array([0, 0, 5.0]))
    np.testing.assert_allclose(normals, np.tile([0, 0, 1.0], (400, 1)), atol=1e-5)


def test_normals_of_a_sphere_point_outward_and_nan_points_get_nan():
    rng = np.random.default_rng(0)
    directions = rng.normal(size=(800, 3))
    sphere = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    sphere[0] = np.nan
    normals = ops.estimate_normals(sphere, neighbours=12)
    assert np.isnan(normals[0]).all()
    assert ((normals[1:] * sphere[1:]).sum(axis=1) > 0.95).mean() > 0.98


def test_knn_matches_sorting_all_distances():
    points = torch.from_numpy(np.stack([random_cloud(120, 1), random_cloud(120, 2)]))
    query = points[:, :10]
    distance, index = batched.knn(query, points, 5)
    full = torch.cdist(query.double(), points.double()) ** 2
    expected = full.sort(dim=-1).indices[..., :5]
    torch.testing.assert_close(index, expected)
    torch.testing.assert_close(distance.double(), full.gather(-1, expected), rtol=1e-5, atol=1e-6)


def test_knn_ignores_padding():
    points = torch.tensor([[[0.0, 0, 0], [1.0, 0, 0], [0.1, 0, 0]]])
    mask = torch.tensor([[True, True, False]])
    _, index = batched.knn(points[:, :1], points, 2, mask)
    assert index.tolist() == [[[0, 1]]]


def test_ball_query_keeps_points_inside_the_radius_and_pads_with_the_nearest():
    points = torch.tensor([[[0.0, 0, 0], [0.1, 0, 0], [0.15, 0, 0], [2.0, 0, 0]]])
    group = batched.ball_query(points[:, :1], points, radius=0.2, size=6)
    assert group.tolist() == [[[0, 1, 2, 0, 0, 0]]]


def test_ball_query_does_not_depend_on_point_order():
    points = torch.from_numpy(random_cloud(400))[None] * 0.3
    order = torch.randperm(400)
    centres = points[:, :20]
    a = batched.gather_points(points, batched.ball_query(centres, points, 0.2, 16))
    b = batched.gather_points(points[:, order], batched.ball_query(centres, points[:, order], 0.2, 16))
    torch.testing.assert_close(a, b)
