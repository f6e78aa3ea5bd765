"""LAS / LAZ / COPC: real files read like laspy reads them, round trips keep every dimension,
generated clouds come back within the scale, hostile files raise FormatError naming the file."""

from __future__ import annotations

import shutil
import struct
import warnings

import laspy
import numpy as np
import pytest

import pointfield
from pointfield import FormatError, PointCloud
from pointfield.clouds.cloud import same_fields

COUNTS = {
    "simple.las": 1065,
    "simple.laz": 1065,
    "test1_4.las": 1000,
    "1_4_w_evlr.laz": 1000,
    "extrabytes.las": 1065,
    "plane.laz": 28185,
    "simple.copc.laz": 1065,
    "autzen_trim.laz": 110000,
}
SMALL = [name for name in COUNTS if name != "autzen_trim.laz"]
LEGACY_COUNT_OFFSET = 107  # uint32 point count of LAS 1.0-1.3 headers
COUNT_1_4_OFFSET = 247  # uint64 point count of LAS 1.4 headers
VLR_COUNT_OFFSET = 100


def las_file(shared_data, name):
    return shared_data / "las" / name


def patched(tmp_path, source, name, offset, fmt, value):
    data = bytearray(source.read_bytes())
    struct.pack_into(fmt, data, offset, value)
    path = tmp_path / name
    path.write_bytes(bytes(data))
    return path


def laspy_dimensions(path):
    las = laspy.read(path)
    return {name: np.asarray(las[name]) for name in las.point_format.dimension_names}


