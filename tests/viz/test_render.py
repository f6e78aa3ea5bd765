"""The point renderer: deterministic z-buffering, colour choice, NaN handling, the up-axis rule."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from pointfield import Mesh, PointCloud, PointfieldError, Records
from pointfield.clouds import synthetic
from pointfield.viz import guess_up_axis, image_grid, render_cloud, save_image
from pointfield.viz.render import _nearest_per_pixel, colour_source, normalised_colours

WHITE = np.array([255, 255, 255], np.uint8)


def _covered(image: np.ndarray) -> np.ndarray:
    return (image != WHITE).any(axis=2)


def test_image_has_the_requested_size_and_draws_the_cloud():
    image = render_cloud(synthetic.sphere(2000, seed=0), width=160, height=120)
    assert image.shape == (120, 160, 3) and image.dtype == np.uint8
    assert 0.1 < _covered(image).mean() < 0.9  # the cloud, framed with background around it


def test_rendering_twice_gives_the_same_image():
    cloud = synthetic.lidar_scan(8, 256, seed=0)
    assert np.array_equal(render_cloud(cloud, 200, 150), render_cloud(cloud, 200, 150))


def test_the_order_of_the_points_does_not_change_the_image():
    # The nearest point wins each pixel whatever the order: no last-write-wins.
    cloud = synthetic.cube_surface(3000, seed=0)
    order = np.random.default_rng(1).permutation(len(cloud))
    shuffled = PointCloud(cloud.points[order], {k: v[order] for k, v in cloud.fields.items()})
    assert np.array_equal(render_cloud(cloud, 200, 150), render_cloud(shuffled, 200, 150))


def test_the_nearest_point_wins_a_pixel_and_ties_go_to_the_lower_index():
    column = np.array([5.5, 5.5, 5.5, 9.5])
    row = np.array([4.5, 4.5, 4.5, 4.5])
    depth = np.array([3.0, 1.0, 1.0, 2.0])
    nearest = _nearest_per_pixel(column, row, depth, 12, 10, point_size=1)
    assert nearest[4, 5] == 1
    assert nearest[4, 9] == 3
    assert (nearest == -1).sum() == 12 * 10 - 2


def test_discs_cover_the_pixels_around_a_point():
    nearest = _nearest_per_pixel(
        np.array([10.5]), np.array([10.5]), np.array([1.0]), 21, 21, point_size=5
    )
    covered = np.argwhere(nearest == 0)
    assert len(covered) == 21  # a 5-pixel disc: 5x5 less its 4 corners
    assert (np.abs(covered - 10) <= 2).all()


def test_nan_points_are_ignored():
    cloud = synthetic.sphere(1500, seed=0)
    with_nan = PointCloud(
        np.concatenate([cloud.points, np.full((500, 3), np.nan, np.float32)]),
        {
            k: np.concatenate([v, np.zeros((500, *v.shape[1:]), v.dtype)])
            for k, v in cloud.fields.items()
        },
    )
    assert np.array_equal(render_cloud(cloud, 160, 120), render_cloud(with_nan, 160, 120))


def test_a_cloud_without_finite_points_gives_a_blank_image():
    blank = render_cloud(
        PointCloud(np.full((10, 3), np.nan, np.float32)), 40, 30, background=(1, 2, 3)
    )
    assert (blank == [1, 2, 3]).all()
    assert (render_cloud(PointCloud(np.zeros((0, 3), np.float32)), 40, 30) == 255).all()


def test_records_cannot_be_drawn():
    with pytest.raises(PointfieldError, match="x/y/z"):
        render_cloud(Records({"descriptor": np.zeros((4, 8), np.uint8)}))


def test_colour_source_prefers_colors_then_intensity_then_height():
    points = np.zeros((3, 3), np.float32)
    colors = np.zeros((3, 3), np.uint8)
    intensity = np.ones(3, np.float32)
    assert colour_source(PointCloud(points, {"colors": colors, "intensity": intensity})) == "colors"
    assert colour_source(PointCloud(points, {"intensity": intensity})) == "intensity"
    assert colour_source(PointCloud(points, {"label": np.arange(3)})) == "height"
    assert colour_source(PointCloud(points, {"label": np.arange(3)}), "label") == "label"


def test_colouring_by_a_missing_or_multi_component_field_is_an_error():
    cloud = PointCloud(np.zeros((3, 3), np.float32), {"features": np.zeros((3, 5), np.float32)})
    with pytest.raises(PointfieldError, match="nosuch"):
        colour_source(cloud, "nosuch")
    with pytest.raises(PointfieldError, match="features"):
        colour_source(cloud, "features")


def test_colors_are_drawn_in_their_own_colour():
    cloud = synthetic.sphere(2000, seed=0)
    cloud.fields["colors"] = np.tile(np.array([[220, 20, 20]], np.uint8), (len(cloud), 1))
    image = render_cloud(cloud, 160, 120).astype(int)
    drawn = image[_covered(image)]
    assert (drawn[:, 0] > drawn[:, 1] + 40).mean() > 0.95


def test_colours_of_every_dtype_are_normalised_alike():
    as_uint8 = np.array([[255, 128, 0], [10, 20, 30]], np.uint8)
    expected = as_uint8 / 255
    np.testing.assert_allclose(normalised_colours(as_uint8), expected, atol=1e-6)
    np.testing.assert_allclose(normalised_colours(as_uint8.astype(np.uint16)), expected, atol=1e-6)
    np.testing.assert_allclose(
        normalised_colours(as_uint8.astype(np.uint16) * 257), expected, atol=1e-6
    )
    np.testing.assert_allclose(normalised_colours(as_uint8 / 255.0), expected, atol=1e-6)
    np.testing.assert_allclose(normalised_colours(as_uint8.astype(np.float32)), expected, atol=1e-6)
    rgba = np.concatenate([as_uint8, np.full((2, 1), 7, np.uint8)], axis=1)
    np.testing.assert_allclose(normalised_colours(rgba), expected, atol=1e-6)


def test_colouring_by_different_sources_gives_different_images():
    cloud = synthetic.lidar_scan(8, 256, seed=0)
    by_intensity = render_cloud(cloud, 160, 120)
    by_height = render_cloud(cloud, 160, 120, color_by="height")
    by_ring = render_cloud(cloud, 160, 120, color_by="ring")
    assert np.array_equal(by_intensity, render_cloud(cloud, 160, 120, color_by="intensity"))
    assert not np.array_equal(by_intensity, by_height)
    assert not np.array_equal(by_height, by_ring)


def test_up_axis_rule():
    flat = PointCloud(np.random.default_rng(0).uniform([-50, -50, -2], [50, 50, 3], (500, 3)))
    tall = PointCloud(np.random.default_rng(0).uniform(-1, 1, (500, 3)))
    camera_frame = PointCloud(np.random.default_rng(0).uniform([-1, -1, 2], [1, 1, 3], (500, 3)))
    assert guess_up_axis(flat) == "z"  # lidar sweeps and terrain
    assert guess_up_axis(tall) == "y"  # graphics models
    assert guess_up_axis(camera_frame) == "-y"  # all in front of a camera at the origin
    assert guess_up_axis(synthetic.depth_camera(12, 16)) == "-y"  # organised
    tall.metadata["format"] = "las"
    assert guess_up_axis(tall) == "z"  # LAS elevation is z whatever the extents


def test_up_axis_can_be_given_and_changes_the_view():
    cloud = synthetic.torus(2000, seed=0)
    assert not np.array_equal(
        render_cloud(cloud, 120, 90, up="z"), render_cloud(cloud, 120, 90, up="x")
    )
    assert np.array_equal(render_cloud(cloud, 120, 90), render_cloud(cloud, 120, 90, up="z"))
    with pytest.raises(PointfieldError, match="axis"):
        render_cloud(cloud, 120, 90, up="w")


def test_a_mesh_is_drawn_as_its_surface_not_only_its_vertices():
    mesh = synthetic.icosphere(1)
    vertices_only = PointCloud(mesh.points, dict(mesh.fields))
    surface = _covered(render_cloud(mesh, 160, 120, point_size=1)).sum()
    assert surface > 3 * _covered(render_cloud(vertices_only, 160, 120, point_size=1)).sum()


def test_a_mesh_coloured_by_a_vertex_field_is_drawn_as_its_vertices():
    mesh = synthetic.icosphere(1)
    mesh.fields["colors"] = np.full((len(mesh.points), 3), 200, np.uint8)
    vertices_only = PointCloud(mesh.points, dict(mesh.fields))
    assert np.array_equal(render_cloud(mesh, 120, 90), render_cloud(vertices_only, 120, 90))


def test_a_mesh_with_no_area_falls_back_to_its_vertices():
    flat = Mesh(
        np.zeros((3, 3), np.float32) + [[0, 0, 0], [1, 0, 0], [2, 0, 0]],
        faces=np.array([[0, 1, 2]]),
    )
    assert _covered(render_cloud(flat, 60, 40)).any()


def test_clouds_above_the_point_budget_are_subsampled_deterministically(monkeypatch):
    import pointfield.viz.render as render_module

    monkeypatch.setattr(render_module, "MAX_POINTS", 1000)
    cloud = synthetic.sphere(5000, seed=0)
    image = render_cloud(cloud, 100, 80)
    assert np.array_equal(image, render_cloud(cloud, 100, 80))
    assert _covered(image).mean() > 0.2
    smaller = PointCloud(cloud.points[:1000], {k: v[:1000] for k, v in cloud.fields.items()})
    assert not np.array_equal(
        image, render_cloud(smaller, 100, 80)
    )  # a random subset, not a prefix


def test_image_grid_tiles_images_with_labels():
    images = [
        np.zeros((30, 40, 3), np.uint8),
        np.full((20, 40, 3), 100, np.uint8),
        np.zeros((30, 40, 3), np.uint8),
    ]
    sheet = image_grid(images, ["a", "b", "c"], columns=2)
    assert sheet.shape[1] == 80 and sheet.shape[0] > 60  # 2 x 2 cells, label strips below
    assert (sheet[:30, :40] == 0).all()


def test_save_image_writes_a_png(tmp_path):
    image = render_cloud(synthetic.sphere(500, seed=0), 64, 48)
    path = save_image(tmp_path / "cloud.png", image)
    with Image.open(path) as png:
        assert png.format == "PNG" and png.size == (64, 48)
        assert np.array_equal(np.asarray(png.convert("RGB")), image)
    assert [p.name for p in tmp_path.iterdir()] == ["cloud.png"]  # no temporary file left
