"""OFF meshes: ModelNet files (malformed first lines included), variants, round trips, hostile."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import pointfield
from pointfield import FormatError, Mesh, PointCloud
from pointfield.clouds.cloud import same_fields
from pointfield.clouds.formats.off import looks_like_off

# (file under modelnet/, vertices, faces) — from MANIFEST.md.
MODELNET = [
    ("ModelNet10/bathtub/train/bathtub_0001.off", 3514, 3546),
    ("ModelNet10/bathtub/train/bathtub_0002.off", 700, 664),
    ("ModelNet10/bathtub/train/bathtub_0004.off", 2842, 3519),
    ("ModelNet10/chair/train/chair_0001.off", 2382, 2234),
    ("ModelNet10/chair/train/chair_0002.off", 192, 96),
    ("ModelNet10/toilet/train/toilet_0001.off", 3739, 6341),
    ("ModelNet10/toilet/train/toilet_0002.off", 11098, 17826),
    ("ModelNet40/airplane/train/airplane_0006.off", 13091, 29589),
]

TETRAHEDRON = b"""OFF
4 4 0
0 0 0
1 0 0
0 1 0
0 0 1
3 0 1 2
3 0 1 3
3 0 2 3
3 1 2 3
"""


def read_quietly(path, **options):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return pointfield.read(path, **options)


def write_bytes(tmp_path, name, data):
    path = tmp_path / name
    path.write_bytes(data)
    return path


@pytest.mark.parametrize(
    ("name", "vertices", "faces"), MODELNET, ids=[r[0].split("/")[-1] for r in MODELNET]
)
def test_modelnet_files_read_with_their_manifest_counts(shared_data, name, vertices, faces):
    mesh = read_quietly(shared_data / "modelnet" / name)
    assert isinstance(mesh, Mesh)
    assert mesh.points.shape == (vertices, 3) and mesh.points.dtype == np.float64
    assert mesh.faces.shape == (faces, 3) and mesh.faces.dtype == np.int32
    assert mesh.faces.min() >= 0 and mesh.faces.max() < vertices
    assert mesh.metadata == {"format": "off", "encoding": "ascii", "keyword": "OFF"}


def test_airplane_with_crlf_and_trailing_spaces_has_the_manifest_bounds(shared_data):
    mesh = read_quietly(shared_data / "modelnet/ModelNet40/airplane/train/airplane_0006.off")
    low, high = mesh.bounds()
    np.testing.assert_allclose(low, [0.03, 5.19, 0.0], atol=0.005)
    np.testing.assert_allclose(high, [4990.55, 4596.94, 714.76], atol=0.005)


def test_modelnets_malformed_first_line_reads_like_the_well_formed_file(shared_data, tmp_path):
    original = (shared_data / "modelnet/ModelNet10/chair/train/chair_0002.off").read_bytes()
    glued = b"OFF" + original.split(b"\n", 1)[1]  # "OFF192 96 0", as in the raw ModelNet set
    assert glued.startswith(b"OFF192 96 0\n")
    expected = read_quietly(shared_data / "modelnet/ModelNet10/chair/train/chair_0002.off")
    mesh = read_quietly(write_bytes(tmp_path, "glued.off", glued))
    np.testing.assert_array_equal(mesh.points, expected.points)
    np.testing.assert_array_equal(mesh.faces, expected.faces)


@pytest.mark.parametrize(
    "text",
    [
        TETRAHEDRON,
        TETRAHEDRON.replace(b"OFF\n4 4 0", b"OFF 4 4 0"),
        TETRAHEDRON.replace(b"OFF\n4 4 0", b"OFF4 4 0"),
        TETRAHEDRON.replace(b"\n", b"\r\n"),
        TETRAHEDRON.replace(b"OFF\n", b"# made by hand\nOFF # keyword\n\n# counts next\n"),
        TETRAHEDRON.replace(b"1 0 0\n", b"  1\t0   0  # a corner\n\n"),
        TETRAHEDRON.replace(b"4 4 0", b"4 4"),
    ],
    ids=[
        "plain",
        "counts on the keyword line",
        "glued counts",
        "crlf",
        "comments",
        "spacing",
        "no edge count",
    ],
)
def test_header_layouts_comments_and_spacing_all_read(tmp_path, text):
    mesh = read_quietly(write_bytes(tmp_path, "tet.off", text))
    np.testing.assert_array_equal(mesh.points, [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]])


def test_coff_integer_vertex_colours_are_uint8_and_float_colours_stay_float(tmp_path):
    ints = b"COFF\n3 1 0\n0 0 0 255 0 0 255\n1 0 0 0 255 0 255\n0 1 0 0 0 255 255\n3 0 1 2\n"
    mesh = read_quietly(write_bytes(tmp_path, "int.off", ints))
    assert mesh.fields["colors"].dtype == np.uint8 and mesh.fields["colors"].shape == (3, 4)
    floats = b"COFF\n3 1 0\n0 0 0 1.0 0 0\n1 0 0 0 1 0\n0 1 0 0 0 1\n3 0 1 2\n"
    mesh = read_quietly(write_bytes(tmp_path, "float.off", floats))
    assert mesh.fields["colors"].dtype == np.float64
    np.testing.assert_array_equal(mesh.fields["colors"], np.eye(3))


def test_noff_and_cnoff_carry_normals_then_colours(tmp_path):
    text = b"CNOFF\n3 1 0\n0 0 0 0 0 1 9 8 7\n1 0 0 0 0 1 9 8 7\n0 1 0 0 0 1 9 8 7\n3 0 1 2\n"
    mesh = read_quietly(write_bytes(tmp_path, "cn.off", text))
    np.testing.assert_array_equal(mesh.fields["normals"], [[0, 0, 1]] * 3)
    np.testing.assert_array_equal(mesh.fields["colors"], [[9, 8, 7]] * 3)
    text = b"NOFF\n3 1 0\n0 0 0 0 0 1\n1 0 0 0 0 1\n0 1 0 0 0 1\n3 0 1 2\n"
    assert set(read_quietly(write_bytes(tmp_path, "n.off", text)).fields) == {"normals"}


def test_face_colours_become_a_face_field(tmp_path):
    text = TETRAHEDRON.replace(b"3 0 1 2\n", b"3 0 1 2 255 0 0\n")
    for k in (b"3 0 1 3", b"3 0 2 3", b"3 1 2 3"):
        text = text.replace(k + b"\n", k + b" 0 255 0\n")
    mesh = read_quietly(write_bytes(tmp_path, "fc.off", text))
    assert mesh.face_fields["colors"].dtype == np.uint8
    np.testing.assert_array_equal(mesh.face_fields["colors"][:2], [[255, 0, 0], [0, 255, 0]])
    np.testing.assert_array_equal(mesh.faces[0], [0, 1, 2])


def test_polygons_of_different_sizes_give_a_ragged_face_array(tmp_path):
    text = b"OFF\n5 2 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n2 2 2\n4 0 1 2 3\n3 0 1 4\n"
    mesh = read_quietly(write_bytes(tmp_path, "ragged.off", text))
    assert mesh.faces.dtype == object and len(mesh.faces) == 2
    np.testing.assert_array_equal(mesh.faces[0], [0, 1, 2, 3])
    np.testing.assert_array_equal(mesh.faces[1], [0, 1, 4])
    assert len(mesh.triangles()) == 3


def test_all_quads_give_an_f_by_4_array(tmp_path):
    text = b"OFF\n4 1 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n"
    assert read_quietly(write_bytes(tmp_path, "quad.off", text)).faces.shape == (1, 4)


def test_a_file_without_faces_is_a_point_cloud(tmp_path):
    cloud = read_quietly(write_bytes(tmp_path, "points.off", b"OFF\n2 0 0\n1 2 3\n4 5 6\n"))
    assert type(cloud) is PointCloud and len(cloud) == 2


def test_lines_after_the_last_face_are_ignored_with_a_warning(tmp_path):
    with pytest.warns(UserWarning, match="1 line"):
        mesh = pointfield.read(write_bytes(tmp_path, "extra.off", TETRAHEDRON + b"3 0 1 2\n"))
    assert len(mesh.faces) == 4


def test_signature_recognises_off_keywords_and_glued_counts():
    assert looks_like_off(b"OFF\n4 4 0")
    assert looks_like_off(b"OFF3514 3546 0\n")
    assert (
        looks_like_off(b"COFF 1 0 0") and looks_like_off(b"NOFF\r\n") and looks_like_off(b"CNOFF\n")
    )
    assert not looks_like_off(b"OFFSET 1 2 3") and not looks_like_off(b"ply\n")


def test_an_off_file_with_a_lying_suffix_still_reads(tmp_path):
    assert isinstance(pointfield.read(write_bytes(tmp_path, "mesh.xyz", TETRAHEDRON)), Mesh)


# ---------------------------------------------------------------------------------------------
# Round trips


def test_a_modelnet_mesh_round_trips_exactly(shared_data, tmp_path):
    mesh = read_quietly(shared_data / "modelnet/ModelNet10/toilet/train/toilet_0001.off")
    pointfield.write(tmp_path / "toilet.off", mesh)
    back = read_quietly(tmp_path / "toilet.off")
    np.testing.assert_array_equal(back.points, mesh.points)
    np.testing.assert_array_equal(back.faces, mesh.faces)


def test_a_coloured_mesh_with_normals_and_face_colours_round_trips(tmp_path):
    rng = np.random.default_rng(5)
    mesh = Mesh(
        rng.normal(size=(6, 3)).astype(np.float32),
        {
            "normals": rng.normal(size=(6, 3)).astype(np.float32),
            "colors": rng.integers(0, 256, (6, 4), dtype=np.uint8),
        },
        faces=np.array([[0, 1, 2], [3, 4, 5], [0, 2, 4]], np.int32),
        face_fields={"colors": rng.random((3, 3))},
    )
    pointfield.write(tmp_path / "rich.off", mesh)
    assert (tmp_path / "rich.off").read_bytes().startswith(b"CNOFF\n6 3 0\n")
    back = read_quietly(tmp_path / "rich.off")
    np.testing.assert_array_equal(back.points, mesh.points.astype(np.float64))
    np.testing.assert_array_equal(back.fields["normals"], mesh.fields["normals"].astype(np.float64))
    assert same_fields({"colors": back.fields["colors"]}, {"colors": mesh.fields["colors"]})
    np.testing.assert_array_equal(back.faces, mesh.faces)
    assert same_fields(back.face_fields, mesh.face_fields)


def test_a_ragged_mesh_round_trips(tmp_path):
    faces = np.empty(2, object)
    faces[:] = [np.array([0, 1, 2, 3]), np.array([0, 1, 4])]
    mesh = Mesh(np.arange(15, dtype=np.float64).reshape(5, 3), faces=faces)
    pointfield.write(tmp_path / "ragged.off", mesh)
    back = read_quietly(tmp_path / "ragged.off")
    assert back.faces.dtype == object and len(back.faces) == 2
    assert all(np.array_equal(a, b) for a, b in zip(back.faces, mesh.faces, strict=True))


def test_a_point_cloud_is_written_as_vertices_without_faces(tmp_path):
    cloud = PointCloud(np.array([[1.5, 2, 3], [np.nan, 0, -1e-300]]))
    pointfield.write(tmp_path / "cloud.off", cloud)
    back = read_quietly(tmp_path / "cloud.off")
    assert type(back) is PointCloud
    np.testing.assert_array_equal(back.points, cloud.points)


def test_fields_off_cannot_hold_are_left_out_with_a_warning(tmp_path):
    cloud = PointCloud(np.zeros((2, 3)), {"intensity": np.ones(2)})
    with pytest.warns(UserWarning, match="'intensity'"):
        pointfield.write(tmp_path / "drop.off", cloud)


# ---------------------------------------------------------------------------------------------
# Hostile input: each is a FormatError naming the file


HOSTILE = {
    "empty": b"",
    "blank": b"\n \n",
    "random bytes": bytes(np.random.default_rng(1).integers(0, 256, 700, dtype=np.uint8)),
    "no keyword": b"4 4 0\n0 0 0\n",
    "unsupported variant": b"STOFF\n1 0 0\n0 0 0 0 0\n",
    "binary OFF": b"OFF BINARY\n",
    "header only": b"OFF\n",
    "negative counts": b"OFF\n-1 1 0\n",
    "counts not integers": b"OFF\nnan 1 0\n",
    "counts in exponent form": b"OFF\n1e3 1 0\n",
    "one count": b"OFF\n4\n",
    "huge counts in a tiny file": b"OFF\n1000000000000 1000000000000 0\n0 0 0\n",
    "fewer vertex lines than declared": TETRAHEDRON.replace(b"4 4 0", b"9 4 0"),
    "a vertex with two values": TETRAHEDRON.replace(b"1 0 0\n", b"1 0\n"),
    "a vertex with a word": TETRAHEDRON.replace(b"1 0 0\n", b"1 zero 0\n"),
    "a face index out of range": TETRAHEDRON.replace(b"3 1 2 3", b"3 1 2 4"),
    "a negative face index": TETRAHEDRON.replace(b"3 1 2 3", b"3 1 -2 3"),
    "a fractional face index": TETRAHEDRON.replace(b"3 1 2 3", b"3 1 2.5 3"),
    "a nan face index": TETRAHEDRON.replace(b"3 1 2 3", b"3 1 nan 3"),
    "a face with two corners": TETRAHEDRON.replace(b"3 1 2 3", b"2 1 2"),
    "a face line shorter than its k": TETRAHEDRON.replace(b"3 1 2 3", b"5 1 2 3"),
    "mixed face colours": TETRAHEDRON.replace(b"3 1 2 3", b"3 1 2 3 1 1 1"),
    "COFF vertex without colour": b"COFF\n1 0 0\n0 0 0\n",
}


@pytest.mark.parametrize("data", HOSTILE.values(), ids=HOSTILE.keys())
def test_hostile_off_is_a_format_error_naming_the_file(tmp_path, data):
    path = write_bytes(tmp_path, "hostile.off", data)
    with pytest.raises(FormatError) as error:
        pointfield.read(path)
    assert str(path) in str(error.value)


def test_an_out_of_range_index_names_its_line(tmp_path):
    path = write_bytes(tmp_path, "line.off", TETRAHEDRON.replace(b"3 1 2 3", b"3 1 2 7"))
    with pytest.raises(FormatError, match=r"line 10: vertex index 7 is not one of the 4 vertices"):
        pointfield.read(path)
