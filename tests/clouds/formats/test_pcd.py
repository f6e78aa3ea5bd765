"""PCD: real PCL files, round trips in every encoding, and hostile inputs."""

from __future__ import annotations

import re
import struct
import warnings

import lzf
import numpy as np
import pytest

import pointfield
from pointfield import FormatError, Mesh, PointCloud, Records
from pointfield.clouds.cloud import same_fields
from pointfield.clouds.formats.pcd import MAX_HEADER_BYTES, looks_like_pcd

ENCODINGS = ("binary", "binary_compressed", "ascii")

# name -> points (NaN points included), as ../shared/data/MANIFEST.md gives them.
MANIFEST_COUNTS = {
    "pcl_bunny_ascii.pcd": 397,
    "pcl_bun0_ascii_normals.pcd": 397,
    "pcl_curve_close_binary.pcd": 110,
    "pcl_office1_keypoints_binary.pcd": 1318,
    "pcl_colored_cloud_binary.pcd": 1000,
    "pcl_milk_binary_compressed.pcd": 13704,
    "pcl_milk_color_binary_compressed.pcd": 13704,
    "pcl_logo_binary_compressed.pcd": 12909,
    "pcl_cturtle_binary_compressed.pcd": 167198,
    "pcl_table_scene_mug_organized.pcd": 307200,
    "pcl_brisk_descriptors_count64.pcd": 1534,
    "pdal_utm17_space_ascii.pcd": 10,
}

HEADER_07 = [
    "VERSION 0.7",
    "FIELDS x y z",
    "SIZE 4 4 4",
    "TYPE F F F",
    "COUNT 1 1 1",
    "WIDTH 2",
    "HEIGHT 1",
    "VIEWPOINT 0 0 0 1 0 0 0",
    "POINTS 2",
]


def write_pcd_file(path, header_lines, data=b""):
    path.write_bytes(("\n".join(header_lines) + "\n").encode() + data)
    return path


def with_line(keyword, replacement, lines=HEADER_07):
    """``lines`` with the line starting with ``keyword`` replaced (or removed when None)."""
    out = []
    for line in lines:
        if line.split()[0] == keyword:
            if replacement is not None:
                out.append(replacement)
        else:
            out.append(line)
    return out


def bits(a):
    """Floats as their raw bits, so NaN compares equal to NaN and payloads count."""
    a = np.ascontiguousarray(a)
    return a.view(f"u{a.dtype.itemsize}") if a.dtype.kind == "f" else a


# ----------------------------------------------------------------------------------------------
# Real files


@pytest.mark.parametrize("name", sorted(MANIFEST_COUNTS))
def test_every_shared_pcd_file_reads_with_its_manifest_count(shared_data, name):
    cloud = pointfield.read(shared_data / "pcd" / name)
    assert len(cloud) == MANIFEST_COUNTS[name]
    assert cloud.metadata["format"] == "pcd"
    assert cloud.metadata["encoding"] in ENCODINGS


def test_every_shared_pcd_file_is_in_the_table(shared_data):
    assert {p.name for p in (shared_data / "pcd").glob("*.pcd")} == set(MANIFEST_COUNTS)


def test_organised_cloud_keeps_its_grid_and_nan_points(shared_data):
    cloud = pointfield.read(shared_data / "pcd" / "pcl_table_scene_mug_organized.pcd")
    assert cloud.shape == (480, 640)
    assert len(cloud) == 307200
    assert cloud.nan_count == 97920
    assert cloud.fields["colors"].shape == (307200, 4)
    assert cloud.fields["colors"].dtype == np.uint8
    assert cloud.metadata["viewpoint"] == (0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0)


def test_width_1_height_1000_file_is_organised_as_a_column(shared_data):
    cloud = pointfield.read(shared_data / "pcd" / "pcl_colored_cloud_binary.pcd")
    assert cloud.shape == (1000, 1)
    assert set(cloud.fields) == {"colors", "normals", "curvature"}


