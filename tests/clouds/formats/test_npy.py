"""NPY and NPZ: plain and structured arrays, archives, lossless round trips, hostile files."""

from __future__ import annotations

import io
import struct
import warnings
import zipfile

import numpy as np
import pytest

import pointfield
from pointfield import FormatError, Mesh, PointCloud, Records
from pointfield.clouds.cloud import same_fields


def read_quietly(path, **options):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return pointfield.read(path, **options)


def save(tmp_path, name, array):
    path = tmp_path / name
    np.save(path, array, allow_pickle=False)
    return path


def npy_bytes(array):
    buffer = io.BytesIO()
    np.save(buffer, array, allow_pickle=True)
    return buffer.getvalue()


def rich_cloud(n=40, shape=None):
    rng = np.random.default_rng(11)
    points = rng.normal(size=(n, 3)).astype(np.float64)
    points[2] = np.nan
    return PointCloud(
        points,
        {
            "colors": rng.integers(0, 256, (n, 4), dtype=np.uint8),
            "normals": rng.normal(size=(n, 3)).astype(np.float32),
            "intensity": rng.integers(0, 65535, n).astype(np.uint16),
            "label": rng.integers(-3, 3, n).astype(np.int8),
            "valid": rng.random(n) > 0.5,
            "descriptor": rng.random((n, 8)).astype(np.float16),
        },
        shape,
        {"sensor": "test", "viewpoint": [0, 0, 0, 1, 0, 0, 0]},
    )


# ---------------------------------------------------------------------------------------------
# .npy reading


def test_a_plain_float32_array_keeps_its_dtype(tmp_path):
    points = np.arange(12, dtype=np.float32).reshape(4, 3)
    cloud = read_quietly(save(tmp_path, "plain.npy", points))
    assert cloud.points.dtype == np.float32 and cloud.fields == {}
    np.testing.assert_array_equal(cloud.points, points)
    assert cloud.metadata == {"format": "npy", "encoding": "binary"}


def test_extra_columns_of_a_plain_array_are_features(tmp_path):
    array = np.arange(20, dtype=np.float64).reshape(4, 5)
    cloud = read_quietly(save(tmp_path, "wide.npy", array))
    np.testing.assert_array_equal(cloud.points, array[:, :3])
    np.testing.assert_array_equal(cloud.fields["features"], array[:, 3:])


def test_integer_coordinates_become_float64_points(tmp_path):
    cloud = read_quietly(save(tmp_path, "ints.npy", np.ones((2, 3), np.int32)))
    assert cloud.points.dtype == np.float64


def test_an_h_w_3_array_is_an_organised_cloud(tmp_path):
    cloud = read_quietly(save(tmp_path, "grid.npy", np.zeros((4, 5, 3), np.float32)))
    assert cloud.shape == (4, 5) and len(cloud) == 20


def test_a_fortran_ordered_big_endian_array_reads_in_native_order(tmp_path):
    array = np.asfortranarray(np.arange(12, dtype=">f8").reshape(4, 3))
    cloud = read_quietly(save(tmp_path, "fortran.npy", array))
    np.testing.assert_array_equal(cloud.points, array)
    assert cloud.points.dtype == np.float64 and cloud.points.dtype.isnative


