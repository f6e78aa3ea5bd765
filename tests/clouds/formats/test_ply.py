"""PLY: real files read with their MANIFEST counts, every encoding round-trips, hostile files fail
cleanly with a FormatError naming the file."""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
import pytest

import pointfield
from pointfield.clouds.cloud import PointCloud, Records, same_fields
from pointfield.clouds.formats import ply
from pointfield.clouds.formats.ply import ENCODINGS, is_ply, read_ply, write_ply
from pointfield.clouds.mesh import Mesh
from pointfield.errors import FormatError

REAL_PLY = "ply/"
REAL_SPLATS = "gaussians/3dgs_point_cloud_iter7000.ply"


def manifest_ply_files(shared_data: Path) -> dict[str, tuple[int, int | None]]:
    """MANIFEST rows for PLY files: local path -> (vertex count, face count or None)."""
    rows = {}
    for line in (shared_data / "MANIFEST.md").read_text().splitlines():
        match = re.match(r"\|\s*`([^`]+\.ply)`", line)
        if not match or not (match[1].startswith(REAL_PLY) or match[1] == REAL_SPLATS):
            continue
        vertices = re.search(r"vertex\[(\d+)\]", line)
        faces = re.search(r"face\[(\d+)\]", line)
        assert vertices, f"MANIFEST row for {match[1]} gives no vertex count"
        rows[match[1]] = (int(vertices[1]), int(faces[1]) if faces else None)
    return rows


