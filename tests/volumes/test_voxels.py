"""VoxelGrid from clouds and meshes: which voxels, which per-voxel values, solid filling, memory limits."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import pointfield
from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.mesh import Mesh
from pointfield.clouds.ops import voxel_downsample
from pointfield.errors import PointfieldError
from pointfield.volumes import VoxelGrid, mesh_openness, voxelize_cloud, voxelize_mesh
from pointfield.volumes.voxels import check_dense_fits, dense_bytes


def sphere_mesh(subdivisions: int = 3) -> Mesh:
    sphere = trimesh.creation.icosphere(subdivisions)
    return Mesh(np.asarray(sphere.vertices), {}, None, {}, faces=np.asarray(sphere.faces))


def test_cloud_voxels_hold_counts_mean_colours_and_majority_labels():
    points = np.array([[0.0, 0, 0], [0.2, 0.1, 0.3], [0.4, 0.4, 0.4], [1.1, 0, 0], [1.2, 0.1, 0]])
    colors = np.array([[0, 0, 0], [100, 50, 10], [200, 100, 20], [9, 9, 9], [11, 11, 11]], np.uint8)
    labels = np.array([3, 5, 5, 7, 2], np.int32)
    grid = voxelize_cloud(PointCloud(points, {"colors": colors, "labels": labels}), 0.5)
    assert grid.coords.tolist() == [[0, 0, 0], [2, 0, 0]]
    assert grid.fields["counts"].tolist() == [3, 2]
    assert grid.fields["colors"].tolist() == [[100, 50, 10], [10, 10, 10]]
    assert grid.fields["labels"].tolist() == [5, 2]  # a tie (7 once, 2 once) goes to the smaller label


def test_cloud_voxels_are_the_downsampled_cloud_voxels(shared_data):
    cloud = pointfield.read(shared_data / "pcd/pcl_milk_color_binary_compressed.pcd")
    grid = voxelize_cloud(cloud, 0.004)
    down = voxel_downsample(cloud, 0.004)
    assert len(grid) == len(down)
    assert grid.fields["counts"].sum() == len(cloud)
    # Each centroid of the downsampled cloud lies in its voxel, in the same (i, j, k) order.
    inside = (down.points >= grid.origin + grid.coords * grid.size - 1e-6) & (
        down.points <= grid.origin + (grid.coords + 1) * grid.size + 1e-6)
    assert inside.all()


def test_dense_and_back_give_the_same_grid():
    grid = VoxelGrid(np.array([[0, 1, 2], [3, 0, 0]]), np.array([1.0, 2, 3]), 0.5, {"counts": np.array([4, 6])})
    occupancy = grid.dense()
    assert occupancy.shape == (4, 2, 3) and occupancy.sum() == 2 and occupancy[3, 0, 0]
    again = VoxelGrid.from_dense(occupancy, grid.origin, grid.size, {"counts": grid.dense("counts")})
    assert np.array_equal(again.coords, grid.coords)
    assert again.fields["counts"].tolist() == [4, 6]


def test_a_dense_grid_over_its_budget_names_the_voxel_that_fits():
    with pytest.raises(PointfieldError, match=r"1000 x 1000 x 1000 voxels, 954 MiB.*voxel of 0\.0..") as error:
        check_dense_fits(np.array([1.0, 1.0, 1.0]), 0.001, 100 << 20, 1, what="the grid")
    fits = float(str(error.value).split("a voxel of ")[-1].split(" ")[0])
    assert dense_bytes(np.ones(3), fits, 1)[1] <= 100 << 20


def test_surface_voxels_of_a_sphere_lie_on_its_surface():
    grid = voxelize_mesh(sphere_mesh(), 0.1)
    radius = np.linalg.norm(grid.centres(), axis=1)
    assert np.abs(radius - 1).max() <= 0.1 * np.sqrt(3) / 2 + 1e-9  # a voxel the surface crosses
    assert grid.metadata["openness"]["boundary"] == 0


def test_a_filled_sphere_holds_every_voxel_inside_and_none_outside():
    size = 0.1
    grid = voxelize_mesh(sphere_mesh(), size, fill=True, device="cpu")
    occupancy = grid.dense()
    centres = grid.origin + (np.argwhere(np.ones(grid.shape, bool)) + 0.5) * size
    radius = np.linalg.norm(centres, axis=1).reshape(grid.shape)
    half_diagonal = size * np.sqrt(3) / 2
    assert occupancy[radius < 0.99 - half_diagonal].all()  # 0.99: the icosphere's flat faces dip inside r = 1
    assert not occupancy[radius > 1 + half_diagonal].any()


def test_filling_a_closed_modelnet_mesh_gives_its_volume(shared_data):
    mesh = pointfield.read(shared_data / "modelnet/ModelNet10/chair/train/chair_0002.off")
    assert mesh_openness(mesh)["boundary"] == 0
    volume = trimesh.Trimesh(mesh.points, mesh.triangles()).volume
    size = 0.02
    solid = voxelize_mesh(mesh, size, fill=True, device="cpu")
    surface = voxelize_mesh(mesh, size)
    inside = len(solid) - len(surface)
    # The voxels inside the surface alone fall short of the volume; with the surface's, they cover it.
    assert 0 < inside * size**3 <= volume <= len(solid) * size**3


def test_a_mesh_that_is_not_quite_closed_still_fills(shared_data):
    """toilet_0001 has 165 edges bounding holes: the winding number fills it where a flood fill would leak."""
    mesh = pointfield.read(shared_data / "modelnet/ModelNet10/toilet/train/toilet_0001.off")
    openness = mesh_openness(mesh)
    assert 0 < openness["boundary"] < 0.05 * openness["edges"]
    volume = trimesh.Trimesh(mesh.points, mesh.triangles()).volume
    size = 0.04
    solid = voxelize_mesh(mesh, size, fill=True, device="cpu")
    surface = voxelize_mesh(mesh, size)
    assert (len(solid) - len(surface)) * size**3 <= volume <= len(solid) * size**3
    assert solid.metadata["openness"] == openness


def test_a_voxel_too_small_for_the_budget_is_refused_before_any_work():
    with pytest.raises(PointfieldError, match=r"a voxel of 1e-05 .* more than the 1 MiB allowed: a voxel of"):
        voxelize_mesh(sphere_mesh(), 1e-5, max_bytes=1 << 20)


def test_a_grid_refuses_negative_coordinates_and_fields_of_the_wrong_length():
    with pytest.raises(ValueError, match="non-negative"):
        VoxelGrid(np.array([[-1, 0, 0]]))
    with pytest.raises(ValueError, match="first dimension must be 1"):
        VoxelGrid(np.array([[1, 0, 0]]), fields={"counts": np.array([1, 2])})
