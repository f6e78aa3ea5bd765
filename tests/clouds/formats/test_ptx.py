"""Leica PTX: every scan, its transform and grid, no-return cells, round trips, hostile headers,
and the command line."""

from __future__ import annotations

import json
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

import pointfield
from pointfield import FormatError, PointCloud
from pointfield.cli import main
from pointfield.clouds.formats import format_of, ptx
from pointfield.clouds.formats.ptx import looks_like_ptx

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from fuzzing import two_scan_ptx

IDENTITY = ["1 0 0", "0 1 0", "0 0 1", "1 0 0 0", "0 1 0 0", "0 0 1 0", "0 0 0 1"]


def ptx_file(tmp_path, text, name="scan.ptx"):
    path = tmp_path / name
    path.write_text(text)
    return path


def read_quietly(path, **options):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return pointfield.read(path, **options)


def scan_text(columns, rows, rows_text, position="0 0 0", pose=IDENTITY):
    return "\n".join([str(columns), str(rows), position, *pose, *rows_text]) + "\n"


# ---------------------------------------------------------------------------------------------
# Reading


def test_every_scan_is_read_with_its_transform_applied_and_a_scan_index(tmp_path):
    cloud = read_quietly(ptx_file(tmp_path, two_scan_ptx()))
    assert len(cloud) == 10 and cloud.points.dtype == np.float64
    np.testing.assert_array_equal(cloud.fields["scan_index"], [0] * 6 + [1] * 4)
    assert cloud.fields["scan_index"].dtype == np.uint8
    # The second scan's transform: rows x -> (0, 1, 0), y -> (-1, 0, 0), z -> z, then (10, 20, 30).
    second = cloud.points[cloud.fields["scan_index"] == 1]
    raw = np.array([[1, 2, 3], [7, 8, 9], [4, 5, 6], [-1, -2, -3]], np.float64)  # row-major grid
    np.testing.assert_array_equal(second, np.stack([-raw[:, 1], raw[:, 0], raw[:, 2]], 1) + [10, 20, 30])


def test_the_transform_is_read_as_pdal_reads_it_translation_in_the_fourth_row(tmp_path):
    # PDAL's multiple-and-transform.ptx: z doubled, then moved by (600000, 800000, 400).
    pose = ["1 0 0", "0 1 0", "0 0 2", "1 0 0 0", "0 1 0 0", "0 0 2 0", "600000 800000 400 1"]
    text = scan_text(1, 1, ["37012.24 49028.31 15.83 0.034912"], "600000 800000 400", pose)
    cloud = read_quietly(ptx_file(tmp_path, text))
    np.testing.assert_allclose(cloud.points, [[637012.24, 849028.31, 431.66]], rtol=0, atol=1e-9)


def test_cells_without_a_return_are_nan_points_that_keep_intensity_and_colour(tmp_path):
    cloud = read_quietly(ptx_file(tmp_path, two_scan_ptx()))
    first = cloud.points[:6]
    # Cell (column 1, row 0) of a 3 x 2 grid: row-major index 1.
    assert np.isnan(first[1]).all() and cloud.nan_count == 1
    assert cloud.fields["intensity"][1] == 0.5
    np.testing.assert_array_equal(cloud.fields["colors"][1], [0, 0, 0])


def test_a_single_scan_reads_as_its_grid_in_row_major_order(tmp_path):
    # 3 columns of 2 rows, listed column by column: value = 10 * column + row.
    rows = [f"{10 * c + r + 1} 1 1 0.5" for c in range(3) for r in range(2)]
    cloud = read_quietly(ptx_file(tmp_path, scan_text(3, 2, rows)))
    assert cloud.shape == (2, 3)
    grid = cloud.points[:, 0].reshape(cloud.shape)
    np.testing.assert_array_equal(grid, [[1, 11, 21], [2, 12, 22]])


def test_a_scan_of_one_row_is_not_organised(tmp_path):
    cloud = read_quietly(ptx_file(tmp_path, scan_text(3, 1, ["1 2 3 0.5"] * 3)))
    assert cloud.shape is None and len(cloud) == 3


def test_colours_are_uint8_and_intensity_float64(tmp_path):
    cloud = read_quietly(ptx_file(tmp_path, two_scan_ptx()))
    assert cloud.fields["colors"].dtype == np.uint8
    np.testing.assert_array_equal(cloud.fields["colors"][0], [10, 20, 30])
    assert cloud.fields["intensity"].dtype == np.float64


def test_each_scans_grid_pose_and_transform_are_recorded(tmp_path):
    cloud = read_quietly(ptx_file(tmp_path, two_scan_ptx()))
    first, second = cloud.metadata["ptx_scans"]
    assert (first["columns"], first["rows"], first["points"]) == (3, 2, 6)
    assert (second["columns"], second["rows"], second["points"]) == (2, 2, 4)
    assert second["scanner_position"] == [10, 20, 30]
    assert second["scanner_axes"] == [[0, 1, 0], [-1, 0, 0], [0, 0, 1]]
    assert second["transform"][3] == [10, 20, 30, 1]
    assert cloud.metadata["format"] == "ptx" and cloud.metadata["encoding"] == "text"
    json.dumps(cloud.metadata)  # plain numbers, so every writer with metadata can keep it