def sample_cloud(count: int = 50, seed: int = 0, dtype: type = np.float32) -> PointCloud:
    """Points with NaN rows, colours, normals, intensity, an (N, 4) field and labels."""
    rng = np.random.default_rng(seed)
    points = (rng.normal(size=(count, 3)) * 1000).astype(dtype)
    points[count // 2] = np.nan
    feature = rng.normal(size=(count, 4)).astype(np.float32)
    feature[0, 2] = np.nan
    feature[-1, 0] = np.inf
    return PointCloud(
        points,
        {
            "colors": rng.integers(0, 256, (count, 3), dtype=np.uint8),
            "normals": rng.normal(size=(count, 3)).astype(np.float32),
            "intensity": rng.integers(0, 65536, count, dtype=np.uint16),
            "feature": feature,
            "label": rng.integers(-5, 40, count, dtype=np.int32),
        },
    )


def sample_mesh(seed: int = 0) -> Mesh:
    rng = np.random.default_rng(seed)
    points = rng.random((30, 3), dtype=np.float32)
    faces = rng.integers(0, 30, (40, 3), dtype=np.int32)
    return Mesh(
        points,
        {
            "colors": rng.integers(0, 256, (30, 4), dtype=np.uint8),
            "quality": rng.normal(size=30),
        },
        faces=faces,
        face_fields={
            "colors": rng.integers(0, 256, (40, 3), dtype=np.uint8),
            "texcoord": rng.random((40, 6), dtype=np.float32),
            "weight": rng.integers(-30000, 30000, 40, dtype=np.int16),
        },
    )


def polygon_mesh(seed: int = 0) -> Mesh:
    """Triangles, quads and a pentagon mixed, with a per-face list of varying length too."""
    rng = np.random.default_rng(seed)
    sizes = [3, 4, 3, 5, 4, 3]
    faces = np.empty(len(sizes), object)
    weights = np.empty(len(sizes), object)
    for i, size in enumerate(sizes):
        faces[i] = rng.integers(0, 12, size).astype(np.int32)
        weights[i] = rng.random(size).astype(np.float32)
    return Mesh(rng.random((12, 3)), faces=faces, face_fields={"weights": weights})


def assert_same_cloud(a: PointCloud, b: PointCloud) -> None:
    assert type(a) is type(b)
    assert a.points.dtype == b.points.dtype
    np.testing.assert_array_equal(a.points, b.points)
    assert same_fields(a.fields, b.fields), (a.fields, b.fields)
    if isinstance(a, Mesh):
        assert same_fields({"faces": a.faces}, {"faces": b.faces})
        assert same_fields(a.face_fields, b.face_fields)


def write_bytes(tmp_path: Path, data: bytes, name: str = "cloud.ply") -> Path:
    path = tmp_path / name
    path.write_bytes(data)
    return path


# --- real files --------------------------------------------------------------------------------


def test_every_real_ply_file_reads_with_the_counts_in_the_manifest(shared_data):
    files = manifest_ply_files(shared_data)
    assert len(files) >= 15
    for name, (vertices, faces) in files.items():
        cloud = read_ply(shared_data / name)
        assert len(cloud) == vertices, name
        if faces:
            assert isinstance(cloud, Mesh), name
            assert len(cloud.faces) == faces, name
        else:
            assert not isinstance(cloud, Mesh), name


def test_double_properties_stay_float64(shared_data):
    cloud = read_ply(shared_data / "ply/pcu_duplicated_pcloud_double_normals.ply")
    assert cloud.points.dtype == np.float64
    assert cloud.fields["normals"].dtype == np.float64


def test_element_face_0_reads_as_a_plain_point_cloud(shared_data):
    cloud = read_ply(shared_data / "ply/trimesh_points_bin.ply")
    assert type(cloud) is PointCloud
    assert "ply_elements" not in cloud.metadata


def test_sized_type_names_keep_their_dtypes(shared_data):
    records = read_ply(shared_data / "ply/pdal_sized_dims_ascii.ply")
    assert isinstance(records, Records)  # x and y but no z
    assert {name: values.dtype for name, values in records.fields.items()} == {
        "x": np.int8,
        "y": np.uint16,
        "j": np.int32,
        "i": np.float64,
    }
    assert [values[0] for values in records.fields.values()] == [1, 12346, 12345, 1234567890.0]


def test_comments_and_obj_info_are_kept(shared_data):
    cloud = read_ply(shared_data / "ply/pdal_simple_binary_cloudcompare.ply")
    assert cloud.metadata["obj_info"] == ["Generated by CloudCompare!"]
    assert cloud.metadata["comments"] == ["Author: CloudCompare (TELECOM PARISTECH/EDF R&D)"]
    poisson = read_ply(shared_data / "ply/pcu_bunny_poisson_binary_le.ply")
    assert len(poisson.metadata["comments"]) == 17
    assert "\t--depth 5" in poisson.metadata["comments"]


def test_face_list_properties_and_face_colours(shared_data):
    mesh = read_ply(shared_data / "ply/trimesh_fuze_binary_le_colors_texcoord.ply")
    assert mesh.faces.shape == (1000, 3)
    assert mesh.fields["colors"].shape == (502, 4)
    assert mesh.face_fields["texcoord"].shape == (1000, 6)
    assert mesh.face_fields["texcoord"].dtype == np.float32
    assert mesh.face_fields["colors"].shape == (1000, 4)
    assert mesh.face_fields["colors"].dtype == np.uint8


def test_gaussian_splat_file_keeps_every_property(shared_data):
    splats = read_ply(shared_data / REAL_SPLATS)
    expected = {"normals", "opacity"} | {f"f_dc_{i}" for i in range(3)}
    expected |= {f"f_rest_{i}" for i in range(45)} | {f"scale_{i}" for i in range(3)}
    expected |= {f"rot_{i}" for i in range(4)}
    assert set(splats.fields) == expected
    assert all(values.dtype == np.float32 for values in splats.fields.values())


@pytest.mark.parametrize(
    "name",
    [
        "ply/trimesh_fuze_binary_le_colors_texcoord.ply",
        "ply/trimesh_bunny_ascii_mesh.ply",
        "ply/plyfile_tet_ascii_face_colors.ply",
        "ply/pcu_truck_binary_le_rgba.ply",
        "ply/armadillo_points_normals_ascii.ply",
        REAL_SPLATS,
    ],
)
def test_real_files_match_plyfile(shared_data, name):
    plyfile = pytest.importorskip("plyfile")
    theirs = plyfile.PlyData.read(str(shared_data / name))
    ours = read_ply(shared_data / name)
    vertex = theirs["vertex"].data
    np.testing.assert_array_equal(ours.points, np.stack([vertex[a] for a in "xyz"], axis=1))
    if "normals" in ours.fields:
        normals = np.stack([vertex[a] for a in ("nx", "ny", "nz")], axis=1)
        np.testing.assert_array_equal(ours.fields["normals"], normals)
    for field in (
        set(vertex.dtype.names) - set("xyz") - {"nx", "ny", "nz", "red", "green", "blue", "alpha"}
    ):
        np.testing.assert_array_equal(ours.fields[field], vertex[field])
    if isinstance(ours, Mesh):
        faces = theirs["face"].data
        np.testing.assert_array_equal(ours.faces, np.stack(faces["vertex_indices"]))
        if "colors" in ours.face_fields:
            np.testing.assert_array_equal(ours.face_fields["colors"][:, 0], faces["red"])


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_real_mesh_round_trips_through_every_encoding(shared_data, tmp_path, encoding):
    mesh = read_ply(shared_data / "ply/trimesh_fuze_binary_le_colors_texcoord.ply")
    write_ply(tmp_path / "fuze.ply", mesh, encoding)
    again = read_ply(tmp_path / "fuze.ply")
    assert_same_cloud(mesh, again)
    assert again.metadata["comments"] == mesh.metadata["comments"]


# --- generated files: round trips --------------------------------------------------------------


@pytest.mark.parametrize("encoding", ENCODINGS)
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_cloud_round_trips_with_dtypes_and_nan(tmp_path, encoding, dtype):
    cloud = sample_cloud(dtype=dtype)
    write_ply(tmp_path / "cloud.ply", cloud, encoding)
    again = read_ply(tmp_path / "cloud.ply")
    assert again.metadata["encoding"] == encoding
    assert_same_cloud(cloud, again)
    assert again.nan_count == 1
    assert all(values.dtype.isnative for values in again.fields.values())


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_extreme_floats_round_trip_exactly(tmp_path, encoding):
    single = np.array(
        [1e-45, 3.4028235e38, -0.0, 0.1, 1 / 3, 16777217, -1.17549435e-38], np.float32
    )
    double = np.array([5e-324, 1.7976931348623157e308, 0.1, 1 / 3, 2**53 + 1, -2.2e-308, 1e22])
    rng = np.random.default_rng(1)
    random_single = rng.normal(size=500).astype(np.float32) * np.float32(10.0) ** rng.integers(
        -30, 30, 500
    )
    cloud = PointCloud(
        np.zeros((507, 3), np.float32),
        {
            "single": np.concatenate([single, random_single]),
            "double": np.concatenate(
                [double, rng.normal(size=500) * 10.0 ** rng.integers(-300, 300, 500)]
            ),
        },
    )
    write_ply(tmp_path / "floats.ply", cloud, encoding)
    assert same_fields(read_ply(tmp_path / "floats.ply").fields, cloud.fields)


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_mesh_round_trips_with_face_fields(tmp_path, encoding):
    mesh = sample_mesh()
    write_ply(tmp_path / "mesh.ply", mesh, encoding)
    again = read_ply(tmp_path / "mesh.ply")
    assert_same_cloud(mesh, again)


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_polygons_of_mixed_sizes_round_trip_as_object_arrays(tmp_path, encoding):
    mesh = polygon_mesh()
    write_ply(tmp_path / "polygons.ply", mesh, encoding)
    again = read_ply(tmp_path / "polygons.ply")
    assert again.faces.dtype == object
    assert [list(face) for face in again.faces] == [list(face) for face in mesh.faces]
    for ours, theirs in zip(again.face_fields["weights"], mesh.face_fields["weights"], strict=True):
        np.testing.assert_array_equal(ours, theirs)
        assert ours.dtype == np.float32


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_other_elements_round_trip_through_metadata(tmp_path, encoding):
    cloud = sample_cloud(count=6)
    edges = {
        "vertex1": np.array([0, 1, 2], np.int32),
        "vertex2": np.array([1, 2, 0], np.int32),
        "crease": np.array([0.5, 1.0, 0.25], np.float64),
    }
    materials = {"ambient": np.array([[1, 2, 3]], np.uint8)}
    cloud.metadata["ply_elements"] = {"edge": edges, "material": materials}
    write_ply(tmp_path / "edges.ply", cloud, encoding)
    again = read_ply(tmp_path / "edges.ply").metadata["ply_elements"]
    assert list(again) == ["edge", "material"]
    assert same_fields(again["edge"], edges)
    assert same_fields(again["material"], materials)


def test_comments_and_obj_info_round_trip(tmp_path):
    cloud = sample_cloud(count=3)
    cloud.metadata.update(comments=["made by a test", "  spaced  "], obj_info=["scanner 7"])
    write_ply(tmp_path / "notes.ply", cloud, "ascii")
    again = read_ply(tmp_path / "notes.ply")
    assert again.metadata["comments"] == ["made by a test", "  spaced  "]
    assert again.metadata["obj_info"] == ["scanner 7"]


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_empty_cloud_round_trips(tmp_path, encoding):
    cloud = PointCloud(np.zeros((0, 3), np.float32), {"intensity": np.zeros(0, np.float32)})
    write_ply(tmp_path / "empty.ply", cloud, encoding)
    assert_same_cloud(cloud, read_ply(tmp_path / "empty.ply"))


def test_fields_are_cast_only_when_no_value_changes(tmp_path):
    count = 4
    cloud = PointCloud(
        np.zeros((count, 3)),
        {"label": np.array([0, -7, 2**31 - 1, 5]), "flag": np.array([True, False, True, True])},
    )
    with pytest.warns(UserWarning, match=r"'label' \(int64\) is written as int32"):
        write_ply(tmp_path / "cast.ply", cloud)
    again = read_ply(tmp_path / "cast.ply")
    assert again.fields["label"].dtype == np.int32
    np.testing.assert_array_equal(again.fields["label"], cloud.fields["label"])
    assert again.fields["flag"].dtype == np.uint8
    np.testing.assert_array_equal(again.fields["flag"], [1, 0, 1, 1])


@pytest.mark.parametrize(
    "fields",
    [
        {"big": np.array([0, 2**60])},
        {"name": np.array(["a", "b"])},
        {"cube": np.zeros((2, 2, 2), np.float32)},
        {"two words": np.zeros(2, np.float32)},
        {"colors": np.zeros((2, 3), np.uint8), "red": np.zeros(2, np.uint8)},
    ],
    ids=["int64-beyond-a-double", "strings", "3-d", "name-with-space", "name-clash"],
)
def test_fields_ply_cannot_hold_are_refused(tmp_path, fields):
    cloud = PointCloud(np.zeros((2, 3), np.float32), fields)
    with pytest.raises(FormatError, match=re.escape(str(tmp_path))):
        write_ply(tmp_path / "refused.ply", cloud)


def test_mesh_whose_faces_index_missing_vertices_is_refused(tmp_path):
    mesh = Mesh(np.zeros((3, 3), np.float32), faces=np.array([[0, 1, 3]]))
    with pytest.raises(FormatError, match="3 vertices"):
        write_ply(tmp_path / "broken.ply", mesh)


def test_ascii_is_written_in_batches_without_seams(tmp_path, monkeypatch):
    monkeypatch.setattr(ply.writer, "TEXT_WRITE_BATCH", 4)
    for name, cloud in {"mesh": sample_mesh(), "polygons": polygon_mesh()}.items():
        write_ply(tmp_path / f"{name}.ply", cloud, "ascii")
        assert_same_cloud(cloud, read_ply(tmp_path / f"{name}.ply"))


def test_organised_shape_is_not_stored_and_says_so(tmp_path):
    cloud = PointCloud(np.zeros((4, 3), np.float32), shape=(2, 2))
    with pytest.warns(UserWarning, match="organised"):
        write_ply(tmp_path / "grid.ply", cloud)


def test_registry_reads_and_writes_ply_with_generic_encoding_names(tmp_path):
    cloud = sample_cloud(count=5)
    pointfield.write(tmp_path / "a.ply", cloud, encoding="binary")
    pointfield.write(tmp_path / "b.ply", cloud, encoding="ascii")
    a, b = pointfield.read(tmp_path / "a.ply"), pointfield.read(tmp_path / "b.ply")
    assert (a.metadata["format"], a.metadata["encoding"]) == ("ply", "binary_little_endian")
    assert (b.metadata["format"], b.metadata["encoding"]) == ("ply", "ascii")
    assert_same_cloud(a, b)


def test_ply_content_is_recognised_behind_a_wrong_suffix(tmp_path):
    cloud = sample_cloud(count=5)
    write_ply(tmp_path / "really_ply.pcd", cloud, "ascii")
    again = pointfield.read(tmp_path / "really_ply.pcd")
    assert again.metadata["format"] == "ply"
    assert_same_cloud(cloud, again)


def test_signature_recognises_ply_with_either_line_ending():
    assert is_ply(b"ply\nformat ascii 1.0\n")
    assert is_ply(b"ply\r\nformat ascii 1.0\r\n")
    assert not is_ply(b"plyx\n")
    assert not is_ply(b"# .PCD v0.7\n")


# --- generated files: header and data variants -------------------------------------------------


def test_crlf_header_before_binary_data(tmp_path):
    points = np.array([[1.5, -2.0, 3.25], [0.0, 1e-3, -7.0]], np.float32)
    header = "\r\n".join(
        [
            "ply",
            "format binary_little_endian 1.0",
            "comment windows",
            "element vertex 2",
            "property float x",
            "property float y",
            "property float z",
            "end_header",
            "",
        ]
    )
    path = write_bytes(tmp_path, header.encode() + points.tobytes())
    cloud = read_ply(path)
    np.testing.assert_array_equal(cloud.points, points)
    assert cloud.metadata["comments"] == ["windows"]


def test_crlf_ascii_file(tmp_path):
    text = (
        "ply\r\nformat ascii 1.0\r\nelement vertex 2\r\nproperty float x\r\nproperty float y\r\n"
        "property float z\r\nelement face 1\r\nproperty list uchar int vertex_indices\r\n"
        "end_header\r\n1 2 3\r\n4 5 6\r\n3 0 1 1\r\n"
    )
    mesh = read_ply(write_bytes(tmp_path, text.encode()))
    np.testing.assert_array_equal(mesh.points, [[1, 2, 3], [4, 5, 6]])
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 1]])