def test_descriptor_file_without_xyz_reads_as_records(shared_data):
    records = pointfield.read(shared_data / "pcd" / "pcl_brisk_descriptors_count64.pcd")
    assert isinstance(records, Records)
    assert len(records) == 1534
    assert records.fields["brisk_descriptor512"].shape == (1534, 64)
    assert records.fields["brisk_descriptor512"].dtype == np.uint8
    assert records.fields["brisk_scale"].dtype == np.float32


def test_old_v5_header_reads(shared_data):
    cloud = pointfield.read(shared_data / "pcd" / "pcl_bunny_ascii.pcd")
    assert cloud.metadata["version"] == ".5"
    assert cloud.points.dtype == np.float32
    np.testing.assert_array_equal(cloud.points[0], np.float32([0.0054216, 0.11349, 0.040749]))


def test_upper_case_xyz_are_points_in_file_precision(shared_data):
    cloud = pointfield.read(shared_data / "pcd" / "pdal_utm17_space_ascii.pcd")
    assert cloud.fields == {}
    assert cloud.points.dtype == np.float32
    np.testing.assert_array_equal(cloud.points[0], np.float32([289814.15, 4320978.61, 170.76]))


@pytest.mark.parametrize(
    ("name", "components"),
    [
        ("pcl_colored_cloud_binary.pcd", 3),
        ("pcl_milk_color_binary_compressed.pcd", 4),
        ("pcl_table_scene_mug_organized.pcd", 4),
    ],
)
def test_packed_colours_of_scans_decode_to_uint8_rgb_or_rgba(shared_data, name, components):
    cloud = pointfield.read(shared_data / "pcd" / name)
    colors = cloud.fields["colors"]
    assert colors.dtype == np.uint8 and colors.shape == (len(cloud), components)
    valid = colors[~np.isnan(cloud.points).any(axis=1)]
    # Scans of real objects: many distinct colours, neither all black nor all white.
    assert len(np.unique(valid[:, :3], axis=0)) > 200
    assert 40 < valid[:, :3].mean() < 215
    if components == 4:
        assert (valid[:, 3] == 255).all()  # PCL writes opaque points


def test_float_packed_rgb_decodes_the_pcl_logos_grey_and_green(shared_data):
    cloud = pointfield.read(shared_data / "pcd" / "pcl_logo_binary_compressed.pcd")
    colors = cloud.fields["colors"]
    assert colors.shape == (12909, 3)
    np.testing.assert_array_equal(np.unique(colors, axis=0), [[128, 128, 128], [146, 186, 100]])


def test_colours_are_pcls_0xAARRGGBB_word(shared_data):
    # The first point of milk_color is 0xff675a55: alpha ff, red 67, green 5a, blue 55.
    cloud = pointfield.read(shared_data / "pcd" / "pcl_milk_color_binary_compressed.pcd")
    np.testing.assert_array_equal(cloud.fields["colors"][0], [0x67, 0x5A, 0x55, 0xFF])


@pytest.mark.parametrize(
    "name", sorted(set(MANIFEST_COUNTS) - {"pcl_bunny_ascii.pcd"})  # pypcd4 rejects VERSION .5
)
def test_values_match_pypcd4(shared_data, name):
    pypcd4 = pytest.importorskip("pypcd4", reason="pypcd4 is the cross-check peer")
    path = shared_data / "pcd" / name
    theirs = pypcd4.PointCloud.from_path(path).pc_data
    ours = pointfield.read(path)
    for column in theirs.dtype.names:
        if "__" in column and ours.metadata["encoding"] == "binary_compressed":
            continue  # pypcd4 misorders COUNT > 1 columns there; see the brisk test below
        expected = bits(theirs[column])
        if column == "rgb":  # the unused top byte of an rgb word is not a colour
            expected = expected & 0x00FFFFFF
        assert np.array_equal(bits(_our_column(ours, column)), expected), column


