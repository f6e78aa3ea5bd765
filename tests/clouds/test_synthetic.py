"""The procedural clouds are seedable, well-formed, and lie on the shapes they claim."""

from __future__ import annotations

import numpy as np
import pytest

from pointfield import Mesh, PointCloud
from pointfield.clouds import synthetic
from pointfield.clouds.cloud import same_fields

SEEDED = {
    "sphere": lambda seed: synthetic.sphere(500, seed=seed),
    "torus": lambda seed: synthetic.torus(500, seed=seed),
    "cube_surface": lambda seed: synthetic.cube_surface(500, seed=seed),
    "lidar_scan": lambda seed: synthetic.lidar_scan(8, 128, seed=seed),
    "depth_camera": lambda seed: synthetic.depth_camera(24, 32, seed=seed),
}


@pytest.mark.parametrize("name", SEEDED)
def test_the_same_seed_gives_the_same_cloud_bit_for_bit(name):
    a, b = SEEDED[name](7), SEEDED[name](7)
    assert np.array_equal(a.points, b.points, equal_nan=True)
    assert same_fields(a.fields, b.fields)


@pytest.mark.parametrize("name", SEEDED)
def test_another_seed_gives_another_cloud(name):
    a, b = SEEDED[name](1), SEEDED[name](2)
    assert a.points.shape != b.points.shape or not np.array_equal(
        a.points, b.points, equal_nan=True
    )


@pytest.mark.parametrize("name", SEEDED)
def test_points_are_float32_and_fields_use_the_dtypes_of_real_files(name):
    cloud = SEEDED[name](0)
    assert cloud.points.dtype == np.float32
    if "colors" in cloud.fields:
        assert cloud.fields["colors"].dtype == np.uint8
        assert cloud.fields["colors"].shape == (len(cloud), 3)
    for float_field in ("normals", "intensity"):
        if float_field in cloud.fields:
            assert cloud.fields[float_field].dtype == np.float32


def test_sphere_points_lie_on_the_sphere_with_outward_unit_normals():
    cloud = synthetic.sphere(1000, radius=2.5, seed=0)
    radii = np.linalg.norm(cloud.points, axis=1)
    np.testing.assert_allclose(radii, 2.5, rtol=1e-5)
    np.testing.assert_allclose(cloud.fields["normals"] * 2.5, cloud.points, atol=1e-5)


def test_torus_points_satisfy_the_torus_equation():
    cloud = synthetic.torus(1000, major_radius=1.0, minor_radius=0.3, seed=0)
    x, y, z = cloud.points.astype(np.float64).T
    # (sqrt(x^2 + y^2) - R)^2 + z^2 = r^2
    np.testing.assert_allclose((np.hypot(x, y) - 1.0) ** 2 + z**2, 0.09, atol=1e-5)


def test_torus_rejects_a_tube_wider_than_the_ring():
    with pytest.raises(ValueError):
        synthetic.torus(10, major_radius=1.0, minor_radius=1.5)


def test_cube_points_lie_on_a_face_with_that_face_normal():
    cloud = synthetic.cube_surface(1000, size=2.0, seed=0)
    on_face = np.isclose(np.abs(cloud.points), 1.0)
    assert on_face.any(axis=1).all()
    assert (np.abs(cloud.points) <= 1.0 + 1e-6).all()
    normal_axis = np.argmax(np.abs(cloud.fields["normals"]), axis=1)
    assert on_face[np.arange(len(cloud)), normal_axis].all()


def test_lidar_scan_has_intensity_in_unit_range_rings_and_a_ground():
    cloud = synthetic.lidar_scan(rings=16, columns=256, seed=0)
    assert 0 < len(cloud) <= 16 * 256
    intensity, ring = cloud.fields["intensity"], cloud.fields["ring"]
    assert ring.dtype == np.uint8 and set(np.unique(ring)) <= set(range(16))
    assert intensity.min() >= 0 and intensity.max() <= 1
    assert cloud.points[:, 2].min() > -synthetic.SENSOR_HEIGHT - 0.1
    assert np.linalg.norm(cloud.points, axis=1).max() < 80.5


def test_depth_camera_is_organised_with_nan_holes_and_points_in_front():
    cloud = synthetic.depth_camera(height=30, width=40, seed=0)
    assert cloud.shape == (30, 40) and len(cloud) == 1200
    invalid = np.isnan(cloud.points).any(axis=1)
    assert 0 < invalid.sum() < len(cloud)
    assert np.isnan(cloud.points[invalid]).all()
    assert (cloud.fields["colors"][invalid] == 0).all()
    assert (cloud.points[~invalid, 2] > 0).all()


@pytest.mark.parametrize("subdivisions", [0, 1, 2, 3])
def test_icosphere_counts_and_closed_outward_surface(subdivisions):
    mesh = synthetic.icosphere(subdivisions, radius=2.0)
    assert isinstance(mesh, Mesh)
    assert len(mesh.points) == 10 * 4**subdivisions + 2
    assert mesh.faces.shape == (20 * 4**subdivisions, 3)
    np.testing.assert_allclose(np.linalg.norm(mesh.points, axis=1), 2.0, rtol=1e-6)
    # Closed: every undirected edge is shared by exactly two faces.
    edges = np.sort(
        np.concatenate([mesh.faces[:, [0, 1]], mesh.faces[:, [1, 2]], mesh.faces[:, [2, 0]]]),
        axis=1,
    )
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert (counts == 2).all()
    corners = mesh.points[mesh.faces].astype(np.float64)
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    assert ((normals * corners.mean(axis=1)).sum(axis=1) > 0).all()


def test_generators_return_point_clouds():
    for make in SEEDED.values():
        assert isinstance(make(0), PointCloud)