WHITESPACE_VARIANTS = {
    # name: (first line, second line, what follows the last line)
    "single-spaces": ("1 2 3", "4 5 6", "\n"),
    "trailing-space": ("1 2 3 ", "4 5 6 ", "\n"),
    "trailing-space-on-some-lines": ("1 2 3 ", "4 5 6", "\n"),
    "tabs": ("1\t2\t3", "4\t5\t6", "\n"),
    "repeated-spaces": ("  1   2 3", "4 5    6  ", "\n"),
    "crlf": ("1 2 3 \r", "4 5 6 \r", "\n"),
    "no-final-newline": ("1 2 3", "4 5 6", ""),
    "blank-lines-after": ("1 2 3", "4 5 6", "\n\n\n"),
}


@pytest.mark.parametrize("variant", list(WHITESPACE_VARIANTS))
@pytest.mark.parametrize("repeats", [1, 6000], ids=["short", "long"])  # long: parsed by pyarrow
def test_ascii_whitespace_variants_read_the_same(tmp_path, variant, repeats):
    first, second, end = WHITESPACE_VARIANTS[variant]
    header = (
        f"ply\nformat ascii 1.0\nelement vertex {2 * repeats}\nproperty float x\n"
        "property uchar y\nproperty double z\nend_header\n"
    )
    text = header + "\n".join([first, second] * repeats) + end
    cloud = read_ply(write_bytes(tmp_path, text.encode()))
    np.testing.assert_array_equal(cloud.points, np.tile([[1, 2, 3], [4, 5, 6]], (repeats, 1)))
    assert cloud.fields == {}