def read_quietly(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return pointfield.read(path)


# --- reading ----------------------------------------------------------------------------------


@pytest.mark.parametrize("name", COUNTS)
def test_every_las_file_reads_with_its_manifest_count(shared_data, name):
    cloud = pointfield.read(las_file(shared_data, name))
    assert len(cloud) == COUNTS[name]
    assert cloud.metadata["format"] == "las"


@pytest.mark.parametrize("name", COUNTS)
def test_coordinates_are_float64_and_equal_to_laspys(shared_data, name):
    path = las_file(shared_data, name)
    cloud = pointfield.read(path)
    las = laspy.read(path)
    assert cloud.points.dtype == np.float64
    for axis, coordinate in enumerate("xyz"):
        np.testing.assert_array_equal(cloud.points[:, axis], np.asarray(las[coordinate]))


@pytest.mark.parametrize("name", COUNTS)
def test_every_dimension_is_a_field_with_laspys_values_and_dtype(shared_data, name):
    path = las_file(shared_data, name)
    cloud = pointfield.read(path)
    for dimension, expected in laspy_dimensions(path).items():
        if dimension in ("X", "Y", "Z"):
            continue
        if dimension in ("red", "green", "blue"):
            actual = cloud.fields["colors"][:, ("red", "green", "blue").index(dimension)]
        else:
            actual = cloud.fields[dimension]
        assert actual.dtype == expected.dtype, dimension
        np.testing.assert_array_equal(actual, expected, err_msg=dimension)


def test_bit_fields_are_uint8_fields(shared_data):
    cloud = pointfield.read(las_file(shared_data, "test1_4.las"))
    for name in (
        "return_number",
        "number_of_returns",
        "synthetic",
        "key_point",
        "withheld",
        "overlap",
        "scanner_channel",
        "scan_direction_flag",
        "edge_of_flight_line",
    ):
        assert cloud.fields[name].dtype == np.uint8
    assert cloud.fields["return_number"].max() <= 15


def test_colors_are_uint16_n_by_3(shared_data):
    cloud = pointfield.read(las_file(shared_data, "simple.las"))
    assert cloud.fields["colors"].dtype == np.uint16
    assert cloud.fields["colors"].shape == (1065, 3)
    assert not {"red", "green", "blue"} & cloud.fields.keys()


def test_extra_bytes_dimensions_are_fields_in_their_types(shared_data):
    fields = pointfield.read(las_file(shared_data, "extrabytes.las")).fields
    assert (fields["Colors"].dtype, fields["Colors"].shape) == (np.uint16, (1065, 3))
    assert (fields["Reserved"].dtype, fields["Reserved"].shape) == (np.uint8, (1065, 7))
    assert (fields["Flags"].dtype, fields["Flags"].shape) == (np.int8, (1065, 2))
    assert fields["Intensity"].dtype == np.uint32
    assert fields["Time"].dtype == np.uint64
    assert fields["intensity"].dtype == np.uint16  # the standard one, beside the extra one


def test_fields_own_contiguous_memory(shared_data):
    cloud = pointfield.read(las_file(shared_data, "simple.las"))
    for name, values in cloud.fields.items():
        assert values.flags.c_contiguous and values.flags.owndata, name


def test_metadata_says_version_point_format_scales_offsets(shared_data):
    metadata = pointfield.read(las_file(shared_data, "test1_4.las")).metadata
    header = laspy.read(las_file(shared_data, "test1_4.las")).header
    assert metadata["encoding"] == "las"
    assert metadata["las_version"] == "1.4"
    assert metadata["las_point_format"] == 6
    assert metadata["scales"] == list(header.scales)
    assert metadata["offsets"] == list(header.offsets)
    assert metadata["las_copc"] is False


def test_copc_reads_as_laz_and_says_so(shared_data):
    metadata = pointfield.read(las_file(shared_data, "simple.copc.laz")).metadata
    assert metadata["encoding"] == "laz"
    assert metadata["las_copc"] is True
    assert not any(vlr["user_id"] == "copc" for vlr in metadata["las_vlrs"] + metadata["las_evlrs"])


def test_a_copc_output_is_refused_rather_than_written_as_plain_laz(shared_data, tmp_path):
    # COPC is read, not written: a .copc.laz without the octree hierarchy would fool COPC readers.
    cloud = pointfield.read(las_file(shared_data, "simple.copc.laz"))
    with pytest.raises(FormatError, match=r"out\.copc\.laz: pointfield cannot write COPC.*write \.laz"):
        pointfield.write(tmp_path / "out.copc.laz", cloud)
    assert list(tmp_path.iterdir()) == []
    pointfield.write(tmp_path / "out.laz", cloud)  # the same cloud as plain LAZ is fine
    assert len(pointfield.read(tmp_path / "out.laz")) == len(cloud)


def test_crs_records_are_kept_in_metadata(shared_data):
    metadata = pointfield.read(las_file(shared_data, "autzen_trim.laz")).metadata
    kept = {(vlr["user_id"], vlr["record_id"]) for vlr in metadata["las_vlrs"]}
    assert {("LASF_Projection", 34735), ("LASF_Projection", 2112)} <= kept
    assert ("laszip encoded", 22204) not in kept


def test_content_wins_over_a_lying_suffix(shared_data, tmp_path):
    path = tmp_path / "points.xyz"
    shutil.copy(las_file(shared_data, "simple.las"), path)
    assert len(pointfield.read(path)) == 1065


# --- round trips ------------------------------------------------------------------------------


@pytest.mark.parametrize("encoding", ["las", "laz"])
@pytest.mark.parametrize("name", COUNTS)
def test_las_round_trip_keeps_every_dimension_exactly(shared_data, tmp_path, name, encoding):
    source = las_file(shared_data, name)
    cloud = pointfield.read(source)
    path = tmp_path / f"copy.{encoding}"
    pointfield.write(path, cloud)
    back = pointfield.read(path)
    assert back.metadata["encoding"] == encoding
    np.testing.assert_array_equal(back.points, cloud.points)
    assert same_fields(back.fields, cloud.fields)
    original, written = laspy_dimensions(source), laspy_dimensions(path)
    assert list(written) == list(original)
    for dimension in original:
        np.testing.assert_array_equal(written[dimension], original[dimension], err_msg=dimension)


def test_round_trip_keeps_crs_and_evlrs(shared_data, tmp_path):
    for name in ("autzen_trim.laz", "1_4_w_evlr.laz"):
        path = tmp_path / name
        pointfield.write(path, pointfield.read(las_file(shared_data, name)))
        original = laspy.read(las_file(shared_data, name)).header
        written = laspy.read(path).header
        assert [(v.user_id, v.record_id, v.record_data_bytes()) for v in written.vlrs] == [
            (v.user_id, v.record_id, v.record_data_bytes()) for v in original.vlrs
        ]
        assert len(written.evlrs or []) == len(original.evlrs or [])
        np.testing.assert_array_equal(written.scales, original.scales)
        np.testing.assert_array_equal(written.offsets, original.offsets)


def generated_cloud(n=500, seed=0):
    rng = np.random.default_rng(seed)
    points = rng.uniform(-50, 50, (n, 3)) + [500_000.0, 4_000_000.0, 100.0]
    return PointCloud(
        points,
        {
            "gps_time": rng.uniform(0, 1e5, n),
            "intensity": rng.integers(0, 65535, n).astype(np.uint16),
            "label": rng.integers(-(2**40), 2**40, n),
            "feature": rng.normal(size=(n, 5)).astype(np.float32),
            "pair": rng.integers(-5, 5, (n, 2)).astype(np.int16),
            "normals": rng.normal(size=(n, 3)).astype(np.float32),
            "colors": rng.integers(0, 65535, (n, 3)).astype(np.uint16),
        },
    )


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_generated_cloud_round_trips_within_the_scale(tmp_path, suffix):
    cloud = generated_cloud()
    path = tmp_path / f"cloud{suffix}"
    pointfield.write(path, cloud)
    back = pointfield.read(path)
    scale = back.metadata["scales"][0]
    assert scale == 0.001
    assert np.abs(back.points - cloud.points).max() <= scale / 2 + 1e-9
    assert back.metadata["offsets"] == list(np.floor(cloud.points.min(axis=0)))


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_other_fields_become_extra_bytes_of_their_dtype(tmp_path, suffix):
    cloud = generated_cloud()
    path = tmp_path / f"cloud{suffix}"
    pointfield.write(path, cloud)
    back = pointfield.read(path)
    for name in ("gps_time", "intensity", "label", "feature", "pair", "normals", "colors"):
        assert back.fields[name].dtype == cloud.fields[name].dtype, name
        np.testing.assert_array_equal(back.fields[name], cloud.fields[name], err_msg=name)
    extra = set(laspy.read(path).point_format.extra_dimension_names)
    assert {"label", "pair", "nx", "ny", "nz", "feature[0]", "feature[4]"} <= extra


@pytest.mark.parametrize(
    ("fields", "expected_format"),
    [
        ({}, 0),
        ({"gps_time": np.zeros(4)}, 1),
        ({"colors": np.zeros((4, 3), np.uint16)}, 2),
        ({"colors": np.zeros((4, 3), np.uint16), "gps_time": np.zeros(4)}, 3),
        ({"classification": np.array([0, 1, 2, 200], np.uint8)}, 6),
        (
            {
                "classification": np.array([0, 1, 2, 200], np.uint8),
                "colors": np.zeros((4, 3), np.uint16),
            },
            7,
        ),
        ({"nir": np.zeros(4, np.uint16)}, 8),
    ],
)
def test_the_smallest_point_format_that_holds_the_fields_is_chosen(
    tmp_path, fields, expected_format
):
    path = tmp_path / "cloud.las"
    pointfield.write(path, PointCloud(np.arange(12.0).reshape(4, 3), fields))
    assert laspy.read(path).header.point_format.id == expected_format


def test_uint8_colors_are_scaled_to_uint16_with_a_warning(tmp_path):
    colors = np.array([[0, 128, 255], [1, 2, 3]], np.uint8)
    path = tmp_path / "cloud.las"
    with pytest.warns(UserWarning, match="colors uint8 -> uint16"):
        pointfield.write(path, PointCloud(np.zeros((2, 3)), {"colors": colors}))
    back = pointfield.read(path).fields["colors"]
    np.testing.assert_array_equal(back, colors.astype(np.uint16) * 257)


def test_unit_float_colors_and_intensity_are_scaled_to_uint16(tmp_path):
    path = tmp_path / "cloud.las"
    cloud = PointCloud(
        np.zeros((2, 3)),
        {
            "colors": np.array([[0, 0.5, 1], [1, 1, 1]], np.float32),
            "intensity": np.array([0.0, 1.0], np.float32),
        },
    )
    with pytest.warns(UserWarning, match="in \\[0, 1\\]"):
        pointfield.write(path, cloud)
    back = pointfield.read(path).fields
    np.testing.assert_array_equal(back["colors"], [[0, 32768, 65535], [65535, 65535, 65535]])
    np.testing.assert_array_equal(back["intensity"], [0, 65535])


def test_rgba_colors_keep_alpha(tmp_path):
    colors = np.array([[1, 2, 3, 4], [5, 6, 7, 8]], np.uint16)
    path = tmp_path / "cloud.laz"
    pointfield.write(path, PointCloud(np.zeros((2, 3)), {"colors": colors}))
    np.testing.assert_array_equal(pointfield.read(path).fields["colors"], colors)


def test_suffix_chooses_compression_and_aliases_name_encodings(shared_data, tmp_path):
    cloud = pointfield.read(las_file(shared_data, "simple.las"))
    pointfield.write(tmp_path / "a.laz", cloud)
    pointfield.write(tmp_path / "b.las", cloud, encoding="compressed")
    pointfield.write(tmp_path / "c.las", cloud, encoding="binary")
    assert pointfield.read(tmp_path / "a.laz").metadata["encoding"] == "laz"
    assert pointfield.read(tmp_path / "b.las").metadata["encoding"] == "laz"
    assert pointfield.read(tmp_path / "c.las").metadata["encoding"] == "las"


def test_nan_points_are_dropped_with_a_warning(tmp_path):
    points = np.array([[0, 0, 0], [np.nan, 1, 1], [2, 2, 2]], np.float32)
    cloud = PointCloud(points, {"intensity": np.array([1, 2, 3], np.uint16)})
    path = tmp_path / "cloud.las"
    with pytest.warns(UserWarning, match="1 of 3 points dropped"):
        pointfield.write(path, cloud)
    back = pointfield.read(path)
    np.testing.assert_array_equal(back.fields["intensity"], [1, 3])


def test_organised_shape_is_not_kept_and_says_so(tmp_path):
    cloud = PointCloud(np.zeros((6, 3)), shape=(2, 3))
    with pytest.warns(UserWarning, match="no organised layout"):
        pointfield.write(tmp_path / "cloud.las", cloud)
    assert pointfield.read(tmp_path / "cloud.las").shape is None


def test_wide_extent_gets_a_coarser_scale(tmp_path):
    points = np.array([[0.0, 0.0, 0.0], [1e7, 0.0, 0.0]])
    path = tmp_path / "cloud.las"
    pointfield.write(path, PointCloud(points))
    back = pointfield.read(path)
    assert back.metadata["scales"] == [0.01, 0.01, 0.01]
    np.testing.assert_allclose(back.points, points, atol=0.005)


def test_values_too_big_for_a_standard_dimension_are_clipped_with_a_warning(tmp_path):
    path = tmp_path / "cloud.las"
    cloud = PointCloud(np.zeros((2, 3)), {"user_data": np.array([3, 300])})
    with pytest.warns(UserWarning, match="user_data int64 -> uint8, 1 values rounded or clipped"):
        pointfield.write(path, cloud)
    np.testing.assert_array_equal(pointfield.read(path).fields["user_data"], [3, 255])


def test_fields_las_cannot_hold_are_named_in_a_warning(tmp_path):
    cloud = PointCloud(np.zeros((2, 3)), {"name": np.array(["a", "b"]), "x" * 40: np.zeros(2)})
    with pytest.warns(UserWarning, match="LAS cannot hold these fields: name .*xxxx"):
        pointfield.write(tmp_path / "cloud.las", cloud)


def test_empty_cloud_round_trips(tmp_path):
    for suffix in (".las", ".laz"):
        pointfield.write(tmp_path / f"empty{suffix}", PointCloud(np.zeros((0, 3))))
        assert len(pointfield.read(tmp_path / f"empty{suffix}")) == 0


# --- hostile files ----------------------------------------------------------------------------


def assert_format_error(path, match):
    with pytest.raises(FormatError, match=match) as caught:
        pointfield.read(path)
    assert str(path) in str(caught.value)


def test_empty_file_is_a_format_error(tmp_path):
    path = tmp_path / "empty.las"
    path.write_bytes(b"")
    with pytest.raises(FormatError) as caught:
        pointfield.read(path)
    assert str(path) in str(caught.value)


def test_truncated_header_is_a_format_error(shared_data, tmp_path):
    path = tmp_path / "short.las"
    path.write_bytes(las_file(shared_data, "simple.las").read_bytes()[:100])
    assert_format_error(path, "truncated")


def test_truncated_points_are_a_format_error(shared_data, tmp_path):
    path = tmp_path / "half.las"
    data = las_file(shared_data, "simple.las").read_bytes()
    path.write_bytes(data[: len(data) // 2])
    assert_format_error(path, "header declares 1065 points of 34 bytes")


def test_random_bytes_after_the_signature_are_a_format_error(tmp_path):
    rng = np.random.default_rng(0)
    for i in range(20):
        path = tmp_path / f"random{i}.las"
        path.write_bytes(b"LASF" + rng.integers(0, 256, 3000, dtype=np.uint8).tobytes())
        assert_format_error(path, None)


def test_huge_point_count_is_refused_before_allocating(shared_data, tmp_path):
    legacy = patched(
        tmp_path,
        las_file(shared_data, "simple.las"),
        "huge.las",
        LEGACY_COUNT_OFFSET,
        "<I",
        4_000_000_000,
    )
    assert_format_error(legacy, "header declares 4000000000 points")
    modern = patched(
        tmp_path, las_file(shared_data, "test1_4.las"), "huge14.las", COUNT_1_4_OFFSET, "<Q", 10**12
    )
    assert_format_error(modern, "header declares 1000000000000 points")


def test_huge_point_count_in_laz_is_refused_by_the_chunk_table(shared_data, tmp_path):
    path = patched(
        tmp_path,
        las_file(shared_data, "simple.laz"),
        "huge.laz",
        LEGACY_COUNT_OFFSET,
        "<I",
        4_000_000_000,
    )
    assert_format_error(path, "LAZ chunk")


def test_huge_vlr_count_is_a_format_error(shared_data, tmp_path):
    path = patched(
        tmp_path,
        las_file(shared_data, "simple.las"),
        "vlrs.las",
        VLR_COUNT_OFFSET,
        "<I",
        4_000_000_000,
    )
    assert_format_error(path, "4000000000 VLRs")


def laz_chunk_table_offset(path):
    offset_to_points = struct.unpack_from("<I", path.read_bytes(), 96)[0]
    return struct.unpack_from("<q", path.read_bytes(), offset_to_points)[0]


def test_huge_laz_chunk_count_is_a_format_error(shared_data, tmp_path):
    source = las_file(shared_data, "simple.laz")
    path = patched(
        tmp_path, source, "chunks.laz", laz_chunk_table_offset(source) + 4, "<I", 4_000_000_000
    )
    assert_format_error(path, "4000000000 chunks")


def test_huge_laz_chunk_size_does_not_allocate_by_it(shared_data, tmp_path):
    source = las_file(shared_data, "simple.laz")
    chunk_size_offset = 227 + 54 + 12  # header, VLR header, LASzip record up to chunk_size
    path = patched(tmp_path, source, "chunk_size.laz", chunk_size_offset, "<I", 1_943_389_008)
    assert len(read_quietly(path)) == 1065  # one chunk: read point by point, nothing sized by it


def test_huge_layer_size_in_a_layered_laz_chunk_is_a_format_error(shared_data, tmp_path):
    source = las_file(shared_data, "1_4_w_evlr.laz")
    offset_to_points = struct.unpack_from("<I", source.read_bytes(), 96)[0]
    first_layer_size = offset_to_points + 8 + 30 + 4  # chunk offset, raw point, point count
    path = patched(tmp_path, source, "layer.laz", first_layer_size, "<I", 2**31)
    assert_format_error(path, "bytes of layers")


def test_mutated_files_read_or_raise_format_error_quickly(shared_data, tmp_path):
    rng = np.random.default_rng(5)
    sources = [las_file(shared_data, name).read_bytes() for name in SMALL]
    for case in range(240):
        data = bytearray(sources[case % len(sources)])
        kind = case % 4
        if kind == 0:
            for _ in range(int(rng.integers(1, 8))):
                i = int(rng.integers(len(data)))
                data[i] ^= 1 << int(rng.integers(8))
        elif kind == 1:
            data = data[: int(rng.integers(len(data)))]
        elif kind == 2:
            i = int(rng.integers(min(len(data), 400)))
            width = int(rng.choice([1, 2, 4, 8]))
            data[i : i + width] = rng.integers(0, 256, width, dtype=np.uint8).tobytes()
        else:
            i = int(rng.integers(len(data)))
            data[i:] = rng.integers(0, 256, len(data) - i, dtype=np.uint8).tobytes()
        path = tmp_path / f"case{case}.{'laz' if case % len(sources) in (1, 3, 5) else 'las'}"
        path.write_bytes(bytes(data))
        try:
            read_quietly(path)
        except FormatError as error:
            assert str(path) in str(error)
        path.unlink()
