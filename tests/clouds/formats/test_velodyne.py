"""Raw float32 scans (.bin): KITTI / nuScenes / ScanNet layouts, round trips, size checks."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import pointfield
from pointfield import FormatError, PointCloud
from pointfield.clouds.cloud import same_fields


def read_quietly(path, **options):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return pointfield.read(path, **options)


def write_quietly(path, cloud):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pointfield.write(path, cloud)


def raw_scan(tmp_path, values, name="scan.bin"):
    path = tmp_path / name
    np.asarray(values, "<f4").tofile(path)
    return path


@pytest.mark.parametrize(
    ("name", "count"),
    [("kitti/mmdet3d_demo/000008.bin", 17238), ("kitti/semantickitti_seq00/000000.bin", 124668)],
)
def test_kitti_scans_read_as_x_y_z_intensity(shared_data, name, count):
    cloud = read_quietly(shared_data / name)
    assert cloud.points.shape == (count, 3) and cloud.points.dtype == np.float32
    assert set(cloud.fields) == {"intensity"} and cloud.fields["intensity"].dtype == np.float32
    assert cloud.fields["intensity"].min() >= 0 and cloud.fields["intensity"].max() <= 1
    assert cloud.metadata == {"format": "velodyne", "encoding": "float32", "columns": 4}


def test_the_kitti_scan_has_the_manifest_extent(shared_data):
    low, high = read_quietly(shared_data / "kitti/mmdet3d_demo/000008.bin").bounds()
    np.testing.assert_allclose(low, [2.9, -26.4, -3.6], atol=0.05)
    np.testing.assert_allclose(high, [76.8, 10.3, 2.9], atol=0.05)


def test_the_scannet_scan_reads_with_six_columns_as_colours(shared_data):
    cloud = read_quietly(
        shared_data / "other_pointclouds/scannet_scene0000_00_xyzrgb.bin", columns=6
    )
    assert len(cloud) == 40684
    colors = cloud.fields["colors"]
    assert colors.shape == (40684, 3) and colors.dtype == np.float32
    assert colors.min() >= 0 and colors.max() <= 255


def test_five_columns_are_nuscenes_intensity_and_ring(tmp_path):
    path = raw_scan(tmp_path, [[1, 2, 3, 0.5, 7], [4, 5, 6, 0.25, 31]])
    cloud = read_quietly(path, columns=5)
    np.testing.assert_array_equal(cloud.fields["intensity"], [0.5, 0.25])
    np.testing.assert_array_equal(cloud.fields["ring"], [7, 31])


def test_other_column_counts_give_features(tmp_path):
    cloud = read_quietly(raw_scan(tmp_path, np.arange(16).reshape(2, 8)), columns=8)
    assert cloud.fields["features"].shape == (2, 5)
    assert read_quietly(raw_scan(tmp_path, np.arange(6).reshape(2, 3)), columns=3).fields == {}


# ---------------------------------------------------------------------------------------------
# Round trips: every layout gives back float32 points and fields bit for bit


def scan(n=64, **fields):
    rng = np.random.default_rng(9)
    points = rng.normal(scale=30, size=(n, 3)).astype(np.float32)
    points[5] = np.nan
    return PointCloud(points, {name: make(rng, n) for name, make in fields.items()})


LAYOUTS = {
    4: {"intensity": lambda rng, n: rng.random(n, np.float32)},
    5: {
        "intensity": lambda rng, n: rng.random(n, np.float32),
        "ring": lambda rng, n: rng.integers(0, 32, n).astype(np.float32),
    },
    6: {"colors": lambda rng, n: rng.integers(0, 256, (n, 3)).astype(np.float32)},
    9: {"features": lambda rng, n: rng.random((n, 6), np.float32)},
    3: {},
}


@pytest.mark.parametrize("columns", LAYOUTS, ids=[f"{c} columns" for c in LAYOUTS])
def test_each_layout_round_trips_with_its_column_count(tmp_path, columns):
    cloud = scan(**LAYOUTS[columns])
    write_quietly(tmp_path / "round.bin", cloud)
    assert (tmp_path / "round.bin").stat().st_size == len(cloud) * 4 * columns
    back = read_quietly(tmp_path / "round.bin", columns=columns)
    np.testing.assert_array_equal(back.points, cloud.points)
    assert back.points.dtype == np.float32
    assert same_fields(back.fields, cloud.fields)


def test_a_layout_other_than_kittis_warns_which_columns_to_read_it_with(tmp_path):
    with pytest.warns(UserWarning, match="columns=6"):
        pointfield.write(tmp_path / "rgb.bin", scan(**LAYOUTS[6]))


def test_uint8_colours_are_written_as_float32_without_loss(tmp_path):
    cloud = scan(colors=lambda rng, n: rng.integers(0, 256, (n, 3), dtype=np.uint8))
    write_quietly(tmp_path / "u8.bin", cloud)
    back = read_quietly(tmp_path / "u8.bin", columns=6)
    np.testing.assert_array_equal(back.fields["colors"], cloud.fields["colors"])


def test_float64_points_that_lose_digits_warn(tmp_path):
    cloud = PointCloud(
        np.array([[636110.300003, 849345.050003, 512.139999]]),
        {"intensity": np.ones(1, np.float32)},
    )
    with pytest.warns(UserWarning, match="points changed when rounded to float32"):
        pointfield.write(tmp_path / "utm.bin", cloud)


def test_fields_the_layout_cannot_hold_are_left_out_with_a_warning(tmp_path):
    cloud = scan(**LAYOUTS[4], normals=lambda rng, n: rng.random((n, 3)))
    with pytest.warns(UserWarning, match="'normals'"):
        pointfield.write(tmp_path / "drop.bin", cloud)
    assert set(read_quietly(tmp_path / "drop.bin").fields) == {"intensity"}


def test_an_empty_cloud_cannot_be_written(tmp_path):
    with pytest.raises(FormatError, match="zero points"):
        pointfield.write(tmp_path / "empty.bin", PointCloud(np.zeros((0, 3), np.float32)))


# ---------------------------------------------------------------------------------------------
# Hostile input and wrong options: each is a FormatError naming the file


def test_a_size_that_does_not_fit_the_columns_suggests_the_counts_that_do(shared_data):
    path = shared_data / "other_pointclouds/scannet_scene0000_00_xyzrgb.bin"
    with pytest.raises(FormatError) as error:
        pointfield.read(path, columns=5)
    message = str(error.value)
    assert str(path) in message and "976416 bytes" in message
    assert "columns=3, 4, 6, 7, 8, 12, 14 would divide it" in message


@pytest.mark.parametrize(
    ("data", "columns"),
    [
        (b"", 4),
        (b"\x00" * 17, 4),
        (b"\x00" * 15, 4),
        (b"\x00" * 7, 3),
        (b"\x00" * 48, 0),
        (b"\x00" * 48, 2),
        (b"\x00" * 48, -4),
        (b"\x00" * 48, "4"),
        (b"\x00" * 48, True),
        (b"\x00" * 48, 4.0),
    ],
    ids=[
        "empty",
        "17 bytes",
        "15 bytes",
        "7 bytes, 3 columns",
        "0 columns",
        "2 columns",
        "negative columns",
        "columns as text",
        "columns as bool",
        "columns as float",
    ],
)
def test_hostile_sizes_and_wrong_columns_are_format_errors_naming_the_file(tmp_path, data, columns):
    path = tmp_path / "bad.bin"
    path.write_bytes(data)
    with pytest.raises(FormatError) as error:
        pointfield.read(path, columns=columns)
    assert str(path) in str(error.value)


def test_a_size_no_column_count_divides_says_so(tmp_path):
    path = tmp_path / "odd.bin"
    path.write_bytes(b"\x00" * 13)
    with pytest.raises(FormatError, match="not a float32 scan"):
        pointfield.read(path)