def test_ascii_faces_of_mixed_sizes(tmp_path):
    text = (
        "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
        "property float z\nelement face 2\nproperty list uchar int vertex_indices\n"
        "property uchar red\nend_header\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2 7\n4 0 1 2 3 9\n"
    )
    mesh = read_ply(write_bytes(tmp_path, text.encode()))
    assert [list(face) for face in mesh.faces] == [[0, 1, 2], [0, 1, 2, 3]]
    np.testing.assert_array_equal(mesh.face_fields["red"], [7, 9])


def test_vertex_list_property_of_fixed_length_is_an_n_by_k_field(tmp_path):
    text = (
        "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
        "property float z\nproperty list uchar float descriptor\nend_header\n"
        "0 0 0 3 1 2 3 \n1 1 1 3 4 5 6 \n"
    )
    cloud = read_ply(write_bytes(tmp_path, text.encode()))
    np.testing.assert_array_equal(cloud.fields["descriptor"], [[1, 2, 3], [4, 5, 6]])
    assert cloud.fields["descriptor"].dtype == np.float32


def test_big_endian_written_by_plyfile_reads_the_same_values(tmp_path):
    plyfile = pytest.importorskip("plyfile")
    vertex = np.array(
        [(1.5, -2.25, 1e30, 200, 40000), (0.1, 7.0, -3.0, 1, 2)],
        dtype=[("x", "f4"), ("y", "f4"), ("z", "f8"), ("red", "u1"), ("value", "u2")],
    )
    # Faces hold only their list: plyfile writes scalars beside a list in native byte order
    # even in a big-endian file (and reads them back the same wrong way).
    face = np.empty(2, dtype=[("vertex_indices", "O")])
    face["vertex_indices"] = [np.array([0, 1, 1], "i4"), np.array([1, 0, 0, 1], "i4")]
    plyfile.PlyData(
        [
            plyfile.PlyElement.describe(vertex, "vertex"),
            plyfile.PlyElement.describe(
                face, "face", len_types={"vertex_indices": "u1"}, val_types={"vertex_indices": "i4"}
            ),
        ],
        byte_order=">",
    ).write(str(tmp_path / "big.ply"))
    mesh = read_ply(tmp_path / "big.ply")
    assert mesh.metadata["encoding"] == "binary_big_endian"
    assert mesh.points.dtype == np.float64  # float32 x, y with float64 z: the common type
    np.testing.assert_array_equal(mesh.points[:, 2], vertex["z"])
    np.testing.assert_array_equal(mesh.fields["value"], vertex["value"])
    assert mesh.fields["value"].dtype.isnative
    assert [list(f) for f in mesh.faces] == [[0, 1, 1], [1, 0, 0, 1]]


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_files_we_write_read_the_same_in_plyfile(tmp_path, encoding):
    plyfile = pytest.importorskip("plyfile")
    mesh = sample_mesh()
    write_ply(tmp_path / "ours.ply", mesh, encoding)
    theirs = plyfile.PlyData.read(str(tmp_path / "ours.ply"))
    vertex = theirs["vertex"].data
    np.testing.assert_array_equal(np.stack([vertex[a] for a in "xyz"], axis=1), mesh.points)
    np.testing.assert_array_equal(vertex["alpha"], mesh.fields["colors"][:, 3])
    np.testing.assert_array_equal(vertex["quality"], mesh.fields["quality"])
    faces = theirs["face"].data
    np.testing.assert_array_equal(np.stack(faces["vertex_indices"]), mesh.faces)
    np.testing.assert_array_equal(np.stack(faces["texcoord"]), mesh.face_fields["texcoord"])
    np.testing.assert_array_equal(faces["weight"], mesh.face_fields["weight"])


