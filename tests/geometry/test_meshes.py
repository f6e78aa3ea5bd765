"""TSDF fusion and marching cubes: the cube's own depth maps give the cube; files in every format."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pointfield import read
from pointfield.cli import main
from pointfield.errors import PointfieldError
from pointfield.geometry.meshes import (
    decimate,
    export_mesh,
    mesh_from_volume,
    write_mesh,
)
from pointfield.geometry.tsdf import TSDFVolume, fuse, interpolated_depth
from pointfield.scenes import synthetic_scene


@pytest.fixture(scope="module")
def fused_cube() -> TSDFVolume:
    """The synthetic cube's exact depth maps (24 views of 64 px) fused over [-1, 1]^3 at 64^3."""
    scene = synthetic_scene("cube", views=24, size=64)
    return fuse(TSDFVolume.create([-1, -1, -1], [1, 1, 1], 64), cube_views(scene), scene.cameras)


def cube_views(scene):
    return [(torch.from_numpy(scene.depth(i)), torch.from_numpy(scene.image(i))) for i in range(len(scene))]


def test_fusing_the_cubes_exact_depth_gives_the_cube(fused_cube):
    mesh = mesh_from_volume(fused_cube)
    vertices = mesh.points
    # vertices on the cube's surface to a fraction of a voxel, and all six faces covered
    distance_to_surface = np.abs(np.abs(vertices).max(axis=1) - 0.5)
    assert np.median(distance_to_surface) < fused_cube.voxel / 4
    assert np.percentile(distance_to_surface, 99) < 1.5 * fused_cube.voxel
    faces_covered = {(axis, sign) for axis, sign in zip(np.abs(vertices).argmax(1), np.sign(
        vertices[np.arange(len(vertices)), np.abs(vertices).argmax(1)]))}
    assert len(faces_covered) == 6
    # colours come from the images: the +x face is red
    on_plus_x = vertices[:, 0] > 0.49
    red, green, blue = mesh.fields["colors"][on_plus_x].mean(axis=0)
    assert red > 2 * green and red > 2 * blue


def test_only_blocks_near_the_surface_are_stored_and_view_order_does_not_matter(fused_cube):
    # the cube's shell of 8^3 blocks is a small part of the grid
    assert 0 < fused_cube.allocated_fraction < 0.5
    scene = synthetic_scene("cube", views=24, size=64)
    order = list(reversed(range(len(scene))))
    reversed_volume = fuse(TSDFVolume.create([-1, -1, -1], [1, 1, 1], 64),
                           [cube_views(scene)[i] for i in order], scene.cameras[order])
    forward_tsdf, forward_observed = fused_cube.dense()
    reversed_tsdf, reversed_observed = reversed_volume.dense()
    np.testing.assert_array_equal(forward_observed, reversed_observed)
    np.testing.assert_allclose(forward_tsdf, reversed_tsdf, atol=1e-5)


def test_views_coarser_than_the_grid_do_not_shrink_the_cube():
    # Pixels wider than voxels, as in bench_geometry (100 px views, 256^3). With the depth of the
    # nearest pixel's centre, a face seen at a grazing angle reads several voxels off either way,
    # and the clamping in front and dropping behind sank the faces half a voxel into the cube
    # (-0.47 voxel on average here); interpolated depth reads the face itself (-0.13).
    scene = synthetic_scene("cube", views=40, size=40)
    volume = fuse(TSDFVolume.create([-1, -1, -1], [1, 1, 1], 160), cube_views(scene), scene.cameras)
    vertices = mesh_from_volume(volume).points
    away_from_edges = np.sort(np.abs(vertices), axis=1)[:, 1] < 0.5 - volume.truncation
    signed = (np.abs(vertices).max(axis=1) - 0.5)[away_from_edges] / volume.voxel
    assert -0.25 < signed.mean() < 0.1
    assert np.abs(signed).mean() < 0.3


