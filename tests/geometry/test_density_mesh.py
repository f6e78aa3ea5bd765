"""Density meshes (``--method density``): a field trained on the cube gives the cube; runs without a box are refused.

The field is the session's ``ngp_cube_run``: trained 200 steps in the box [-1, 1]^3, twice the
cube's side, so a mesh of the box's walls would lie 16 voxels (of 64 across the box) from the cube.
"""

from __future__ import annotations

import numpy as np
import pytest

import pointfield
from pointfield import read
from pointfield.cli import main
from pointfield.errors import PointfieldError
from pointfield.fields.train import train
from pointfield.geometry import export_mesh, mesh_from_density

RESOLUTION = 64
VOXEL = 2 / RESOLUTION  # the field's box is [-1, 1]^3


@pytest.fixture(scope="module")
def cube_mesh(ngp_cube_run):
    """The density mesh of the cube's field at 64^3 and the default threshold."""
    return mesh_from_density(pointfield.load_run(ngp_cube_run, "cpu"), resolution=RESOLUTION)


def largest_axis(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(axis, sign)`` ``(N,)`` of the cube face each point is nearest to."""
    axis = np.abs(points).argmax(axis=1)
    return axis, np.sign(points[np.arange(len(points)), axis])


def test_the_density_mesh_of_a_field_trained_on_the_cube_lies_on_the_cube(cube_mesh):
    vertices = cube_mesh.points
    distance_to_surface = np.abs(np.abs(vertices).max(axis=1) - 0.5)
    # Measured, field seeds 0 to 2: medians of 1.5 to 2.1 voxels (TSDF fusion of the same field's
    # renders: 1.5); the rest lies on interior walls the half-trained field left inside the cube.
    assert np.median(distance_to_surface) < 3 * VOXEL
    near = distance_to_surface < 2 * VOXEL
    axis, sign = largest_axis(vertices[near])
    assert len(set(zip(axis.tolist(), sign.tolist()))) == 6  # every face of the cube


def test_the_faces_of_the_density_mesh_face_outwards(cube_mesh):
    triangles = cube_mesh.points[cube_mesh.faces]
    normals = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    centres = triangles.mean(axis=1)
    on_surface = np.abs(np.abs(centres).max(axis=1) - 0.5) < 2 * VOXEL
    axis, sign = largest_axis(centres[on_surface])
    outward = normals[on_surface][np.arange(len(axis)), axis] * sign > 0
    assert outward.mean() > 0.8  # measured 0.90 to 0.95


def test_the_density_mesh_is_coloured_by_the_cubes_faces(cube_mesh):
    colours = cube_mesh.fields["colors"].astype(np.float64)
    on_surface = np.abs(np.abs(cube_mesh.points).max(axis=1) - 0.5) < 2 * VOXEL
    axis, sign = largest_axis(cube_mesh.points)
    # The field is rough (about 18 dB held out), its colours muddy near the cube's edges: seed 0
    # gives +x (75, 51, 41) and +z (50, 56, 140) -- each face's own colour, by a margin.
    red, green, blue = colours[on_surface & (axis == 0) & (sign > 0)].mean(axis=0)  # +x is red
    assert red > 1.4 * green and red > 1.4 * blue
    red, green, blue = colours[on_surface & (axis == 2) & (sign > 0)].mean(axis=0)  # +z is blue
    assert blue > 2 * red and blue > 1.5 * green


def test_nerf_export_writes_a_decimated_density_mesh(ngp_cube_run, tmp_path, capsys):
    out = tmp_path / "cube.ply"
    assert main(["nerf", "export", str(ngp_cube_run), "--mesh", str(out), "--method", "density",
                 "--resolution", "32", "--faces", "1000", "--device", "cpu", "--no-progress"]) == 0
    # The default threshold: instant-ngp's 2.5 over the box's longest side, 2.
    assert "density 32x32x32 at 1.25 over the field's box" in capsys.readouterr().out
    assert 0 < len(read(out).faces) <= 1000


def test_a_tinynerf_run_is_meshed_over_its_scenes_box(tmp_path):
    # Untrained, its density is about softplus(0) = 0.69 everywhere: above 0.1 the whole box is
    # matter, and the zero density padded around the box closes it.
    train(None, model="tiny", out=tmp_path / "run", steps=1, eval_every=1, cube_views=3, cube_size=8, device="cpu",
          model_options={"samples": 8}, progress=False)
    mesh = mesh_from_density(pointfield.load_run(tmp_path / "run", "cpu"), resolution=16, threshold=0.1)
    voxel = 1.2 / 16  # the cube's box, [-0.6, 0.6]^3
    distance_to_box = np.abs(np.abs(mesh.points).max(axis=1) - 0.6)
    assert distance_to_box.max() < voxel
    axis, sign = largest_axis(mesh.points)
    assert len(set(zip(axis.tolist(), sign.tolist()))) == 6
    assert mesh.fields["colors"].dtype == np.uint8


def test_a_threshold_the_density_never_reaches_is_refused(ngp_cube_run, tmp_path):
    with pytest.raises(PointfieldError, match="never reaches the threshold 1e[+]06"):
        export_mesh(ngp_cube_run, tmp_path / "none.ply", method="density", threshold=1e6, resolution=16,
                    device="cpu", progress=False)
    assert not (tmp_path / "none.ply").exists()


def test_a_density_grid_too_large_says_what_fits(ngp_cube_run):
    run = pointfield.load_run(ngp_cube_run, "cpu")
    with pytest.raises(PointfieldError, match=r"density grid .* needs .* GiB, .* pass --resolution \d+ or less"):
        mesh_from_density(run, resolution=1024, memory_limit=1 << 30)


def test_an_unknown_mesh_method_or_a_threshold_without_density_is_refused(ngp_cube_run, tmp_path):
    with pytest.raises(PointfieldError, match="mesh method must be one of tsdf, density, got 'poisson'"):
        export_mesh(ngp_cube_run, tmp_path / "cube.ply", method="poisson")
    with pytest.raises(PointfieldError, match="threshold is for --method density"):
        export_mesh(ngp_cube_run, tmp_path / "cube.ply", threshold=5.0)


def test_a_splat_run_has_no_density_to_mesh(splat_run, tmp_path, capsys):
    code = main(["splat", "export", str(splat_run), "--mesh", str(tmp_path / "mesh.ply"), "--method", "density",
                 "--no-progress"])
    error = capsys.readouterr().err
    assert code == 1
    assert "density meshing needs a field run of a bounded scene" in error and "use --method tsdf" in error
    assert not (tmp_path / "mesh.ply").exists()


def test_a_field_of_an_unbounded_scene_has_no_box_to_mesh(tmp_path):
    options = {"backend": "eager", "levels": 4, "log2_table_size": 12, "max_resolution": 32,
               "proposal_samples": [32, 16], "field_samples": 16, "target_samples": 2048}
    train(None, model="ngp", out=tmp_path / "run", steps=1, eval_every=1, cube_views=3, cube_size=8, device="cpu",
          model_options=options, scene_box="unbounded", progress=False)
    with pytest.raises(PointfieldError, match="unbounded scene .* use --method tsdf"):
        export_mesh(tmp_path / "run", tmp_path / "mesh.ply", method="density", device="cpu", progress=False)


def test_what_matter_encloses_is_filled_so_only_the_outside_surface_is_meshed():
    from skimage.measure import marching_cubes

    from pointfield.geometry.density import fill_enclosed

    # A hollow ball (matter from radius 6 to 9) and, apart from it, a cup open to the outside.
    axis = np.arange(32) - 15.5
    x, y, z = np.meshgrid(axis, axis, axis, indexing="ij")
    radius = np.sqrt(x**2 + y**2 + z**2)
    grid = np.where((radius > 6) & (radius < 9), 10.0, 0.0).astype(np.float32)
    cup = np.zeros((40, 32, 32), np.float32)
    cup[4:12, 4:28, 4:28] = 10.0
    cup[6:13, 8:24, 8:24] = 0.0  # hollowed from the top: its inside is joined to the outside
    fill_enclosed(grid, 1.0)
    fill_enclosed(cup, 1.0)
    vertices = marching_cubes(np.pad(grid, 1), level=1.0)[0] - 1
    distance = np.linalg.norm(vertices - 15.5, axis=1)
    assert distance.min() > 8  # the inner wall is gone: one sphere, radius 9
    assert cup[8, 16, 16] == 0.0  # an open cavity is left as it is