# --- hostile files -----------------------------------------------------------------------------

ASCII_HEADER = (
    "ply\nformat ascii 1.0\nelement vertex {count}\n"
    "property float x\nproperty float y\nproperty float z\n"
)
BINARY_HEADER = ASCII_HEADER.replace("ascii", "binary_little_endian")
MESH_HEADER = (
    "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
    "property float z\nelement face 1\nproperty list {count_type} int vertex_indices\nend_header\n"
)
THREE_VERTICES = np.zeros((3, 3), np.float32).tobytes()


def hostile_files() -> dict[str, bytes]:
    rng = np.random.default_rng(7)
    valid_binary = BINARY_HEADER.format(count=4).encode() + b"end_header\n" + bytes(48)
    return {
        "empty": b"",
        "not-ply": b"solid cube\nfacet normal 0 0 1\n",
        "header-only-ascii": (ASCII_HEADER.format(count=10) + "end_header\n").encode(),
        "header-only-binary": (BINARY_HEADER.format(count=10) + "end_header\n").encode(),
        "truncated-binary": valid_binary[:-5],
        "truncated-ascii": (ASCII_HEADER.format(count=3) + "end_header\n1 2 3\n4 5 6\n").encode(),
        "trillion-vertices-binary": BINARY_HEADER.format(count=10**12).encode()
        + b"end_header\n"
        + bytes(1000),
        "trillion-vertices-ascii": (
            ASCII_HEADER.format(count=10**12) + "end_header\n" + "1 2 3\n" * 150
        ).encode(),
        "negative-count": (ASCII_HEADER.format(count=-5) + "end_header\n").encode(),
        "bad-type": ASCII_HEADER.format(count=1).replace("float y", "floot y").encode()
        + b"end_header\n1 2 3\n",
        "random-bytes-after-magic": b"ply\n" + rng.integers(0, 256, 1000, dtype=np.uint8).tobytes(),
        "no-end-header": ASCII_HEADER.format(count=1).encode(),
        "header-over-1-MiB": b"ply\nformat ascii 1.0\n"
        + b"comment padding padding padding\n" * 40000,
        "unknown-encoding": b"ply\nformat binary_middle_endian 1.0\nend_header\n",
        "no-format-line": b"ply\nelement vertex 0\nproperty float x\nend_header\n",
        "unknown-keyword": b"ply\nformat ascii 1.0\nvertices 3\nend_header\n",
        "property-before-element": b"ply\nformat ascii 1.0\nproperty float x\nend_header\n",
        "float-list-count": MESH_HEADER.format(count_type="float").encode() + THREE_VERTICES,
        "records-without-properties": b"ply\nformat ascii 1.0\nelement vertex 2\nend_header\n\n\n",
        "negative-list-length": MESH_HEADER.format(count_type="char").encode()
        + THREE_VERTICES
        + b"\xff",
        "huge-list-length": MESH_HEADER.format(count_type="uint").encode()
        + THREE_VERTICES
        + b"\xff\xff\xff\xff"
        + bytes(12),
        "vertex-index-out-of-range": MESH_HEADER.format(count_type="uchar").encode()
        + THREE_VERTICES
        + b"\x03"
        + np.array([0, 1, 3], "<i4").tobytes(),
        "negative-vertex-index": MESH_HEADER.format(count_type="uchar").encode()
        + THREE_VERTICES
        + b"\x03"
        + np.array([0, -1, 2], "<i4").tobytes(),
        "not-a-number": (ASCII_HEADER.format(count=2) + "end_header\n1 2 3\n4 five 6\n").encode(),
        "too-few-values": (ASCII_HEADER.format(count=2) + "end_header\n1 2 3\n4 5\n").encode(),
        "value-out-of-type-range": b"ply\nformat ascii 1.0\nelement vertex 1\nproperty uchar x\n"
        b"property float y\nproperty float z\nend_header\n300 1 2\n",
        "fractional-list-length": b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n"
        b"property float y\nproperty float z\nproperty list uchar float f\nend_header\n"
        b"1 2 3 1.5 1\n",
        "list-coordinate": b"ply\nformat ascii 1.0\nelement vertex 1\nproperty list uchar float x\n"
        b"property float y\nproperty float z\nend_header\n1 0 2 3\n",
        "no-vertex-element": b"ply\nformat ascii 1.0\nelement edge 1\nproperty int a\n"
        b"end_header\n1\n",
        "huge-ascii-list-length": (
            MESH_HEADER.replace("binary_little_endian", "ascii").format(count_type="uint")
            + "0 0 0\n1 1 1\n2 2 2\n4000000000 0 1 2\n"
        ).encode(),
        "blank-lines-for-records": (ASCII_HEADER.format(count=3) + "end_header\n\n\n\n").encode(),
        "duplicate-element": b"ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\n"
        b"element vertex 0\nproperty float x\nend_header\n",
    }


