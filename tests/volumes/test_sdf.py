"""Signed distance fields: winding numbers and distances of a triangle soup, SDFGrid queries, gradients, meshes."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

import pointfield
from pointfield.clouds.mesh import Mesh
from pointfield.errors import FormatError
from pointfield.volumes.sdf import SDFGrid, inside_by_levels, mesh_to_sdf
from pointfield.volumes.triangles import (
    TriangleClusters,
    closest_on_triangles,
    solid_angle,
    unsigned_distances,
    winding_numbers,
)


def sphere(subdivisions: int = 3) -> Mesh:
    shape = trimesh.creation.icosphere(subdivisions)
    return Mesh(np.asarray(shape.vertices), faces=np.asarray(shape.faces))


def brute_force_distance(points: np.ndarray, vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    corners = torch.as_tensor(vertices[triangles])
    out = []
    for p in torch.as_tensor(points):
        q = p.expand(len(corners), 3)
        out.append(float((closest_on_triangles(q, corners[:, 0], corners[:, 1], corners[:, 2]) - q).norm(dim=1).min()))
    return np.array(out)


def test_winding_number_is_one_inside_and_zero_outside_a_closed_mesh():
    mesh = sphere()
    clusters = TriangleClusters.build(mesh.points, mesh.triangles())
    rng = np.random.default_rng(0)
    points = rng.uniform(-2, 2, (3000, 3))
    radius = np.linalg.norm(points, axis=1)
    w = winding_numbers(points, clusters)
    assert np.abs(w[radius < 0.95] - 1).max() < 0.02  # the dipole terms of far clusters are approximate
    assert np.abs(w[radius > 1.05]).max() < 0.02


def test_winding_number_of_far_clusters_matches_the_exact_sum():
    mesh = sphere()
    triangles = mesh.triangles()
    clusters = TriangleClusters.build(mesh.points, triangles)
    points = np.random.default_rng(1).uniform(-1.5, 1.5, (200, 3))
    corners = torch.as_tensor(mesh.points[triangles])
    exact = np.array([float(solid_angle(*(corners - torch.as_tensor(p)).unbind(1)).sum()) / (4 * np.pi)
                      for p in points])
    assert np.abs(winding_numbers(points, clusters) - exact).max() < 0.02


def test_distances_equal_the_brute_force_nearest_triangle(shared_data):
    mesh = pointfield.read(shared_data / "modelnet/ModelNet10/chair/train/chair_0002.off")
    triangles = mesh.triangles()
    clusters = TriangleClusters.build(mesh.points, triangles)
    points = np.random.default_rng(2).uniform(-0.7, 0.7, (300, 3))
    exact = brute_force_distance(points, np.asarray(mesh.points, np.float64), triangles)
    assert np.allclose(unsigned_distances(points, clusters), exact, atol=1e-12)


def test_sdf_of_a_sphere_is_radius_minus_one_at_every_node():
    grid = mesh_to_sdf(sphere(4), resolution=24, device="cpu")
    radius = np.linalg.norm(grid.nodes(), axis=-1)
    # The icosphere's flat faces lie up to 0.0012 inside the unit sphere; far nodes' sample distances add less.
    assert np.abs(grid.values - (radius - 1)).max() < 0.01
    assert grid.metadata["openness"]["boundary"] == 0


def test_winding_numbers_are_evaluated_near_the_surface_only_with_the_same_answer():
    mesh = sphere()
    clusters = TriangleClusters.build(mesh.points, mesh.triangles())
    voxel, n = 0.1, 31
    origin = np.full(3, -1.5)
    axes = origin[0] + np.arange(n) * voxel
    nodes = np.stack(np.meshgrid(axes, axes, axes, indexing="ij"), axis=-1)
    lower = np.abs(np.linalg.norm(nodes, axis=-1) - 1) - 0.01
    inside, share, _ = inside_by_levels(lower, voxel, lambda p: winding_numbers(p, clusters), origin)
    everywhere = winding_numbers(nodes.reshape(-1, 3), clusters).reshape(nodes.shape[:3]) > 0.5
    assert np.array_equal(inside, everywhere)
    assert share < 0.5


def test_a_hole_in_the_mesh_leaves_the_signs_right():
    mesh = sphere()
    centres = mesh.points[mesh.triangles()].mean(axis=1)
    mesh = Mesh(mesh.points, faces=mesh.faces[centres[:, 2] < 0.9])  # a cap cut off: a hole of radius 0.44
    grid = mesh_to_sdf(mesh, resolution=20, device="cpu")
    radius = np.linalg.norm(grid.nodes(), axis=-1)
    below = grid.nodes()[..., 2] < 0.5
    assert (grid.values[(radius < 0.9) & below] < 0).all()
    assert (grid.values[radius > 1.1] > 0).all()
    assert grid.metadata["openness"]["boundary"] > 0


def test_trilinear_query_and_gradient_are_exact_on_a_linear_field():
    slope, offset = np.array([0.5, -2.0, 3.0]), 0.25
    origin, spacing = np.array([-1.0, 0.0, 2.0]), 0.2
    axes = [origin[a] + np.arange(n) * spacing for a, n in enumerate((6, 7, 8))]
    nodes = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
    grid = SDFGrid(nodes @ slope + offset, origin, spacing)
    points = origin + np.random.default_rng(3).uniform(0, 1, (100, 3)) * spacing * np.array([5, 6, 7])
    assert np.allclose(grid.query(points), points @ slope + offset, atol=1e-5)
    assert np.allclose(grid.gradient(points), slope, atol=1e-4)


def test_gradient_of_a_sphere_sdf_points_outwards():
    grid = mesh_to_sdf(sphere(), resolution=24, device="cpu")
    points = np.random.default_rng(4).normal(size=(200, 3))
    points = points / np.linalg.norm(points, axis=1, keepdims=True) * 0.8
    gradient = grid.gradient(points)
    cosine = (gradient * points).sum(axis=1) / np.linalg.norm(gradient, axis=1) / 0.8
    assert cosine.min() > 0.95


def test_marching_cubes_gives_a_closed_outward_mesh_of_the_right_volume():
    mesh = mesh_to_sdf(sphere(), resolution=32, device="cpu").to_mesh()
    out = trimesh.Trimesh(mesh.points, mesh.faces)
    assert out.is_watertight  # every edge shared by two faces
    assert out.volume == pytest.approx(4 / 3 * np.pi, rel=0.03)  # positive: faces wind outwards


def test_save_and_load_round_trip_and_refuse_other_files(tmp_path):
    grid = SDFGrid(np.random.default_rng(5).normal(size=(3, 4, 5)), np.array([1.0, 2, 3]), 0.5, {"source": "x"})
    grid.save(tmp_path / "f.npz")
    back = SDFGrid.load(tmp_path / "f.npz")
    assert np.array_equal(back.values, grid.values) and back.spacing == 0.5 and back.metadata == {"source": "x"}
    np.savez(tmp_path / "other.npz", points=np.zeros((2, 3)))
    with pytest.raises(FormatError, match=r"other\.npz: not an SDF grid"):
        SDFGrid.load(tmp_path / "other.npz")