def test_crlf_lines_and_padded_values_read(tmp_path):
    text = scan_text(2, 1, ["1  2 3 0.5", "4 5\t6 0.25"]).replace("\n", "\r\n")
    cloud = read_quietly(ptx_file(tmp_path, text))
    np.testing.assert_array_equal(cloud.points, [[1, 2, 3], [4, 5, 6]])


@pytest.mark.parametrize("name", ["scan.txt", "scan.dat", "scan.pts"])
def test_the_signature_finds_ptx_whatever_the_suffix(tmp_path, name):
    path = ptx_file(tmp_path, two_scan_ptx(), name)
    assert format_of(path).name == "ptx"
    assert len(read_quietly(path)) == 10


@pytest.mark.parametrize(
    ("head", "expected"),
    [
        (b"3\n2\n0 0 0\n1 0 0\n", True),
        (b"1024\r\n512\r\n600000.000000 800000.000000 400.00", True),
        (b"8\n-0.037829 0.12794 0.004474\n", False),  # PTS: count line, then a row
        (b"1 2 3\n4 5 6\n", False),
        (b"3\n2\n0 0\n", False),
        (b"ply\nformat ascii 1.0\n", False),
    ],
)
def test_looks_like_ptx(head, expected):
    assert looks_like_ptx(head) is expected


# ---------------------------------------------------------------------------------------------
# Writing


def test_an_organised_scan_round_trips_with_its_grid_nan_points_and_colours(tmp_path):
    rng = np.random.default_rng(3)
    points = rng.normal(scale=20, size=(12, 3))
    points[[2, 7]] = np.nan
    cloud = PointCloud(
        points,
        {"intensity": rng.random(12), "colors": rng.integers(0, 256, (12, 3), dtype=np.uint8)},
        shape=(3, 4),
    )
    pointfield.write(tmp_path / "grid.ptx", cloud)
    back = read_quietly(tmp_path / "grid.ptx")
    assert back.shape == (3, 4)
    np.testing.assert_array_equal(back.points, points)
    np.testing.assert_array_equal(back.fields["intensity"], cloud.fields["intensity"])
    np.testing.assert_array_equal(back.fields["colors"], cloud.fields["colors"])


def test_several_scans_round_trip_with_their_grids_and_scanner_poses(tmp_path):
    cloud = read_quietly(ptx_file(tmp_path, two_scan_ptx()))
    pointfield.write(tmp_path / "again.ptx", cloud)
    back = read_quietly(tmp_path / "again.ptx")
    np.testing.assert_array_equal(back.points, cloud.points)
    np.testing.assert_array_equal(back.fields["scan_index"], cloud.fields["scan_index"])
    np.testing.assert_array_equal(back.fields["colors"], cloud.fields["colors"])
    for before, after in zip(cloud.metadata["ptx_scans"], back.metadata["ptx_scans"], strict=True):
        for key in ("columns", "rows", "scanner_position", "scanner_axes"):
            assert after[key] == before[key]
        assert after["transform"] == np.eye(4).tolist()  # the points are already transformed


def test_a_cloud_from_another_format_is_one_row_without_intensity_warned(tmp_path):
    points = np.arange(15, dtype=np.float32).reshape(5, 3) + 0.25
    with pytest.warns(UserWarning, match="need an intensity; written as 0"):
        pointfield.write(tmp_path / "plain.ptx", PointCloud(points))
    back = read_quietly(tmp_path / "plain.ptx")
    assert back.shape is None and back.metadata["ptx_scans"][0]["columns"] == 5
    np.testing.assert_array_equal(back.points, points.astype(np.float64))
    np.testing.assert_array_equal(back.fields["intensity"], np.zeros(5))


def test_fields_ptx_cannot_hold_are_named_in_one_warning(tmp_path):
    cloud = PointCloud(
        np.ones((3, 3)),
        {"intensity": np.ones(3), "normals": np.ones((3, 3)), "label": np.arange(3)},
    )
    with pytest.warns(UserWarning, match="'normals', 'label' were not written") as caught:
        pointfield.write(tmp_path / "drop.ptx", cloud)
    assert len(caught) == 1


def test_a_point_at_the_origin_is_warned_about(tmp_path):
    cloud = PointCloud(np.array([[0.0, 0, 0], [1, 2, 3]]), {"intensity": np.ones(2)})
    with pytest.warns(UserWarning, match="1 points at exactly 0 0 0"):
        pointfield.write(tmp_path / "origin.ptx", cloud)
    assert np.isnan(read_quietly(tmp_path / "origin.ptx").points[0]).all()


