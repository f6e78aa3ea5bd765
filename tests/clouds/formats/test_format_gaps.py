"""The gaps a wider set of real files found (issue 18), each through Python and the command line:
old LAZ, comma / tab PCD, records to LAS, names LAS cannot hold, silent narrowing, nuScenes
sweeps read as KITTI."""

from __future__ import annotations

import json
import os
import struct
import sys
import warnings
from pathlib import Path

import laspy
import numpy as np
import pytest

import pointfield
from pointfield import FormatError, PointCloud, Records
from pointfield.cli import main
from pointfield.clouds.formats.las import layout as las_layout
from pointfield.clouds.formats.las.library import rust_panics_quiet

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from fuzzing import legacy_laszip

needs_laszip = pytest.mark.skipif(
    not laspy.LazBackend.Laszip.is_available(), reason="the LASzip backend (pip install laszip)"
)


def read_quietly(path, **options):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return pointfield.read(path, **options)


def one_line_error(capsys, argv, *fragments):
    assert main([str(a) for a in argv]) == 1
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("pointfield: error:"), captured.err
    for fragment in fragments:
        assert str(fragment) in lines[0]
    return lines[0]


def info(capsys, *argv):
    assert main(["cloud", "info", *map(str, argv), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


# ---------------------------------------------------------------------------------------------
# LAZ from LASzip 1.2r0: pointwise, "variable-size chunks", no chunk table


@pytest.fixture
def laz_pair(tmp_path):
    """A LAZ file pointfield wrote, and the same points as LASzip 1.2r0 wrote them."""
    rng = np.random.default_rng(5)
    cloud = PointCloud(
        rng.uniform(0, 100, (500, 3)),
        {"intensity": rng.integers(0, 4000, 500).astype(np.uint16),
         "colors": rng.integers(0, 65536, (500, 3)).astype(np.uint16)},
    )
    pointfield.write(tmp_path / "new.laz", cloud)
    old = tmp_path / "old.laz"
    old.write_bytes(legacy_laszip((tmp_path / "new.laz").read_bytes()))
    return tmp_path / "new.laz", old


@needs_laszip
def test_old_laszip_files_are_read_by_the_laszip_backend_without_a_panic(laz_pair, capfd):
    new, old = laz_pair
    cloud = read_quietly(old)
    expected = read_quietly(new)
    np.testing.assert_array_equal(cloud.points, expected.points)
    np.testing.assert_array_equal(cloud.fields["colors"], expected.fields["colors"])
    assert "panicked" not in capfd.readouterr().err


def test_lazrs_really_panics_on_old_laszip_files(laz_pair, capfd):
    # Why the layout check sends these files to LASzip.
    _, old = laz_pair
    with pytest.raises(BaseException, match="Variable-size chunks") as error, rust_panics_quiet():
        laspy.read(old, laz_backend=laspy.LazBackend.Lazrs)
    assert type(error.value).__name__ == "PanicException"
    assert "panicked" not in capfd.readouterr().err


@needs_laszip
def test_a_lazrs_failure_falls_back_to_laszip_with_the_panic_kept_quiet(
    laz_pair, capfd, monkeypatch
):
    # As if the old layout were not recognised: lazrs runs first, panics, LASzip reads.
    _, old = laz_pair
    monkeypatch.setattr(las_layout, "check_laz", lambda *_: laspy.LazBackend.Lazrs)
    assert len(read_quietly(old)) == 500
    err = capfd.readouterr().err
    assert "panicked" not in err and "Variable-size" not in err


def test_output_to_stderr_beside_a_quiet_panic_still_reaches_stderr(capfd):
    with rust_panics_quiet():
        os.write(2, b"a message from elsewhere\n")
    assert capfd.readouterr().err == "a message from elsewhere\n"


def test_without_laszip_an_old_laz_is_one_clear_error(laz_pair, monkeypatch, capsys):
    _, old = laz_pair
    monkeypatch.setattr(laspy.LazBackend, "is_available", lambda self: self is not self.Laszip)
    with pytest.raises(FormatError, match=r"old LASzip.*pip install laszip"):
        pointfield.read(old)
    one_line_error(capsys, ["cloud", "info", old], old, "pip install laszip")


@needs_laszip
def test_a_file_both_backends_refuse_is_one_line_giving_both_reasons(laz_pair, capfd):
    new, _ = laz_pair
    data = bytearray(new.read_bytes())
    header_size = struct.unpack_from("<H", data, 94)[0]
    struct.pack_into("<H", data, header_size + 54 + 34 + 4, 99)  # POINT10 item version 99
    broken = new.with_name("broken.laz")
    broken.write_bytes(bytes(data))
    assert main(["cloud", "info", str(broken)]) == 1
    lines = capfd.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    assert "lazrs could not read it" in lines[0] and "LASzip could not read it" in lines[0]


@needs_laszip
def test_cloud_info_and_convert_read_an_old_laz(laz_pair, capsys, tmp_path):
    _, old = laz_pair
    assert info(capsys, old)["points"] == 500
    assert main(["cloud", "convert", str(old), str(tmp_path / "out.ply")]) == 0
    assert len(read_quietly(tmp_path / "out.ply")) == 500


# ---------------------------------------------------------------------------------------------
# ASCII PCD with comma or tab separators (PDAL writes and reads them)


@pytest.fixture
def pdal_pcd(shared_data):
    return shared_data / "pcd" / "pdal_utm17_space_ascii.pcd"


def _with_separator(path, out, separator):
    header, data = path.read_bytes().split(b"DATA ascii\n", 1)
    out.write_bytes(header + b"DATA ascii\n" + data.replace(b" ", separator))
    return out


@pytest.mark.parametrize("separator", [b",", b"\t", b", "], ids=["comma", "tab", "comma-space"])
def test_ascii_pcd_with_other_separators_reads_as_the_space_separated_file(
    pdal_pcd, tmp_path, separator
):
    path = _with_separator(pdal_pcd, tmp_path / "utm17.pcd", separator)
    np.testing.assert_array_equal(read_quietly(path).points, read_quietly(pdal_pcd).points)


def test_cloud_info_reads_a_comma_separated_pcd(pdal_pcd, tmp_path, capsys):
    path = _with_separator(pdal_pcd, tmp_path / "utm17_comma.pcd", b",")
    described = info(capsys, path)
    assert described["format"] == "pcd" and described["points"] == 10


# ---------------------------------------------------------------------------------------------
# A cloud without x y z (Records) written to LAS


@pytest.mark.parametrize("suffix", [".las", ".npz", ".xyz", ".bin"])
def test_records_written_to_a_format_without_them_name_the_formats_that_hold_them(tmp_path, suffix):
    records = Records({"descriptor": np.zeros((3, 8), np.float32)})
    with pytest.raises(FormatError) as error:
        pointfield.write(tmp_path / f"records{suffix}", records)
    assert f"{suffix} needs points; write records without x/y/z as .npy, .pcd or .ply" in str(error.value)
    assert not (tmp_path / f"records{suffix}").exists()


def test_converting_a_descriptor_pcd_to_las_is_one_line(tmp_path, capsys):
    source = tmp_path / "descriptors.pcd"
    pointfield.write(source, Records({"brisk": np.arange(64 * 3, dtype=np.float32).reshape(3, 64)}))
    one_line_error(capsys, ["cloud", "convert", source, tmp_path / "out.las"], "needs points")
    assert not (tmp_path / "out.las").exists()


# ---------------------------------------------------------------------------------------------
# Field names a format cannot hold


def test_well_known_names_become_las_dimensions_and_the_rest_are_sanitised(tmp_path):
    cloud = PointCloud(
        np.random.default_rng(1).normal(size=(4, 3)),
        {
            "las:pointSourceId": np.array([1, 2, 3, 4], np.uint16),
            "GpsTime": np.array([0.5, 1.5, 2.5, 3.5]),
            "ext:curvature": np.array([0.1, 0.2, 0.3, 0.4], np.float32),
        },
    )
    with pytest.warns(UserWarning) as caught:
        pointfield.write(tmp_path / "names.las", cloud)
    assert len(caught) == 1
    message = str(caught[0].message)
    assert "'las:pointSourceId' -> 'point_source_id'" in message
    assert "'GpsTime' -> 'gps_time'" in message and "'ext:curvature' -> 'ext_curvature'" in message
    back = read_quietly(tmp_path / "names.las")
    np.testing.assert_array_equal(back.fields["point_source_id"], [1, 2, 3, 4])
    np.testing.assert_array_equal(back.fields["gps_time"], [0.5, 1.5, 2.5, 3.5])
    np.testing.assert_array_equal(back.fields["ext_curvature"], cloud.fields["ext:curvature"])


def test_a_sanitised_name_does_not_overwrite_a_field(tmp_path):
    cloud = PointCloud(
        np.zeros((2, 3)), {"a:b": np.ones(2, np.float32), "a_b": np.zeros(2, np.float32)}
    )
    with pytest.warns(UserWarning, match="'a:b' -> 'a_b_2'"):
        pointfield.write(tmp_path / "clash.las", cloud)
    back = read_quietly(tmp_path / "clash.las")
    np.testing.assert_array_equal(back.fields["a_b"], [0, 0])
    np.testing.assert_array_equal(back.fields["a_b_2"], [1, 1])


def test_cloud_convert_names_the_renamed_fields(tmp_path, capsys):
    source = tmp_path / "names.npz"
    pointfield.write(source, PointCloud(np.zeros((2, 3)), {"nor:curvature": np.ones(2)}))
    assert main(["cloud", "convert", str(source), str(tmp_path / "names.las")]) == 0
    assert "'nor:curvature' -> 'nor_curvature'" in capsys.readouterr().err
    assert "nor_curvature" in read_quietly(tmp_path / "names.las").fields


def test_converting_an_e57_with_a_las_extension_field_to_las(tmp_path, capsys):
    pytest.importorskip("pye57")
    cloud = PointCloud(
        np.random.default_rng(2).normal(size=(5, 3)),
        {"las:pointSourceId": np.array([7, 7, 8, 8, 9], np.uint16)},
    )
    pointfield.write(tmp_path / "scan.e57", cloud)
    assert main(["cloud", "convert", str(tmp_path / "scan.e57"), str(tmp_path / "scan.las")]) == 0
    assert "'las:pointSourceId' -> 'point_source_id'" in capsys.readouterr().err
    back = read_quietly(tmp_path / "scan.las")
    np.testing.assert_array_equal(back.fields["point_source_id"], [7, 7, 8, 8, 9])


# ---------------------------------------------------------------------------------------------
# Silent narrowing: 64-bit integers to PLY, NaN to LAS integers


def test_uint64_to_ply_is_uint32_with_a_warning_when_every_value_fits(tmp_path):
    cloud = PointCloud(np.zeros((3, 3)), {"id": np.array([1, 2, 2**32 - 1], np.uint64)})
    with pytest.warns(UserWarning, match=r"'id' \(uint64\) is written as uint32"):
        pointfield.write(tmp_path / "ids.ply", cloud)
    back = read_quietly(tmp_path / "ids.ply")
    assert back.fields["id"].dtype == np.uint32
    np.testing.assert_array_equal(back.fields["id"], cloud.fields["id"])


def test_64_bit_integers_beyond_32_bits_are_kept_as_exact_doubles_with_a_warning(tmp_path):
    values = np.array([0, 2**40 + 1, 2**53], np.uint64)
    with pytest.warns(UserWarning, match="written as double, exact"):
        pointfield.write(tmp_path / "big.ply", PointCloud(np.zeros((3, 3)), {"id": values}))
    back = read_quietly(tmp_path / "big.ply").fields["id"]
    assert back.dtype == np.float64
    np.testing.assert_array_equal(back.astype(np.uint64), values)


def test_64_bit_integers_a_double_cannot_hold_are_refused(tmp_path):
    cloud = PointCloud(np.zeros((2, 3)), {"id": np.array([0, 2**53 + 1], np.uint64)})
    with pytest.raises(FormatError, match="2\\*\\*53"):
        pointfield.write(tmp_path / "huge.ply", cloud)


def _polygons(*faces):
    array = np.empty(len(faces), object)
    array[:] = [np.array(face, np.int64) for face in faces]
    return array


@pytest.mark.parametrize(
    "faces",
    [np.array([[0, 1, 2], [0, 2, 3]], np.int64), np.array([[0, 1, 2]], np.uint64),
     _polygons([0, 1, 2], [0, 1, 2, 3])],
    ids=["int64 triangles", "uint64 triangles", "int64 polygons"],
)
def test_64_bit_face_indices_are_written_as_int_without_a_warning(tmp_path, faces):
    mesh = pointfield.Mesh(np.random.default_rng(0).normal(size=(4, 3)), faces=faces)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        pointfield.write(tmp_path / "mesh.ply", mesh)
    back = read_quietly(tmp_path / "mesh.ply").faces
    for read, written in zip(back, faces, strict=True):
        assert read.dtype == np.int32
        np.testing.assert_array_equal(read, written)


def test_cloud_convert_prints_the_narrowing_warning(tmp_path, capsys):
    source = tmp_path / "ids.npz"
    pointfield.write(source, PointCloud(np.zeros((2, 3)), {"id": np.array([1, 2], np.uint64)}))
    assert main(["cloud", "convert", str(source), str(tmp_path / "ids.ply")]) == 0
    assert f"pointfield: warning: {tmp_path / 'ids.ply'}: PLY has no 64-bit integers" in capsys.readouterr().err


def test_nan_written_to_las_integer_fields_is_warned(tmp_path):
    cloud = PointCloud(
        np.zeros((3, 3)),
        {
            "classification": np.array([1.0, np.nan, 2.0]),
            "intensity": np.array([0.5, np.nan, 1.0]),
        },
    )
    with pytest.warns(UserWarning) as caught:
        pointfield.write(tmp_path / "nan.las", cloud)
    message = " ".join(str(w.message) for w in caught)
    assert "classification float64 -> uint8, 1 NaN written as 0" in message
    assert "intensity float64 in [0, 1] -> uint16 (x65535), 1 NaN written as 0" in message
    np.testing.assert_array_equal(read_quietly(tmp_path / "nan.las").fields["classification"], [1, 0, 2])


def test_cloud_convert_warns_of_nan_in_las_integer_fields(tmp_path, capsys):
    source = tmp_path / "labels.npz"
    pointfield.write(source, PointCloud(np.zeros((2, 3)), {"classification": np.array([2.0, np.nan])}))
    assert main(["cloud", "convert", str(source), str(tmp_path / "labels.las")]) == 0
    assert "classification float64 -> uint8, 1 NaN written as 0" in capsys.readouterr().err


# ---------------------------------------------------------------------------------------------
# PTS: the count line's points, as PDAL reads them (issue 16)


def test_cloud_info_of_a_pts_counts_the_declared_points(shared_data, capsys):
    assert main(["cloud", "info", str(shared_data / "xyz_pts" / "pdal_bunny_8.pts"), "--json"]) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)["points"] == 8
    assert "pointfield: warning:" in captured.err and "the first 8 were read" in captured.err


# ---------------------------------------------------------------------------------------------
# A nuScenes sweep read without --columns


def nuscenes_sweep(n, seed=0):
    """x y z intensity ring, as nuScenes' LIDAR_TOP sweeps: intensity 0..255, ring 0..31."""
    rng = np.random.default_rng(seed)
    azimuth, distance = rng.uniform(0, 2 * np.pi, n), rng.uniform(2, 60, n)
    return np.stack(
        [
            distance * np.cos(azimuth),
            distance * np.sin(azimuth),
            rng.uniform(-2, 1, n),
            rng.integers(0, 256, n),
            rng.integers(0, 32, n),
        ],
        axis=1,
    ).astype("<f4")


def kitti_scan(n, seed=0):
    sweep = nuscenes_sweep(n, seed)[:, :4].copy()
    sweep[:, 3] = np.random.default_rng(seed).random(n)  # reflectance 0..1
    return sweep


def write_scan(tmp_path, name, records):
    path = tmp_path / name
    records.tofile(path)
    return path


@pytest.mark.parametrize(
    "name", ["n015-2018-07-24__LIDAR_TOP__1532402927647951.pcd.bin", "sweep.pcd.bin"]
)
@pytest.mark.parametrize("count", [1001, 1000], ids=["size fits 5 only", "size fits 4 and 5"])
def test_a_nuscenes_sweep_reads_as_five_columns(tmp_path, name, count):
    sweep = nuscenes_sweep(count)
    cloud = read_quietly(write_scan(tmp_path, name, sweep))
    assert cloud.metadata["columns"] == 5 and len(cloud) == count
    np.testing.assert_array_equal(cloud.fields["ring"], sweep[:, 4])


@pytest.mark.parametrize("count", [1001, 1000], ids=["size fits 5 only", "size fits 4 and 5"])
def test_a_sweep_with_a_plain_name_reads_as_five_columns_with_a_warning(tmp_path, count):
    with pytest.warns(UserWarning, match="fit nuScenes' x y z intensity ring only"):
        cloud = pointfield.read(write_scan(tmp_path, "000001.bin", nuscenes_sweep(count)))
    assert cloud.metadata["columns"] == 5


def test_a_kitti_scan_whose_size_also_fits_five_columns_stays_four(tmp_path):
    cloud = read_quietly(write_scan(tmp_path, "000001.bin", kitti_scan(1000)))
    assert cloud.metadata["columns"] == 4


def test_a_kitti_scan_named_like_nuscenes_reads_as_four_with_a_warning(tmp_path):
    with pytest.warns(UserWarning, match="its name says nuScenes"):
        cloud = pointfield.read(write_scan(tmp_path, "x.pcd.bin", kitti_scan(1000)))
    assert cloud.metadata["columns"] == 4


def test_a_scan_of_neither_layout_is_refused_naming_columns(shared_data):
    path = shared_data / "other_pointclouds" / "scannet_scene0000_00_xyzrgb.bin"  # 6 columns
    with pytest.raises(FormatError, match="columns=") as error:
        pointfield.read(path)
    assert "--columns" in str(error.value) and "6" in str(error.value)


def test_columns_overrides_the_guess(tmp_path):
    path = write_scan(tmp_path, "sweep.pcd.bin", nuscenes_sweep(1000))
    assert read_quietly(path, columns=4).metadata["columns"] == 4


def test_cloud_info_guesses_a_nuscenes_sweep_and_refuses_scannet(tmp_path, shared_data, capsys):
    path = write_scan(tmp_path, "sweep__LIDAR_TOP__1.pcd.bin", nuscenes_sweep(1001))
    described = info(capsys, path)
    assert described["metadata"]["columns"] == 5 and "ring" in described["fields"]
    scannet = shared_data / "other_pointclouds" / "scannet_scene0000_00_xyzrgb.bin"
    one_line_error(capsys, ["cloud", "info", scannet], scannet, "--columns")
    assert info(capsys, scannet, "--columns", "6")["points"] == 40684