def test_depth_is_interpolated_on_a_plane_and_not_across_an_occlusion():
    # A tilted plane's depth map: z = 2 + 0.01 * column, at pixel centres (column + 0.5).
    depth = (2 + 0.01 * (torch.arange(8.0) + 0.5)).expand(6, 8).clone()
    pixels = torch.tensor([[3.25, 2.5], [0.1, 0.2], [7.9, 5.9]])
    # inside: exact; past the outer centres: held at the outer centre's depth
    torch.testing.assert_close(interpolated_depth(depth, pixels), torch.tensor([2.0325, 2.005, 2.075]))
    # a step of more than a tenth of the depth (an occluding edge), or a pixel that saw nothing:
    # the depth of the pixel the position falls in (column 3 of the step, the empty corner's neighbour)
    depth[:, 4:] += 1.0
    depth[0, 0] = 0.0
    pixels = torch.tensor([[3.75, 2.5], [4.25, 2.5], [0.75, 0.75], [1.25, 1.25]])
    torch.testing.assert_close(interpolated_depth(depth, pixels), torch.tensor([2.035, 3.045, 0.0, 2.015]))


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_fusion_on_cuda_gives_the_cpus_grid(fused_cube):
    scene = synthetic_scene("cube", views=24, size=64)
    on_cuda = fuse(TSDFVolume.create([-1, -1, -1], [1, 1, 1], 64, device="cuda"), cube_views(scene), scene.cameras)
    cpu_tsdf, cpu_observed = fused_cube.dense()
    cuda_tsdf, cuda_observed = on_cuda.dense()
    np.testing.assert_array_equal(cpu_observed, cuda_observed)
    # Equal to rounding, but where one view's distance to a voxel sits at -truncation to rounding:
    # it counts on one device and not on the other (1 voxel in 262,144, by 0.02, on an H200 with
    # 83c9098's fusion; none with this one).
    difference = np.abs(cpu_tsdf - cuda_tsdf)
    assert np.mean(difference > 1e-5) < 1e-4
    assert difference.max() < 0.1


def test_a_floater_seen_by_one_view_is_carved_by_the_others():
    scene = synthetic_scene("cube", views=24, size=64)
    views = cube_views(scene)
    depth, colour = views[0]
    floating = depth.clone()
    floating[28:36, 28:36] = depth[depth > 0].min() - 0.6  # a patch hanging 0.6 in front of the cube
    views[0] = (floating, colour)
    volume = fuse(TSDFVolume.create([-1, -1, -1], [1, 1, 1], 64), views, scene.cameras)
    vertices = mesh_from_volume(volume).points
    distance_to_surface = np.abs(np.abs(vertices).max(axis=1) - 0.5)
    assert distance_to_surface.max() < 3 * volume.voxel


def test_decimation_and_every_file_format(fused_cube, tmp_path):
    mesh = mesh_from_volume(fused_cube)
    small = decimate(mesh, 500)
    assert len(small.faces) <= 500 and "colors" in small.fields
    for suffix in (".ply", ".off", ".obj", ".glb"):
        write_mesh(tmp_path / f"cube{suffix}", small)
        assert (tmp_path / f"cube{suffix}").stat().st_size > 1000
    assert len(read(tmp_path / "cube.ply").faces) == len(small.faces)
    with pytest.raises(PointfieldError, match="a mesh is written as"):
        write_mesh(tmp_path / "cube.xyz", small)


def test_a_grid_too_large_says_how_much_it_needs_and_what_fits():
    with pytest.raises(PointfieldError, match=r"needs .* GiB, .* pass --resolution \d+ or less"):
        TSDFVolume.create([0, 0, 0], [1, 1, 1], 1024, memory_limit=1 << 30)
    scene = synthetic_scene("cube", views=2, size=64)
    volume = TSDFVolume.create([-1, -1, -1], [1, 1, 1], 64, memory_limit=3 << 19)  # the grid fits, its 84,480 rows do not
    with pytest.raises(PointfieldError, match=r"allocated voxels would need .* GiB"):
        fuse(volume, cube_views(scene), scene.cameras)


def test_export_mesh_of_a_run_through_the_command_line(splat_run, tmp_path, capsys):
    out = tmp_path / "mesh.ply"
    code = main(["splat", "export", str(splat_run), "--mesh", str(out), "--resolution", "32",
                 "--min-opacity", "0.05", "--no-progress"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert len(read(out).faces) > 0 and "faces" in captured.out
    with pytest.raises(PointfieldError, match="no surface"):
        export_mesh(splat_run, tmp_path / "none.ply", resolution=16, min_opacity=1.5, progress=False)
    assert not (tmp_path / "none.ply").exists()


def test_a_mesh_and_a_cloud_exported_together_render_each_view_once(splat_run, tmp_path, monkeypatch, capsys):
    # Rendering is most of an export's time: --mesh with --cloud rendered every view twice.
    from pointfield.splats.run import SplatRun

    rendered = []
    render = SplatRun.render
    monkeypatch.setattr(SplatRun, "render", lambda self, cameras, **options: rendered.append(len(cameras))
                        or render(self, cameras, **options))
    code = main(["splat", "export", str(splat_run), "--mesh", str(tmp_path / "mesh.ply"), "--resolution", "32",
                 "--cloud", str(tmp_path / "cloud.ply"), "--min-opacity", "0.05", "--no-progress"])
    assert code == 0, capsys.readouterr().err
    views = int(capsys.readouterr().out.split(" views)")[0].rsplit(" ", 1)[1])
    assert sum(rendered) == views and len(read(tmp_path / "cloud.ply").points) > 0