def test_las_colours_are_written_as_0_to_255(tmp_path):
    colors = np.array([[65535, 0, 257], [257 * 128, 514, 0]], np.uint16)
    cloud = PointCloud(np.ones((2, 3)), {"intensity": np.ones(2), "colors": colors})
    with pytest.warns(UserWarning, match=r"colors uint16 -> 0..255"):
        pointfield.write(tmp_path / "las.ptx", cloud)
    np.testing.assert_array_equal(
        read_quietly(tmp_path / "las.ptx").fields["colors"], [[255, 0, 1], [128, 2, 0]]
    )


def test_the_write_is_atomic_a_write_failing_midway_leaves_the_old_file(tmp_path, monkeypatch):
    path = ptx_file(tmp_path, two_scan_ptx())

    def fail(file, *args, **kwargs):  # after the scan header is written
        raise FormatError(file.name, "the disk is full")

    monkeypatch.setattr(ptx, "write_rows", fail)
    with pytest.raises(FormatError, match="the disk is full"):
        pointfield.write(path, PointCloud(np.ones((2, 3)), {"intensity": np.ones(2)}))
    assert path.read_text() == two_scan_ptx()
    assert [p.name for p in tmp_path.iterdir()] == [path.name]


# ---------------------------------------------------------------------------------------------
# Hostile and malformed files: each a FormatError naming the file, before any large allocation

HOSTILE = {
    "grid larger than the file": scan_text(1_000_000_000, 1_000_000_000, ["1 2 3 0.5"]),
    "fewer rows than the grid": scan_text(2, 2, ["1.25 2.25 3.25 0.5"] * 3),
    "header cut short": "3\n2\n0 0 0\n1 0 0\n",
    "negative columns": scan_text(-2, 1, ["1 2 3 0.5"] * 2),
    "transform row of three numbers": scan_text(1, 1, ["1 2 3 0.5"], pose=[*IDENTITY[:6], "0 0 0"]),
    "infinite transform": scan_text(1, 1, ["1 2 3 0.5"], pose=[*IDENTITY[:6], "inf 0 0 1"]),
    "rows of five values": scan_text(1, 1, ["1 2 3 0.5 7"]),
    "rows of 7 then 4 values": scan_text(2, 1, ["1 2 3 0.5 1 2 3", "1 2 3 0.5"]),
    "colour above 255": scan_text(1, 2, ["1 2 3 0.5 1 2 3", "1 2 3 0.5 1 2 300"]),
    "a word among the values": scan_text(2, 1, ["1 2 3 0.5", "1 two 3 0.5"]),
    "a blank line inside a scan": scan_text(3, 1, ["1 2 3 0.5", "", "1 2 3 0.5"]),
    "garbage after the last scan": scan_text(1, 1, ["1 2 3 0.5"]) + "end of file\n",
    "a header line of a megabyte": "1" * (1 << 20) + "\n",
    "empty file": "",
}


@pytest.mark.parametrize("text", HOSTILE.values(), ids=HOSTILE.keys())
def test_hostile_files_are_format_errors_naming_the_file(tmp_path, text):
    path = ptx_file(tmp_path, text)
    with pytest.raises(FormatError) as error:
        pointfield.read(path, format="ptx")
    assert str(path) in str(error.value)


def test_an_error_names_the_line(tmp_path):
    path = ptx_file(tmp_path, scan_text(2, 1, ["1 2 3 0.5", "1 two 3 0.5"]))
    with pytest.raises(FormatError, match="line 12"):
        pointfield.read(path)


# ---------------------------------------------------------------------------------------------
# The command line


def test_cloud_info_describes_a_ptx_scan(tmp_path, capsys):
    assert main(["cloud", "info", str(ptx_file(tmp_path, two_scan_ptx())), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["format"] == "ptx" and info["points"] == 10 and info["nan_points"] == 1
    assert {"intensity", "colors", "scan_index"} <= set(info["fields"])


def test_cloud_convert_reads_and_writes_ptx(tmp_path, capsys):
    source = ptx_file(tmp_path, two_scan_ptx())
    assert main(["cloud", "convert", str(source), str(tmp_path / "scan.ply")]) == 0
    assert "wrote" in capsys.readouterr().out
    ply = read_quietly(tmp_path / "scan.ply")
    np.testing.assert_array_equal(ply.fields["scan_index"], read_quietly(source).fields["scan_index"])
    assert main(["cloud", "convert", str(tmp_path / "scan.ply"), str(tmp_path / "back.ptx")]) == 0
    back = read_quietly(tmp_path / "back.ptx")
    np.testing.assert_array_equal(back.points, read_quietly(source).points)


def test_cloud_info_of_a_broken_ptx_is_one_line(tmp_path, capsys):
    path = ptx_file(tmp_path, scan_text(2, 2, ["1.25 2.25 3.25 0.5"] * 3))
    assert main(["cloud", "info", str(path)]) == 1
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and str(path) in lines[0] and "only 3 rows follow" in lines[0]
