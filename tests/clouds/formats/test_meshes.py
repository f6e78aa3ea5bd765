"""OBJ, STL and GLB / glTF meshes read through the one format registry (trimesh underneath):
what ``nerf export --mesh`` writes, ``read``, ``cloud info / render / convert`` and ``view`` take."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import pointfield
from pointfield.cli import main
from pointfield.clouds import Mesh, PointCloud
from pointfield.errors import FormatError
from pointfield.geometry.meshes import write_mesh
from pointfield.viewer.sources import kind_of


def coloured_box() -> trimesh.Trimesh:
    box = trimesh.creation.box(extents=(1.0, 2.0, 3.0))
    box.visual.vertex_colors = np.tile(np.uint8([200, 30, 10, 255]), (len(box.vertices), 1))
    return box


@pytest.mark.parametrize("suffix", [".glb", ".obj", ".stl"])
def test_a_mesh_that_pointfield_exports_reads_back(tmp_path, suffix):
    box = coloured_box()
    mesh = Mesh(box.vertices, {"colors": box.visual.vertex_colors[:, :3]}, faces=box.faces)
    write_mesh(tmp_path / f"box{suffix}", mesh)  # what nerf export --mesh box.glb / box.obj calls
    back = pointfield.read(tmp_path / f"box{suffix}")
    assert isinstance(back, Mesh) and len(back.faces) == 12
    corners = back.points[back.triangles()]
    area = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1).sum()
    assert area == pytest.approx(2 * (1 * 2 + 1 * 3 + 2 * 3), rel=1e-5)  # the box's surface, whatever the vertex layout
    assert np.allclose(back.points.min(axis=0), [-0.5, -1, -1.5], atol=1e-6)


def test_vertex_colours_and_a_gltf_scene_with_its_buffers(tmp_path):
    coloured_box().export(tmp_path / "box.gltf")
    back = pointfield.read(tmp_path / "box.gltf")
    assert back.metadata["format"] == "gltf" and len(back.faces) == 12
    assert np.all(back.fields["colors"] == [200, 30, 10])


def test_a_glb_is_known_by_its_signature_whatever_its_name(tmp_path):
    coloured_box().export(tmp_path / "box.glb")
    (tmp_path / "box.glb").rename(tmp_path / "box.bin3d")
    assert pointfield.read(tmp_path / "box.bin3d", format=None).metadata["format"] == "gltf"


def test_an_obj_of_vertices_only_is_a_point_cloud(tmp_path):
    (tmp_path / "points.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    cloud = pointfield.read(tmp_path / "points.obj")
    assert type(cloud) is PointCloud and len(cloud) == 3


@pytest.mark.parametrize(("name", "data"), [("bad.glb", b"glTF\x02\x00\x00\x00garbage"),
                                            ("bad.obj", b"v 1 2\nf 1 2 3\n"),
                                            ("empty.stl", b"")])
def test_malformed_meshes_are_format_errors_naming_the_file(tmp_path, name, data):
    (tmp_path / name).write_bytes(data)
    with pytest.raises(FormatError, match=name):
        pointfield.read(tmp_path / name)


def test_cloud_info_render_and_convert_take_a_glb(tmp_path, capsys):
    coloured_box().export(tmp_path / "lego.glb")
    assert main(["cloud", "info", str(tmp_path / "lego.glb")]) == 0
    out = capsys.readouterr().out
    assert "gltf, binary" in out and "faces   12" in out
    assert main(["cloud", "render", str(tmp_path / "lego.glb"), "--out", str(tmp_path / "lego.png"),
                 "--width", "64", "--height", "48"]) == 0
    assert (tmp_path / "lego.png").stat().st_size > 0
    assert main(["cloud", "convert", str(tmp_path / "lego.glb"), str(tmp_path / "lego.off")]) == 0
    assert len(pointfield.read(tmp_path / "lego.off").faces) == 12
    assert kind_of(tmp_path / "lego.glb") == "cloud"  # pointfield view draws it as it draws a PLY mesh


def test_a_cloud_without_faces_is_not_written_as_a_mesh_format(tmp_path):
    with pytest.raises(FormatError, match="cloud without faces"):
        pointfield.write(tmp_path / "points.glb", PointCloud(np.zeros((3, 3))))
    assert not (tmp_path / "points.glb").exists()


def test_stl_has_no_colours_and_says_so(tmp_path):
    box = coloured_box()
    mesh = Mesh(box.vertices, {"colors": box.visual.vertex_colors[:, :3]}, faces=box.faces)
    with pytest.warns(UserWarning, match=r"STL: keeps vertices and triangles; not written: colors"):
        pointfield.write(tmp_path / "box.stl", mesh)
    assert "colors" not in pointfield.read(tmp_path / "box.stl").fields


@pytest.mark.parametrize("suffix", [".glb", ".obj"])
def test_sixteen_bit_and_float_colours_are_scaled_to_bytes_with_a_warning(tmp_path, suffix):
    box = coloured_box()
    for colours, expected in ((np.tile(np.uint16([65535, 32896, 0]), (len(box.vertices), 1)), [255, 128, 0]),
                              (np.tile(np.float32([1.0, 0.5, 0.0]), (len(box.vertices), 1)), [255, 128, 0])):
        with pytest.warns(UserWarning, match=f"colors {colours.dtype}"):
            pointfield.write(tmp_path / f"box{suffix}", Mesh(box.vertices, {"colors": colours}, faces=box.faces))
        assert np.all(pointfield.read(tmp_path / f"box{suffix}").fields["colors"] == expected)
