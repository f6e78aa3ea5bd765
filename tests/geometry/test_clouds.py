"""Point clouds from rendered depth: exact on exact depth, cleaned as asked, for any scene run."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pointfield import read
from pointfield.cli import main
from pointfield.clouds.cloud import PointCloud
from pointfield.errors import PointfieldError
from pointfield.geometry import backproject, clean_cloud, cloud_from_views, export_cloud
from pointfield.scenes import synthetic_scene


def exact_views(scene):
    """The scene's own images and depth as a renderer's views: depth along the ray, opacity from the mask."""
    views = []
    for index in range(len(scene)):
        rays = scene.cameras.rays(index)
        z_depth = torch.from_numpy(scene.depth(index)).double()
        views.append({
            "rgb": torch.from_numpy(scene.image(index)),
            "depth": z_depth / rays.axis_cosine,
            "opacity": torch.from_numpy(scene.mask(index).astype(np.float32)),
        })
    return views


def test_exact_depth_back_projects_onto_the_cube_with_its_face_normals_and_colours():
    scene = synthetic_scene("cube", views=4, size=48)
    cloud = cloud_from_views(exact_views(scene), scene.cameras)
    assert len(cloud.points) == sum(int(scene.mask(i).sum()) for i in range(len(scene)))
    # every point on the surface of the unit cube: its largest coordinate is 0.5
    np.testing.assert_allclose(np.abs(cloud.points).max(axis=1), 0.5, atol=1e-6)  # depth maps are float32
    normals = cloud.fields["normals"]
    has_normal = np.isfinite(normals).all(axis=1)
    assert has_normal.mean() > 0.7  # all but the silhouette and face edges
    axis = np.abs(cloud.points).argmax(axis=1)
    expected = np.zeros_like(normals)
    expected[np.arange(len(axis)), axis] = np.sign(cloud.points[np.arange(len(axis)), axis])
    agreement = (normals[has_normal] * expected[has_normal]).sum(axis=1)
    assert np.median(agreement) > 0.999
    assert cloud.fields["colors"].dtype == np.uint8


def test_transparent_pixels_give_no_points():
    scene = synthetic_scene("cube", views=1, size=16)
    view = exact_views(scene)[0]
    view["opacity"] = torch.full_like(view["opacity"], 0.3)
    assert len(backproject(view, scene.cameras, 0, min_opacity=0.5).points) == 0


def test_clean_cloud_crops_drops_strays_and_thins():
    rng = np.random.default_rng(0)
    surface = rng.random((2000, 3))
    surface[:, 2] = 0.0  # a flat square
    strays = rng.random((5, 3)) * 10 + 5
    cloud = PointCloud(np.concatenate([surface, strays]), {"colors": np.zeros((2005, 3), np.uint8)})
    cleaned = clean_cloud(cloud)
    assert len(cleaned.points) >= 1900 and np.all(cleaned.points < 2)
    cropped = clean_cloud(cloud, crop=[0, 0, -1, 0.5, 0.5, 1], outlier_neighbours=0)
    assert np.all(cropped.points[:, :2] <= 0.5) and 400 < len(cropped.points) < 600
    assert len(clean_cloud(cloud, points=100).points) == 100
    with pytest.raises(PointfieldError, match="crop must be"):
        clean_cloud(cloud, crop=[1, 0, 0, 0, 1, 1])


def test_the_command_prints_a_writers_warning_as_one_line(splat_run, tmp_path, capsys):
    # LAS stores 16-bit colours: the writer warns, and every command says so the way it says errors,
    # with no source file and line of pointfield's code.
    assert main(["splat", "export", str(splat_run), "--centres", str(tmp_path / "centres.las")]) == 0
    err = capsys.readouterr().err
    assert f"pointfield: warning: {tmp_path / 'centres.las'}: LAS changes these fields: colors uint8 -> uint16" in err
    assert "UserWarning" not in err and ".py:" not in err


def test_export_cloud_of_a_splat_run_through_the_command_line(splat_run, tmp_path, capsys):
    out = tmp_path / "cloud.ply"
    assert main(["splat", "export", str(splat_run), "--cloud", str(out), "--min-opacity", "0.05",
                 "--no-progress"]) == 0
    cloud = read(out)
    assert len(cloud.points) > 100 and {"colors", "normals"} <= set(cloud.fields)
    assert "points" in capsys.readouterr().out
    centres = tmp_path / "centres.ply"
    assert main(["splat", "export", str(splat_run), "--centres", str(centres)]) == 0
    assert len(read(centres).points) > 0


def test_nothing_opaque_and_runs_that_are_not_scene_runs_are_clear_errors(splat_run, tmp_path, capsys):
    with pytest.raises(PointfieldError, match="everything rendered transparent"):
        export_cloud(splat_run, tmp_path / "x.ply", min_opacity=1.5, progress=False)
    assert not (tmp_path / "x.ply").exists()
    assert main(["splat", "export", str(splat_run)]) == 1
    assert "needs --out" in capsys.readouterr().err
    not_a_run = tmp_path / "empty"
    not_a_run.mkdir()
    assert main(["nerf", "export", str(not_a_run), "--cloud", str(tmp_path / "y.ply")]) == 1
    assert not (tmp_path / "y.ply").exists()


def test_splat_depth_is_the_distance_along_the_ray_like_every_scene_models():
    from pointfield.scenes import Cameras, look_at
    from pointfield.splats.gaussians import Gaussians
    from pointfield.splats.run import render_camera

    # a wall of small opaque splats on the plane z = 0, seen from 4 units away, square on
    grid = np.stack(np.meshgrid(np.linspace(-3, 3, 121), np.linspace(-3, 3, 121)), -1).reshape(-1, 2)
    wall = Gaussians.from_points(np.concatenate([grid, np.zeros((len(grid), 1))], 1), opacity=0.99)
    cameras = Cameras(look_at([[0.0, 0.0, -4.0]], up=(0.0, 1.0, 0.0)), fx=40.0, fy=40.0, cx=32.0, cy=32.0,
                      width=64, height=64).to(dtype=torch.float32)
    view = render_camera(wall, cameras, 0, torch.ones(3))
    rays = cameras.rays(0)
    covered = view["opacity"] > 0.95
    distance_to_wall = 4.0 / rays.axis_cosine  # the plane is perpendicular to the optical axis
    np.testing.assert_allclose(view["depth"][covered].numpy(), distance_to_wall[covered].numpy(), rtol=2e-3)
    corner = rays.axis_cosine[0, 0]
    assert corner < 0.8  # the test means something: corner rays are far off the axis


def test_median_depth_is_asked_for_by_name_and_used_in_place_of_the_expected(splat_run, tmp_path):
    import pointfield
    from pointfield.geometry.clouds import cameras_of, render_views

    run = pointfield.load_run(splat_run)
    cameras = cameras_of(run, "dataset", 2)
    expected, median = render_views(run, cameras, False), render_views(run, cameras, False, depth="median")
    truth = run.render(cameras[[1]], outputs=("median_depth",))[0]["median_depth"]
    torch.testing.assert_close(median[1]["depth"], truth)
    torch.testing.assert_close(median[1]["rgb"], expected[1]["rgb"])
    seen = expected[1]["opacity"] > 0.5
    assert not torch.allclose(median[1]["depth"][seen], expected[1]["depth"][seen])  # two different depths
    out = tmp_path / "median.ply"
    assert main(["splat", "export", str(splat_run), "--cloud", str(out), "--depth", "median",
                 "--min-opacity", "0.05", "--no-progress"]) == 0
    assert len(read(out).points) > 100
    with pytest.raises(PointfieldError, match="depth must be one of expected, median"):
        export_cloud(run, tmp_path / "x.ply", depth="mean", progress=False)
    assert not (tmp_path / "x.ply").exists()
