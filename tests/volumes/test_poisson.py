"""Poisson reconstruction: a closed mesh through oriented points, estimated normals said aloud, the CLI verb."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import pointfield
from pointfield.cli import main
from pointfield.clouds.cloud import PointCloud
from pointfield.geometry.compare import sample_mesh, surface_scores
from pointfield.volumes import poisson_surface


def sphere_points(subdivisions: int = 4) -> PointCloud:
    shape = trimesh.creation.icosphere(subdivisions)
    return PointCloud(np.asarray(shape.vertices), {"normals": np.asarray(shape.vertex_normals)})


def test_points_of_a_sphere_give_a_closed_outward_sphere():
    mesh = poisson_surface(sphere_points(), depth=5)
    shape = trimesh.Trimesh(mesh.points, mesh.faces)
    assert shape.is_watertight
    assert shape.volume == pytest.approx(4 / 3 * np.pi, rel=0.01)  # positive: faces front along the normals
    assert np.abs(np.linalg.norm(mesh.points, axis=1) - 1).max() < 0.01


def test_normals_pointing_inwards_turn_the_faces_inwards():
    cloud = sphere_points()
    cloud.fields["normals"] = -cloud.fields["normals"]
    mesh = poisson_surface(cloud, depth=5)
    assert trimesh.Trimesh(mesh.points, mesh.faces).volume < 0


def test_a_cloud_without_normals_gets_estimated_ones_and_a_warning():
    cloud = PointCloud(sphere_points().points)
    with pytest.warns(UserWarning, match="no normals: estimated them by PCA"):
        mesh = poisson_surface(cloud, depth=5)
    assert trimesh.Trimesh(mesh.points, mesh.faces).is_watertight


def test_armadillo_is_meshed_close_to_its_points(shared_data, tmp_path, capsys):
    out = tmp_path / "armadillo.ply"
    source = shared_data / "ply/armadillo_points_normals_ascii.ply"
    assert main(["cloud", "poisson", str(source), str(out), "--depth", "6"]) == 0
    assert "faces at depth 6, watertight" in capsys.readouterr().out
    cloud, mesh = pointfield.read(source), pointfield.read(out)
    low, high = cloud.bounds()
    diagonal = float(np.linalg.norm(high - low))
    scores = surface_scores(sample_mesh(mesh, 50_000), cloud.points, 0.01 * diagonal, unit=diagonal)
    assert scores["completeness_relative"] < 0.01  # every input point is near the surface


def test_a_grid_over_the_budget_is_refused_in_one_line(shared_data, tmp_path, capsys):
    code = main(["cloud", "poisson", str(shared_data / "ply/armadillo_points_normals_ascii.ply"),
                 str(tmp_path / "a.ply"), "--depth", "10", "--memory", "1G"])
    error = capsys.readouterr().err
    assert code == 1 and "the Poisson grid" in error and "or larger fits" in error and error.count("\n") == 1
    assert not (tmp_path / "a.ply").exists()