def test_a_structured_array_groups_named_fields(tmp_path):
    xyz = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    rgb = [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    normals = [("nx", ">f4"), ("ny", ">f4"), ("nz", ">f4")]
    dtype = xyz + rgb + normals + [("label", "<i4"), ("hist", "<f4", (5,))]
    array = np.zeros(3, dtype)
    array["red"] = [1, 2, 3]
    array["hist"][1] = 7
    cloud = read_quietly(save(tmp_path, "struct.npy", array))
    assert cloud.points.dtype == np.float32
    assert {k: (v.dtype.str, v.shape) for k, v in cloud.fields.items()} == {
        "colors": ("|u1", (3, 3)),
        "normals": ("<f4", (3, 3)),
        "label": ("<i4", (3,)),
        "hist": ("<f4", (3, 5)),
    }
    np.testing.assert_array_equal(cloud.fields["colors"][:, 0], [1, 2, 3])
    np.testing.assert_array_equal(cloud.fields["hist"][1], [7] * 5)


def test_a_structured_array_with_an_xyz_subarray_takes_its_points_from_it(tmp_path):
    array = np.zeros(2, [("xyz", "<f8", (3,)), ("intensity", "<f4")])
    array["xyz"] = [[1, 2, 3], [4, 5, 6]]
    cloud = read_quietly(save(tmp_path, "xyz.npy", array))
    np.testing.assert_array_equal(cloud.points, [[1, 2, 3], [4, 5, 6]])
    assert set(cloud.fields) == {"intensity"}


def test_a_structured_array_without_coordinates_reads_as_records(tmp_path):
    array = np.zeros(5, [("descriptor", "u1", (64,)), ("scale", "<f4")])
    records = read_quietly(save(tmp_path, "records.npy", array))
    assert isinstance(records, Records) and len(records) == 5
    assert records.fields["descriptor"].shape == (5, 64)


def test_npy_content_under_another_suffix_still_reads(tmp_path):
    path = tmp_path / "cloud.xyz"
    path.write_bytes(npy_bytes(np.zeros((2, 3), np.float32)))
    assert read_quietly(path).metadata["format"] == "npy"


# ---------------------------------------------------------------------------------------------
# .npy round trips


@pytest.mark.parametrize("shape", [None, (5, 8)], ids=["unorganised", "organised"])
def test_npy_round_trips_every_name_dtype_and_bit(tmp_path, shape):
    cloud = rich_cloud(shape=shape)
    pointfield.write(tmp_path / "rich.npy", cloud)
    back = read_quietly(tmp_path / "rich.npy")
    assert back.points.dtype == cloud.points.dtype
    np.testing.assert_array_equal(back.points, cloud.points)
    assert same_fields(back.fields, cloud.fields)
    assert back.shape == shape


def test_records_round_trip_through_npy(tmp_path):
    records = Records({"descriptor": np.arange(20, dtype=np.uint8).reshape(4, 5)})
    pointfield.write(tmp_path / "records.npy", records)
    back = read_quietly(tmp_path / "records.npy")
    assert isinstance(back, Records) and same_fields(back.fields, records.fields)


def test_writing_a_mesh_to_npy_warns_that_faces_are_left_out(tmp_path):
    mesh = Mesh(np.zeros((3, 3)), faces=np.array([[0, 1, 2]]))
    with pytest.warns(UserWarning, match="1 faces were not written"):
        pointfield.write(tmp_path / "mesh.npy", mesh)


# ---------------------------------------------------------------------------------------------
# .npz


@pytest.mark.parametrize("encoding", ["stored", "deflated", "compressed", None])
@pytest.mark.parametrize("shape", [None, (8, 5)], ids=["unorganised", "organised"])
def test_npz_round_trips_fields_dtypes_shape_and_metadata(tmp_path, encoding, shape):
    cloud = rich_cloud(shape=shape)
    pointfield.write(tmp_path / "rich.npz", cloud, encoding=encoding)
    back = read_quietly(tmp_path / "rich.npz")
    np.testing.assert_array_equal(back.points, cloud.points)
    assert back.points.dtype == cloud.points.dtype
    assert same_fields(back.fields, cloud.fields)
    assert back.shape == shape
    assert back.metadata["sensor"] == "test"
    assert back.metadata["viewpoint"] == [0, 0, 0, 1, 0, 0, 0]
    assert back.metadata["encoding"] == ("stored" if encoding in (None, "stored") else "deflated")


def test_npz_written_by_numpy_reads_with_any_points_key(tmp_path):
    np.savez(tmp_path / "a.npz", xyz=np.ones((3, 3)), label=np.arange(3), scale=np.float64(2))
    with pytest.warns(UserWarning, match="'scale'"):
        cloud = pointfield.read(tmp_path / "a.npz")
    assert len(cloud) == 3 and set(cloud.fields) == {"label"}


def test_npz_with_separate_x_y_z_members(tmp_path):
    channel = np.zeros(4, np.uint8)
    axis = np.ones(4)
    np.savez(
        tmp_path / "cols.npz", x=axis, y=axis, z=axis, red=channel, green=channel, blue=channel
    )
    cloud = read_quietly(tmp_path / "cols.npz")
    assert len(cloud) == 4 and cloud.fields["colors"].shape == (4, 3)


def test_a_real_gsplat_npz_reads_with_points_named(shared_data):
    path = shared_data / "gaussians" / "gsplat_test_garden.npz"
    with pytest.warns(UserWarning, match="'Ks', 'height', 'viewmats', 'width'"):
        cloud = pointfield.read(path, points="means3d")
    assert cloud.points.shape == (138766, 3) and cloud.points.dtype == np.float32
    assert cloud.fields["colors"].dtype == np.uint8 and cloud.fields["colors"].shape == (138766, 3)
    with pytest.raises(FormatError, match="means3d"):
        pointfield.read(path)


def test_unserialisable_metadata_is_left_out_with_a_warning(tmp_path):
    cloud = PointCloud(np.zeros((1, 3)), metadata={"callback": print})
    with pytest.warns(UserWarning, match="not JSON-serialisable"):
        pointfield.write(tmp_path / "meta.npz", cloud)
    assert "callback" not in read_quietly(tmp_path / "meta.npz").metadata


# ---------------------------------------------------------------------------------------------
# Hostile input: each is a FormatError naming the file


def npy_with_header(header: str, data: bytes = b"", version: int = 1) -> bytes:
    text = header.encode("latin-1")
    size = struct.pack("<H", len(text)) if version == 1 else struct.pack("<I", len(text))
    return b"\x93NUMPY" + bytes([version, 0]) + size + text + data


VALID = npy_bytes(np.arange(30, dtype=np.float32).reshape(10, 3))

HOSTILE_NPY = {
    "empty": b"",
    "magic only": b"\x93NUMPY",
    "truncated data": VALID[:-5],
    "truncated header": VALID[:40],
    "huge declared shape": npy_with_header(
        "{'descr': '<f8', 'fortran_order': False, 'shape': (1000000000000, 3)}"
    ),
    "negative shape": npy_with_header("{'descr': '<f8', 'fortran_order': False, 'shape': (-1, 3)}"),
    "shape not a tuple": npy_with_header(
        "{'descr': '<f8', 'fortran_order': False, 'shape': 'big'}"
    ),
    "header not a dict": npy_with_header("[1, 2, 3]"),
    "header is code": npy_with_header("__import__('os').system('true')"),
    "unknown dtype": npy_with_header("{'descr': '<q9', 'fortran_order': False, 'shape': (1, 3)}"),
    "bad fortran flag": npy_with_header(
        "{'descr': '<f8', 'fortran_order': 'yes', 'shape': (1, 3)}"
    ),
    "extra header key": npy_with_header(
        "{'descr': '<f8', 'fortran_order': False, 'shape': (1, 3), 'x': 1}"
    ),
    "unknown version": npy_with_header("{}", version=7),
    "huge header length": b"\x93NUMPY\x02\x00" + struct.pack("<I", 2**31) + b"{",
    "nested brackets": npy_with_header("(" * 100_000, version=2),
    "pickled objects": npy_bytes(np.array([[1, "a", None]], dtype=object)),
    "one dimension": npy_bytes(np.zeros(9, np.float32)),
    "two columns": npy_bytes(np.zeros((4, 2), np.float32)),
    "complex numbers": npy_bytes(np.zeros((4, 3), np.complex64)),
    "strings": npy_bytes(np.array([["a", "b", "c"]])),
    "random bytes": b"\x93NUMPY\x01\x00"
    + bytes(np.random.default_rng(2).integers(0, 256, 300, dtype=np.uint8)),
}


@pytest.mark.parametrize("data", HOSTILE_NPY.values(), ids=HOSTILE_NPY.keys())
def test_hostile_npy_is_a_format_error_naming_the_file(tmp_path, data):
    path = tmp_path / "hostile.npy"
    path.write_bytes(data)
    with pytest.raises(FormatError) as error:
        pointfield.read(path)
    assert str(path) in str(error.value)


def zip_bytes(members: dict[str, bytes], compression=zipfile.ZIP_STORED) -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", compression) as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    return buffer.getvalue()


def with_lying_size(archive: bytes, size: int) -> bytes:
    """The archive with its one member's uncompressed size patched in both headers."""
    patched = bytearray(archive)
    local = patched.index(b"PK\x03\x04")
    patched[local + 22 : local + 26] = struct.pack("<I", size)
    central = patched.index(b"PK\x01\x02")
    patched[central + 24 : central + 28] = struct.pack("<I", size)
    return bytes(patched)


def corrupt_member(archive: bytes) -> bytes:
    """The archive with the first bytes of its one member's compressed data overwritten."""
    data_start = 30 + len("points.npy")
    return archive[:data_start] + b"\xff" * 8 + archive[data_start + 8 :]


POINTS = npy_bytes(np.zeros((4, 3), np.float32))

HOSTILE_NPZ = {
    "empty": b"",
    "zip magic then garbage": b"PK\x03\x04" + bytes(range(256)) * 4,
    "truncated archive": zip_bytes({"points.npy": POINTS})[:-30],
    "no points member": zip_bytes({"colors.npy": POINTS}),
    "points member is not an array": zip_bytes({"points.npy": b"hello"}),
    "points member truncated": zip_bytes({"points.npy": POINTS[:-8]}),
    "points member pickled": zip_bytes({"points.npy": npy_bytes(np.array([[None] * 3], object))}),
    "field member pickled": zip_bytes(
        {"points.npy": POINTS, "tag.npy": npy_bytes(np.array([None] * 4))}
    ),
    "points member of the wrong shape": zip_bytes({"points.npy": npy_bytes(np.zeros(4))}),
    "member claims a huge size": with_lying_size(zip_bytes({"points.npy": POINTS}), 2**31),
    "huge declared shape in a member": zip_bytes(
        {
            "points.npy": npy_with_header(
                "{'descr': '<f8', 'fortran_order': False, 'shape': (1000000000000, 3)}"
            )
        }
    ),
    "metadata not JSON": zip_bytes(
        {"points.npy": POINTS, "__metadata__.npy": npy_bytes(np.array("{oops"))}
    ),
    "metadata not an object": zip_bytes(
        {"points.npy": POINTS, "__metadata__.npy": npy_bytes(np.array("[1]"))}
    ),
    "corrupt deflate stream": corrupt_member(
        zip_bytes({"points.npy": POINTS}, zipfile.ZIP_DEFLATED)
    ),
}


@pytest.mark.parametrize("data", HOSTILE_NPZ.values(), ids=HOSTILE_NPZ.keys())
def test_hostile_npz_is_a_format_error_naming_the_file(tmp_path, data):
    path = tmp_path / "hostile.npz"
    path.write_bytes(data)
    with pytest.raises(FormatError) as error:
        pointfield.read(path)
    assert str(path) in str(error.value)