@pytest.mark.parametrize("name", list(hostile_files()))
def test_hostile_file_raises_format_error_naming_the_file(tmp_path, name):
    path = write_bytes(tmp_path, hostile_files()[name], f"{name}.ply")
    with pytest.raises(FormatError, match=re.escape(str(path))):
        read_ply(path)


def mutate(data: bytes, rng: np.random.Generator) -> bytes:
    """One to three random edits: bit flips, truncation, deleted or inserted bytes, or a header
    number swapped for a hostile one."""
    out = bytearray(data)
    for _ in range(int(rng.integers(1, 4))):
        at = int(rng.integers(0, max(len(out), 1)))
        edit = int(rng.integers(0, 5))
        if edit == 0 and out:
            out[at] ^= 1 << int(rng.integers(0, 8))
        elif edit == 1:
            del out[at:]
        elif edit == 2:
            del out[at : at + int(rng.integers(1, 8))]
        elif edit == 3:
            out[at:at] = rng.integers(0, 256, int(rng.integers(1, 8)), dtype=np.uint8).tobytes()
        else:
            header_end = max(out.find(b"end_header"), 0)
            digits = [i for i in range(header_end) if chr(out[i]).isdigit()]
            if digits:
                i = digits[int(rng.integers(0, len(digits)))]
                out[i : i + 1] = str(rng.choice([0, 7, 99999, 10**12, -1])).encode()
    return bytes(out)


def test_mutated_files_read_or_raise_format_error(tmp_path):
    seeds = []
    for index, cloud in enumerate([sample_mesh(), polygon_mesh(), sample_cloud(count=8)]):
        for encoding in ENCODINGS:
            path = tmp_path / f"seed{index}_{encoding}.ply"
            write_ply(path, cloud, encoding)
            seeds.append(path.read_bytes())
    rng = np.random.default_rng(2024)
    path = tmp_path / "mutant.ply"
    outcomes = {"read": 0, "refused": 0}
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # numpy warnings would mean an unchecked value slipped by
        for trial in range(900):
            path.write_bytes(mutate(seeds[trial % len(seeds)], rng))
            try:
                read_ply(path)
                outcomes["read"] += 1
            except FormatError as error:
                assert str(path) in str(error)
                outcomes["refused"] += 1
    assert outcomes["read"] > 0 and outcomes["refused"] > 0
