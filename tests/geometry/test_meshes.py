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
from pointfield.geometry.tsdf import TSDFVolume, fuse
from pointfield.scenes import synthetic_scene


@pytest.fixture(scope="module")
def fused_cube() -> TSDFVolume:
    """The synthetic cube's exact depth maps (24 views of 64 px) fused over [-1, 1]^3 at 64^3."""
    scene = synthetic_scene("cube", views=24, size=64)
    return fuse(TSDFVolume.create([-1, -1, -1], [1, 1, 1], 64), cube_views(scene), scene.cameras)


def cube_views(scene):
    return [(torch.from_numpy(scene.depth(i)), torch.from_numpy(scene.image(i))) for i in range(len(scene))]


def signed_distance_to_cube(vertices: np.ndarray) -> np.ndarray:
    """Of points near the surface of the cube [-0.5, 0.5]^3: positive outside."""
    return np.abs(vertices).max(axis=1) - 0.5


def away_from_edges(vertices: np.ndarray, margin: float) -> np.ndarray:
    """Points on a face of that cube farther than ``margin`` from its edges."""
    return np.sort(np.abs(vertices), axis=1)[:, 1] < 0.5 - margin


def test_fusing_the_cubes_exact_depth_gives_the_cube(fused_cube):
    mesh = mesh_from_volume(fused_cube)
    vertices = mesh.points
    # On the faces' inner parts, vertices lie on the cube's surface to a fraction of a voxel. Within
    # a truncation distance of an edge, a face's plane extends past the edge, and views that see it
    # at a grazing angle count voxels just outside the other face as behind it: edges round outwards
    # by up to about two voxels when, as here, the truncation is an eighth of the cube's side.
    distance = np.abs(signed_distance_to_cube(vertices))
    inner = away_from_edges(vertices, fused_cube.truncation)
    assert np.median(distance[inner]) < fused_cube.voxel / 4
    assert np.percentile(distance[inner], 99) < fused_cube.voxel
    assert distance.max() < 3 * fused_cube.voxel
    # all six faces covered
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
    # Pixels wider than voxels, as in bench_geometry (100 px views, 256^3): a view that sees a face
    # at a grazing angle reads, along its axis, several times a voxel's distance to the surface, so
    # with projective distances the zero level sank about half a voxel into the cube (-0.47 voxel
    # here). The distance to the plane each pixel saw reads the same from every angle (-0.23).
    scene = synthetic_scene("cube", views=40, size=40)
    volume = fuse(TSDFVolume.create([-1, -1, -1], [1, 1, 1], 160), cube_views(scene), scene.cameras)
    vertices = mesh_from_volume(volume).points
    signed = signed_distance_to_cube(vertices)[away_from_edges(vertices, volume.truncation)] / volume.voxel
    assert -0.35 < signed.mean() < 0.1
    assert np.abs(signed).mean() < 0.45


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_fusion_on_cuda_gives_the_cpus_grid(fused_cube):
    scene = synthetic_scene("cube", views=24, size=64)
    on_cuda = fuse(TSDFVolume.create([-1, -1, -1], [1, 1, 1], 64, device="cuda"), cube_views(scene), scene.cameras)
    cpu_tsdf, cpu_observed = fused_cube.dense()
    cuda_tsdf, cuda_observed = on_cuda.dense()
    np.testing.assert_array_equal(cpu_observed, cuda_observed)
    # Equal to rounding, but where one view's distance to a voxel sits at -truncation to rounding:
    # it counts on one device and not on the other (on an H200, 1 voxel in 262,144 differed by 0.02).
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
    assert np.abs(signed_distance_to_cube(vertices)).max() < 3 * volume.voxel


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
    volume = TSDFVolume.create([-1, -1, -1], [1, 1, 1], 64, memory_limit=2 << 20)
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
