"""`pointfield cloud voxelize`, `cloud sdf` and `cloud render` of a voxel file, and their one-line errors."""

from __future__ import annotations

import numpy as np
import trimesh
from PIL import Image

import pointfield
from pointfield.cli import main
from pointfield.volumes import SDFGrid, read_voxels


def test_voxelize_a_cloud_then_render_its_voxels(shared_data, tmp_path, capsys):
    out = tmp_path / "milk.npz"
    assert main(["cloud", "voxelize", str(shared_data / "pcd/pcl_milk_color_binary_compressed.pcd"), str(out),
                 "--voxel", "0.01"]) == 0
    assert "occupied voxels of 0.01" in capsys.readouterr().out
    grid = read_voxels(out)
    assert grid.fields["counts"].sum() == 13704 and "colors" in grid.fields
    png = tmp_path / "milk.png"
    assert main(["cloud", "render", str(out), "--out", str(png), "--width", "160", "--height", "120"]) == 0
    image = np.asarray(Image.open(png))
    assert image.shape == (120, 160, 3) and (image != 255).any()


def test_voxelize_a_mesh_solid_says_how_closed_it_was(shared_data, tmp_path, capsys):
    out = tmp_path / "chair.binvox"
    assert main(["cloud", "voxelize", str(shared_data / "modelnet/ModelNet10/chair/train/chair_0002.off"), str(out),
                 "--voxel", "0.05", "--fill", "--device", "cpu"]) == 0
    printed = capsys.readouterr().out
    assert "solid voxels of 0.05" in printed and "closed (every edge shared by two faces)" in printed
    assert len(read_voxels(out)) > 0


def test_a_voxel_too_small_for_memory_is_one_line_and_writes_nothing(shared_data, tmp_path, capsys):
    out = tmp_path / "chair.binvox"
    code = main(["cloud", "voxelize", str(shared_data / "modelnet/ModelNet10/chair/train/chair_0002.off"), str(out),
                 "--voxel", "0.0001", "--fill", "--memory", "300M"])
    error = capsys.readouterr().err
    assert code == 1 and error.count("\n") == 1
    assert "pointfield: error: a voxel of 0.0001" in error and "a voxel of 0.0" in error and "or larger fits" in error
    assert not out.exists()


def test_fill_of_a_cloud_is_refused(shared_data, tmp_path, capsys):
    code = main(["cloud", "voxelize", str(shared_data / "pcd/pcl_bunny_ascii.pcd"), str(tmp_path / "b.vox"),
                 "--voxel", "0.01", "--fill"])
    assert code == 1 and "--fill needs a mesh" in capsys.readouterr().err


def test_sdf_of_a_mesh_writes_the_grid_and_a_closed_level_set(shared_data, tmp_path, capsys):
    out, level_set = tmp_path / "chair.npz", tmp_path / "chair.ply"
    assert main(["cloud", "sdf", str(shared_data / "modelnet/ModelNet10/chair/train/chair_0002.off"), str(out),
                 "--resolution", "24", "--mesh", str(level_set), "--device", "cpu"]) == 0
    printed = capsys.readouterr().out
    assert "signed distances" in printed and "closed (every edge shared by two faces)" in printed
    grid = SDFGrid.load(out)
    assert grid.values.min() < 0 < grid.values.max()
    mesh = pointfield.read(level_set)
    assert trimesh.Trimesh(mesh.points, mesh.faces).is_watertight


def test_sdf_refuses_a_cloud_in_one_line(shared_data, tmp_path, capsys):
    code = main(["cloud", "sdf", str(shared_data / "pcd/pcl_bunny_ascii.pcd"), str(tmp_path / "b.npz")])
    error = capsys.readouterr().err
    assert code == 1 and "no faces; a signed distance field needs a mesh" in error and error.count("\n") == 1