def test_compressed_count_64_descriptors_are_point_major_as_pcl_writes_them(shared_data):
    # PCL's compressed plane of a COUNT K field holds each point's K values together. Read that
    # way, BRISK's 512 bits have their known per-bit biases; read component-major (as pypcd4
    # does), every bit is a mixture and comes out near 50 %.
    records = pointfield.read(shared_data / "pcd" / "pcl_brisk_descriptors_count64.pcd")
    per_bit_mean = np.unpackbits(records.fields["brisk_descriptor512"], axis=1).mean(axis=0)
    assert per_bit_mean.std() > 0.1
    assert per_bit_mean.min() < 0.3 and per_bit_mean.max() > 0.7


def test_compressed_writes_count_k_fields_point_major(tmp_path):
    values = np.arange(6, dtype=np.uint8).reshape(3, 2)
    path = tmp_path / "k.pcd"
    pointfield.write(path, Records({"k": values}), encoding="binary_compressed")
    data_line = b"DATA binary_compressed\n"
    body = path.read_bytes().partition(data_line)[2]
    compressed_size, size = struct.unpack("<II", body[:8])
    assert lzf.decompress(body[8 : 8 + compressed_size], size) == bytes([0, 1, 2, 3, 4, 5])


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_files_written_are_read_by_pypcd4_with_the_same_values(tmp_path, encoding):
    pypcd4 = pytest.importorskip("pypcd4", reason="pypcd4 is the cross-check peer")
    rng = np.random.default_rng(4)
    cloud = PointCloud(
        rng.normal(size=(30, 3)).astype(np.float32),
        {
            "colors": rng.integers(0, 256, (30, 3), dtype=np.uint8),
            "normals": rng.normal(size=(30, 3)).astype(np.float32),
            "intensity": rng.random(30).astype(np.float64),
        },
    )
    path = tmp_path / "ours.pcd"
    pointfield.write(path, cloud, encoding=encoding)
    theirs = pypcd4.PointCloud.from_path(path).pc_data
    for column in theirs.dtype.names:  # rgb compares as its bits whether TYPE F or U
        assert np.array_equal(bits(_our_column(cloud, column)), bits(theirs[column])), column


def _our_column(cloud, name):
    """The values pointfield holds for the file's column ``name`` (pypcd4's spelling)."""
    if name.lower() in ("x", "y", "z"):
        return cloud.points[:, "xyz".index(name.lower())]
    if name.startswith("normal_"):
        return cloud.fields["normals"][:, "xyz".index(name[-1])]
    if name in ("rgb", "rgba"):  # back to the packed word, to compare its bits
        colors = cloud.fields["colors"]
        word = np.zeros((len(colors), 4), np.uint8)
        word[:, :3] = colors[:, 2::-1]
        if name == "rgba":
            word[:, 3] = colors[:, 3]
        return word.view("<u4").reshape(-1)
    base, _, component = name.partition("__")
    values = cloud.fields[base]
    return values[:, int(component)] if component else values


# ----------------------------------------------------------------------------------------------
# Round trips


VIEWPOINT = (1.5, -2.0, 0.25, 0.5, 0.5, 0.5, 0.5)


def full_cloud(dtype, n=50, seed=0):
    rng = np.random.default_rng(seed)
    points = rng.normal(size=(n, 3)).astype(dtype)
    points[[3, 17]] = np.nan
    return PointCloud(
        points,
        {
            "colors": rng.integers(0, 256, (n, 3), dtype=np.uint8),
            "normals": rng.normal(size=(n, 3)).astype(dtype),
            "intensity": rng.random(n).astype(np.float32),
            "fpfh": rng.random((n, 33)).astype(np.float32),
            "label": rng.integers(-30000, 30000, n).astype(np.int16),
            "stamp": rng.integers(0, 2**64, n, dtype=np.uint64),
            "extreme": np.array([np.inf, -np.inf, -0.0, 1e-45, 3.4e38] * (n // 5), np.float32),
        },
        shape=(5, 10),
        metadata={"viewpoint": VIEWPOINT, "comments": ["made by a test"]},
    )


@pytest.mark.parametrize("encoding", ENCODINGS)
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_round_trip_keeps_points_fields_shape_and_viewpoint(tmp_path, encoding, dtype):
    cloud = full_cloud(dtype)
    path = tmp_path / "cloud.pcd"
    pointfield.write(path, cloud, encoding=encoding)
    back = pointfield.read(path)
    assert back.metadata["encoding"] == encoding
    assert back.points.dtype == dtype
    assert np.array_equal(bits(back.points), bits(cloud.points))
    assert same_fields(back.fields, cloud.fields)
    assert back.shape == (5, 10)
    assert back.nan_count == 2
    assert back.metadata["viewpoint"] == VIEWPOINT
    assert back.metadata["comments"] == ["made by a test"]


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_rgba_colours_round_trip_as_a_uint_rgba_field(tmp_path, encoding):
    rng = np.random.default_rng(1)
    colors = rng.integers(0, 256, (64, 4), dtype=np.uint8)
    cloud = PointCloud(np.zeros((64, 3), np.float32), {"colors": colors})
    path = tmp_path / "rgba.pcd"
    pointfield.write(path, cloud, encoding=encoding)
    assert b"FIELDS x y z rgba\nSIZE 4 4 4 4\nTYPE F F F U\n" in path.read_bytes()
    np.testing.assert_array_equal(pointfield.read(path).fields["colors"], colors)


@pytest.mark.parametrize("encoding", ["binary", "binary_compressed"])
def test_rgb_colours_are_written_as_pcls_float_rgb(tmp_path, encoding):
    colors = np.uint8([[255, 128, 1], [0, 0, 0]])
    path = tmp_path / "rgb.pcd"
    cloud = PointCloud(np.zeros((2, 3), np.float32), {"colors": colors})
    pointfield.write(path, cloud, encoding=encoding)
    assert b"FIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F F\n" in path.read_bytes()
    np.testing.assert_array_equal(pointfield.read(path).fields["colors"], colors)


def test_ascii_writes_packed_rgb_as_an_integer_word_so_its_bits_survive(tmp_path):
    # Every byte value in every channel survives the trip through text.
    values = np.arange(256, dtype=np.uint8)
    colors = np.stack([values, values[::-1], np.roll(values, 7)], axis=1)
    cloud = PointCloud(np.zeros((256, 3), np.float32), {"colors": colors})
    path = tmp_path / "rgb.pcd"
    pointfield.write(path, cloud, encoding="ascii")
    assert b"FIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F U\n" in path.read_bytes()
    np.testing.assert_array_equal(pointfield.read(path).fields["colors"], colors)


def test_ascii_float_rgb_is_read_as_the_bits_of_the_float(tmp_path):
    word = np.uint32([0x00FF8001, 0x00102030]).view(np.float32)
    rows = "".join(f"0 0 0 {v:.9g}\n" for v in word).encode()
    lines = with_line("FIELDS", "FIELDS x y z rgb", with_line("SIZE", "SIZE 4 4 4 4"))
    lines = with_line("TYPE", "TYPE F F F F", with_line("COUNT", "COUNT 1 1 1 1", lines))
    path = write_pcd_file(tmp_path / "f.pcd", [*lines, "DATA ascii"], rows)
    colors = pointfield.read(path).fields["colors"]
    np.testing.assert_array_equal(colors, [[255, 128, 1], [16, 32, 48]])


def test_ascii_float_rgb_written_as_integers_by_pcl_is_read_as_the_word(tmp_path):
    lines = with_line("FIELDS", "FIELDS x y z rgb", with_line("SIZE", "SIZE 4 4 4 4"))
    lines = with_line("TYPE", "TYPE F F F F", with_line("COUNT", "COUNT 1 1 1 1", lines))
    path = write_pcd_file(
        tmp_path / "f.pcd", [*lines, "DATA ascii"], b"0 0 0 4294934529\n0 0 0 1056816\n"
    )
    colors = pointfield.read(path).fields["colors"]
    np.testing.assert_array_equal(colors, [[255, 128, 1], [16, 32, 48]])


@pytest.mark.parametrize("encoding", ["binary", "binary_compressed"])
def test_binary_encodings_keep_nan_payload_bits(tmp_path, encoding):
    payloads = np.uint32([0x7FC00001, 0xFFC0BEEF, 0x7F800001]).view(np.float32)
    path = tmp_path / "nan.pcd"
    cloud = PointCloud(np.zeros((3, 3), np.float32), {"tag": payloads})
    pointfield.write(path, cloud, encoding=encoding)
    assert np.array_equal(bits(pointfield.read(path).fields["tag"]), bits(payloads))


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_non_uint8_colours_round_trip_as_red_green_blue_fields(tmp_path, encoding):
    colors = np.uint16([[0, 1000, 65535], [7, 8, 9]])
    path = tmp_path / "c16.pcd"
    pointfield.write(path, PointCloud(np.zeros((2, 3)), {"colors": colors}), encoding=encoding)
    assert b"FIELDS x y z red green blue\n" in path.read_bytes()
    back = pointfield.read(path)
    assert back.fields["colors"].dtype == np.uint16
    np.testing.assert_array_equal(back.fields["colors"], colors)


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_records_round_trip(tmp_path, encoding):
    rng = np.random.default_rng(2)
    records = Records(
        {
            "scale": rng.random(20).astype(np.float32),
            "descriptor": rng.integers(0, 256, (20, 64), dtype=np.uint8),
        }
    )
    path = tmp_path / "records.pcd"
    pointfield.write(path, records, encoding=encoding)
    back = pointfield.read(path)
    assert isinstance(back, Records)
    assert same_fields(back.fields, records.fields)


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_float16_field_round_trips_as_type_f_size_2(tmp_path, encoding):
    half = np.float16([0.1, 65504, np.nan, -6e-8])
    path = tmp_path / "half.pcd"
    cloud = PointCloud(np.zeros((4, 3), np.float32), {"half": half})
    pointfield.write(path, cloud, encoding=encoding)
    back = pointfield.read(path).fields["half"]
    assert back.dtype == np.float16
    np.testing.assert_array_equal(back, half)


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_empty_cloud_round_trips(tmp_path, encoding):
    path = tmp_path / "empty.pcd"
    pointfield.write(path, PointCloud(np.zeros((0, 3), np.float64)), encoding=encoding)
    back = pointfield.read(path)
    assert len(back) == 0 and back.points.dtype == np.float64


def test_compressed_is_an_alias_of_binary_compressed(tmp_path):
    path = tmp_path / "c.pcd"
    pointfield.write(path, full_cloud(np.float32), encoding="compressed")
    assert pointfield.read(path).metadata["encoding"] == "binary_compressed"


def test_binary_is_the_default_encoding(tmp_path):
    path = tmp_path / "c.pcd"
    pointfield.write(path, full_cloud(np.float32))
    assert pointfield.read(path).metadata["encoding"] == "binary"


def test_mesh_faces_are_left_out_with_a_warning(tmp_path):
    mesh = Mesh(np.eye(3, dtype=np.float32), faces=np.array([[0, 1, 2]]))
    with pytest.warns(UserWarning, match="faces"):
        pointfield.write(tmp_path / "m.pcd", mesh)
    assert len(pointfield.read(tmp_path / "m.pcd")) == 3


def test_fields_pcd_cannot_hold_are_left_out_with_a_warning_naming_them(tmp_path):
    cloud = PointCloud(
        np.zeros((2, 3), np.float32),
        {"name": np.array(["a", "b"]), "cube": np.zeros((2, 2, 2)), "kept": np.ones(2)},
    )
    with pytest.warns(UserWarning, match="'name', 'cube'"):
        pointfield.write(tmp_path / "c.pcd", cloud)
    assert set(pointfield.read(tmp_path / "c.pcd").fields) == {"kept"}


def test_boolean_field_is_written_as_uint8_with_a_warning(tmp_path):
    cloud = PointCloud(np.zeros((2, 3), np.float32), {"valid": np.array([True, False])})
    with pytest.warns(UserWarning, match="U1"):
        pointfield.write(tmp_path / "b.pcd", cloud)
    valid = pointfield.read(tmp_path / "b.pcd").fields["valid"]
    np.testing.assert_array_equal(valid, np.uint8([1, 0]))


def test_invalid_viewpoint_metadata_is_refused(tmp_path):
    cloud = PointCloud(np.zeros((1, 3)), metadata={"viewpoint": (0, 0, 0)})
    with pytest.raises(FormatError, match="viewpoint"):
        pointfield.write(tmp_path / "v.pcd", cloud)


def test_arrays_read_are_writable_and_contiguous(tmp_path):
    for encoding in ENCODINGS:
        path = tmp_path / f"{encoding}.pcd"
        pointfield.write(path, full_cloud(np.float32), encoding=encoding)
        cloud = pointfield.read(path)
        for values in [cloud.points, *cloud.fields.values()]:
            assert values.flags.writeable and values.flags.c_contiguous


# ----------------------------------------------------------------------------------------------
# Header variants


def test_padding_fields_are_skipped(tmp_path):
    lines = [
        "FIELDS x y z _ intensity",
        "SIZE 4 4 4 1 2",
        "TYPE F F F U U",
        "COUNT 1 1 1 4 1",
        "POINTS 2",
        "DATA binary",
    ]
    record = np.dtype([("xyz", "<f4", 3), ("pad", "u1", 4), ("intensity", "<u2")])
    data = np.array([([1, 2, 3], [9] * 4, 7), ([4, 5, 6], [9] * 4, 8)], record).tobytes()
    cloud = pointfield.read(write_pcd_file(tmp_path / "pad.pcd", lines, data))
    np.testing.assert_array_equal(cloud.points, [[1, 2, 3], [4, 5, 6]])
    assert list(cloud.fields) == ["intensity"]
    np.testing.assert_array_equal(cloud.fields["intensity"], np.uint16([7, 8]))


def test_ascii_padding_values_are_skipped(tmp_path):
    lines = ["FIELDS x _ y z", "SIZE 4 1 4 4", "TYPE F U F F", "COUNT 1 2 1 1", "POINTS 2"]
    lines.append("DATA ascii")
    cloud = pointfield.read(write_pcd_file(tmp_path / "pad.pcd", lines, b"1 0 0 2 3\n4 0 0 5 6\n"))
    np.testing.assert_array_equal(cloud.points, [[1, 2, 3], [4, 5, 6]])
    assert cloud.fields == {}


def test_oldest_header_defaults_to_float32_single_components(tmp_path):
    lines = ["# .PCD v.5 - Point Cloud Data file format", "FIELDS x y z", "POINTS 2", "DATA ascii"]
    cloud = pointfield.read(write_pcd_file(tmp_path / "old.pcd", lines, b"1 2 3\n4 5 6\n"))
    assert cloud.points.dtype == np.float32 and cloud.shape is None
    np.testing.assert_array_equal(cloud.points, [[1, 2, 3], [4, 5, 6]])


def test_messy_ascii_whitespace_and_crlf_read(tmp_path):
    data = b"  1\t2   3 \r\n\r\n4 5\t\t6\t\r\n"
    cloud = pointfield.read(write_pcd_file(tmp_path / "ws.pcd", [*HEADER_07, "DATA ascii"], data))
    np.testing.assert_array_equal(cloud.points, [[1, 2, 3], [4, 5, 6]])


def test_ascii_nan_and_infinity_read(tmp_path):
    data = b"nan nan nan\n-inf inf 1\n"
    cloud = pointfield.read(write_pcd_file(tmp_path / "nan.pcd", [*HEADER_07, "DATA ascii"], data))
    assert cloud.nan_count == 1
    assert np.isinf(cloud.points[1, :2]).all()


def test_content_wins_over_a_lying_suffix(tmp_path):
    path = tmp_path / "cloud.ply"
    pointfield.write(tmp_path / "cloud.pcd", full_cloud(np.float32))
    path.write_bytes((tmp_path / "cloud.pcd").read_bytes())
    assert pointfield.read(path).metadata["format"] == "pcd"


@pytest.mark.parametrize(
    "head",
    [b"# .PCD v0.7 - Point Cloud Data file format\nVERSION", b"VERSION 0.7\nFIELDS x y z\n",
     b"FIELDS x y z\nSIZE 4 4 4\n", b"# a comment\nVERSION .5\n"],
)
def test_signature_recognises_pcd_headers(head):
    assert looks_like_pcd(head)


@pytest.mark.parametrize(
    "head",
    [b"ply\nformat ascii 1.0\n", b"OFF\n3 1 0\n", b"1.0 2.0 3.0\n4 5 6\n", b"# x y z\n1 2 3\n",
     b"LASF\x00\x00", b"VERSIONS are fun\n", b"", b"\x93NUMPY"],
)
def test_signature_does_not_claim_other_formats(head):
    assert not looks_like_pcd(head)


# ----------------------------------------------------------------------------------------------
# Hostile input: every case is a FormatError naming the file and what was wrong.


def compressed_block(compressed_size, uncompressed_size, payload):
    return struct.pack("<II", compressed_size, uncompressed_size) + payload


TWO_POINTS = np.arange(6, dtype=np.float32).tobytes()
TRILLION = with_line("WIDTH", "WIDTH 1000000000000", with_line("POINTS", "POINTS 1000000000000"))
HUNDRED_THOUSAND = with_line("WIDTH", "WIDTH 100000", with_line("POINTS", "POINTS 100000"))


def binary(keyword=None, replacement=None):
    """The two-point header, one line changed, as DATA binary with its 24 bytes of points."""
    lines = with_line(keyword, replacement) if keyword else HEADER_07
    return [*lines, "DATA binary"], TWO_POINTS


def compressed(payload, lines=HEADER_07):
    return [*lines, "DATA binary_compressed"], payload


def ascii_data(text, lines=HEADER_07):
    return [*lines, "DATA ascii"], text


# case -> (header lines, data after the header, words the error must contain)
HOSTILE = {
    "empty file": ([], b"", "empty"),
    "header without DATA": (HEADER_07, b"", "no DATA line"),
    "truncated binary data": ([*HEADER_07, "DATA binary"], TWO_POINTS[:-1], "only 23"),
    "POINTS 10^12 binary": (
        [*TRILLION, "DATA binary"], b"\0" * 1000, "needs 12000000000000 bytes"
    ),
    "POINTS 10^12 ascii": (*ascii_data(b"1 2 3\n" * 100, TRILLION), "too few"),
    "POINTS 10^12 compressed": (
        *compressed(compressed_block(4, 2**32 - 1, b"\0" * 4), TRILLION), "need"
    ),
    "WIDTH x HEIGHT != POINTS": (*binary("WIDTH", "WIDTH 3"), "POINTS says 2"),
    "negative POINTS": (*binary("POINTS", "POINTS -2"), "non-negative"),
    "non-numeric SIZE": (*binary("SIZE", "SIZE 4 four 4"), "'four'"),
    "SIZE shorter than FIELDS": (*binary("SIZE", "SIZE 4 4"), "SIZE has 2"),
    "TYPE longer than FIELDS": (*binary("TYPE", "TYPE F F F F"), "TYPE has 4"),
    "COUNT shorter than FIELDS": (*binary("COUNT", "COUNT 1"), "COUNT has 1"),
    "COUNT 0": (*binary("COUNT", "COUNT 1 0 1"), "COUNT 0"),
    "unknown TYPE": (*binary("TYPE", "TYPE F Q F"), "TYPE 'Q'"),
    "float of 3 bytes": (*binary("SIZE", "SIZE 4 3 4"), "SIZE 3"),
    "duplicate field names": (*binary("FIELDS", "FIELDS x y x"), "twice"),
    "VIEWPOINT of 6 numbers": (*binary("VIEWPOINT", "VIEWPOINT 0 0 0 1 0 0"), "expected 7"),
    "VIEWPOINT not numbers": (*binary("VIEWPOINT", "VIEWPOINT 0 0 0 a 0 0 0"), "not 7 numbers"),
    "no FIELDS": (*binary("FIELDS", None), "no FIELDS"),
    "duplicate keyword": ([*HEADER_07, "POINTS 2", "DATA binary"], TWO_POINTS, "two POINTS"),
    "unknown keyword": ([*HEADER_07, "COLOUR red", "DATA binary"], TWO_POINTS, "'COLOUR'"),
    "unknown encoding": ([*HEADER_07, "DATA zip"], TWO_POINTS, "DATA 'zip'"),
    "only padding fields": (
        ["FIELDS _", "SIZE 4", "TYPE U", "COUNT 1", "POINTS 1", "DATA binary"], b"\0" * 4,
        "padding",
    ),
    "corrupt LZF block": (*compressed(compressed_block(4, 24, b"\x20\x05\0\0")), "corrupt"),
    "LZF block expanding too much": (
        *compressed(compressed_block(4, 24, b"\xff" * 4)), "more than the 24 bytes"
    ),
    "LZF block expanding too little": (
        *compressed(compressed_block(3, 24, lzf.compress(b"\0" * 24)[:3])), "bytes"
    ),
    "compressed size larger than the file": (
        *compressed(compressed_block(1000, 24, b"\0" * 20)), "claims 1000"
    ),
    "uncompressed size not the points": (
        *compressed(compressed_block(4, 25, b"\0" * 4)), "expands to 25 bytes"
    ),
    "LZF expansion beyond what LZF can do": (
        *compressed(compressed_block(8, 1200000, b"\0" * 8), HUNDRED_THOUSAND), "cannot expand"
    ),
    "truncated size prefix": (*compressed(b"\0\0\0"), "size prefix"),
    "ascii with words": (*ascii_data(b"1 2 3\n4 five 6\n"), "'five'"),
    "ascii with a short row": (*ascii_data(b"1.5 2.5 3.5\n4 5\n"), "Expected 3 columns"),
    "ascii with too few rows": (*ascii_data(b"1 2 3\n" + b"\n" * 10), "1 rows"),
    "ascii integer out of range": (
        *ascii_data(b"1 2 3\n4 5 -6\n", with_line("TYPE", "TYPE F F U")), "'-6'"
    ),
}


@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_hostile_input_raises_format_error_naming_the_file(tmp_path, case):
    lines, data, reason = HOSTILE[case]
    path = tmp_path / "hostile.pcd"
    path.write_bytes(b"".join(line.encode() + b"\n" for line in lines) + data)
    with pytest.raises(FormatError, match=re.escape(str(path))) as caught:
        pointfield.read(path)
    assert reason in str(caught.value)


def test_header_longer_than_any_real_one_is_refused(tmp_path):
    path = tmp_path / "long.pcd"
    path.write_bytes(b"VERSION 0.7\n" + b"# padding padding padding\n" * (MAX_HEADER_BYTES // 20))
    with pytest.raises(FormatError, match="no DATA line in the first"):
        pointfield.read(path)


def test_header_that_is_not_text_is_refused(tmp_path):
    path = write_pcd_file(tmp_path / "bin.pcd", ["VERSION 0.7"], b"FIELDS \xff\xfe\n")
    with pytest.raises(FormatError, match="not UTF-8 text"):
        pointfield.read(path)


def test_written_header_round_trips_through_the_checks_without_warnings(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        pointfield.write(tmp_path / "c.pcd", full_cloud(np.float64), encoding="ascii")
        pointfield.read(tmp_path / "c.pcd")
