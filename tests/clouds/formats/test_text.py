"""XYZ / TXT / PTS / CSV: layouts, headers, count lines, value round trips, hostile text."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import pointfield
from pointfield import FormatError, PointCloud

# (file under xyz_pts/, points, fields and their dtypes) — counts from MANIFEST.md.
REAL_FILES = [
    ("trimesh_points_cloudcompare.xyz", 101, {"colors": ("float64", (4,))}),
    ("trimesh_points_agisoft.xyz", 100, {"colors": ("uint8", (3,))}),
    ("pdal_gdal_data.xyz", 400, {}),
    ("pdal_autzen.pts", 10, {"intensity": ("float64", ()), "colors": ("uint8", (3,))}),
    ("pdal_test.pts", 19, {"intensity": ("float64", ()), "colors": ("uint8", (3,))}),
]


def read_quietly(path, **options):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return pointfield.read(path, **options)


def write_bytes(tmp_path, name, data):
    path = tmp_path / name
    path.write_bytes(data)
    return path


@pytest.mark.parametrize(("name", "count", "fields"), REAL_FILES, ids=[r[0] for r in REAL_FILES])
def test_real_files_read_with_their_manifest_count_and_fields(shared_data, name, count, fields):
    cloud = read_quietly(shared_data / "xyz_pts" / name)
    assert len(cloud) == count
    assert cloud.points.dtype == np.float64
    assert cloud.metadata == {"format": "text", "encoding": "text"}
    assert {k: (str(v.dtype), v.shape[1:]) for k, v in cloud.fields.items()} == fields


def test_leica_pts_rows_are_x_y_z_intensity_red_green_blue(shared_data):
    cloud = pointfield.read(shared_data / "xyz_pts" / "pdal_test.pts")
    np.testing.assert_array_equal(cloud.points[0], [3.980972, -2.006119, -0.010086])
    assert cloud.fields["intensity"][0] == -1035
    np.testing.assert_array_equal(cloud.fields["colors"][0], [97, 59, 38])


def test_pts_reads_the_points_its_count_line_declares_and_warns_of_the_rest(shared_data):
    # PDAL's bunny_8.pts declares 8 points over 9 rows; PDAL's tests read 8, and so do we.
    with pytest.warns(UserWarning, match="count line says 8 points but 9 rows follow; the first 8"):
        cloud = pointfield.read(shared_data / "xyz_pts" / "pdal_bunny_8.pts")
    assert len(cloud) == 8
    np.testing.assert_array_equal(cloud.points[0], [-0.037829, 0.12794, 0.004474])
    rows = (shared_data / "xyz_pts" / "pdal_bunny_8.pts").read_text().split("\n")[1:9]
    np.testing.assert_array_equal(cloud.points[-1], [float(v) for v in rows[-1].split()])


def test_pts_rows_beyond_the_count_line_are_dropped_with_their_fields(tmp_path):
    path = tmp_path / "extra.pts"
    path.write_text("2\n1 2 3 10 255 0 0\n4 5 6 20 0 255 0\n7 8 9 30 0 0 255\n")
    with pytest.warns(UserWarning, match="the first 2 were read"):
        cloud = pointfield.read(path)
    np.testing.assert_array_equal(cloud.points, [[1, 2, 3], [4, 5, 6]])
    np.testing.assert_array_equal(cloud.fields["intensity"], [10, 20])
    np.testing.assert_array_equal(cloud.fields["colors"], [[255, 0, 0], [0, 255, 0]])


def test_cloudcompare_float_colours_with_alpha_stay_float(shared_data):
    cloud = pointfield.read(shared_data / "xyz_pts" / "trimesh_points_cloudcompare.xyz")
    np.testing.assert_array_equal(cloud.fields["colors"][0], [117.0, 73.0, 49.0, 255.0])


@pytest.mark.parametrize(
    ("rows", "suffix", "fields"),
    [
        ("1 2 3", ".xyz", {}),
        ("1 2 3 4", ".xyz", {"intensity": ()}),
        ("1 2 3 4 5 6", ".xyz", {"colors": (3,)}),
        ("1 2 3 4 5 6", ".xyzn", {"normals": (3,)}),
        ("1 2 3 4 5 6 7", ".xyz", {"colors": (4,)}),
        ("1 2 3 4 5 6 7", ".pts", {"intensity": (), "colors": (3,)}),
        ("1 2 3 4 5", ".txt", {"field_3": (), "field_4": ()}),
        ("1 2 3 4 5 6 7 8", ".txt", {f"field_{i}": () for i in range(3, 8)}),
    ],
)
def test_without_names_the_row_width_and_suffix_pick_the_layout(tmp_path, rows, suffix, fields):
    cloud = read_quietly(write_bytes(tmp_path, "cloud" + suffix, f"{rows}\n{rows}\n".encode()))
    assert {k: v.shape[1:] for k, v in cloud.fields.items()} == fields
    np.testing.assert_array_equal(cloud.points, [[1, 2, 3], [1, 2, 3]])


@pytest.mark.parametrize(
    "header",
    ["//X,Y,Z,R,G,B", "# x y z red green blue", "x,y,z,red,green,blue", "// X Y Z R G B"],
)
def test_a_header_line_names_the_columns(tmp_path, header):
    separator = "," if "," in header else " "
    row = separator.join(["6", "5", "4", "3", "2", "1"])
    cloud = read_quietly(write_bytes(tmp_path, "named.txt", f"{header}\n{row}\n".encode()))
    np.testing.assert_array_equal(cloud.points, [[6, 5, 4]])
    np.testing.assert_array_equal(cloud.fields["colors"], [[3, 2, 1]])
    assert cloud.fields["colors"].dtype == np.uint8


def test_a_header_can_put_columns_in_any_order(tmp_path):
    path = write_bytes(tmp_path, "order.csv", b"intensity,z,y,x\n9,3,2,1\n")
    cloud = read_quietly(path)
    np.testing.assert_array_equal(cloud.points, [[1, 2, 3]])
    np.testing.assert_array_equal(cloud.fields["intensity"], [9])


def test_a_comment_that_does_not_name_x_y_z_is_just_a_comment(tmp_path):
    path = write_bytes(tmp_path, "c.xyz", b"# exported by a scanner\n# a b c d\n1 2 3 4\n")
    assert set(read_quietly(path).fields) == {"intensity"}


def test_the_columns_option_overrides_header_and_layout(tmp_path):
    path = write_bytes(tmp_path, "o.xyz", b"# x y z red green blue\n1 2 3 4 5 6\n")
    cloud = read_quietly(path, columns="x,y,z,nx,ny,nz")
    np.testing.assert_array_equal(cloud.fields["normals"], [[4, 5, 6]])
    cloud = read_quietly(path, columns=["z", "y", "x", "a", "b", "label"])
    np.testing.assert_array_equal(cloud.points, [[3, 2, 1]])
    assert set(cloud.fields) == {"a", "b", "label"}


@pytest.mark.parametrize(
    "text",
    [
        b"1 2 3\n4 5 6\n",
        b"1  2   3\n  4 5 6  \n",
        b"1\t2\t3\n4\t5\t6",
        b"1 2 3\r\n4 5 6\r\n",
        b"1,2,3\n4,5,6\n",
        b"1, 2, 3\n4, 5, 6\n",
        b"1;2;3\n4;5;6\n",
        b"\n1 2 3\n\n4 5 6\n\n",
        b"\xef\xbb\xbf1 2 3\n4 5 6\n",
    ],
)
def test_separators_blank_lines_and_line_ends_all_read(tmp_path, text):
    cloud = read_quietly(write_bytes(tmp_path, "s.xyz", text))
    np.testing.assert_array_equal(cloud.points, [[1, 2, 3], [4, 5, 6]])


def test_six_unnamed_columns_of_unit_vectors_are_normals(tmp_path):
    # modelnet40_normal_resampled rows: x,y,z,nx,ny,nz without a header.
    rows = b"0.1,0.2,0.3,0.0,-0.6,0.8\n0.4,0.5,0.6,1.0,0.0,0.0\n"
    cloud = read_quietly(write_bytes(tmp_path, "airplane_0001.txt", rows))
    np.testing.assert_array_equal(cloud.fields["normals"], [[0, -0.6, 0.8], [1, 0, 0]])
    colours = b"0 0 0 1.0 0.0 0.0\n0 0 0 0.0 1.0 0.0\n"
    assert set(read_quietly(write_bytes(tmp_path, "rgb.txt", colours)).fields) == {"colors"}


def test_a_delimiter_closing_every_row_opens_no_column(tmp_path):
    cloud = read_quietly(write_bytes(tmp_path, "trailing.csv", b"1,2,3,\n4,5,6,\n"))
    np.testing.assert_array_equal(cloud.points, [[1, 2, 3], [4, 5, 6]])


def test_integer_colours_above_255_read_as_uint16(tmp_path):
    cloud = read_quietly(write_bytes(tmp_path, "c16.xyz", b"0 0 0 1000 2 65535\n"))
    assert cloud.fields["colors"].dtype == np.uint16


def test_colours_with_a_fraction_anywhere_stay_float(tmp_path):
    cloud = read_quietly(write_bytes(tmp_path, "cf.xyz", b"0 0 0 1 2 3\n0 0 0 1 2 3.5\n"))
    assert cloud.fields["colors"].dtype == np.float64


def test_nan_and_infinity_are_values(tmp_path):
    cloud = read_quietly(write_bytes(tmp_path, "n.xyz", b"nan 1 2\ninf -inf 3\n"))
    assert np.isnan(cloud.points[0, 0]) and cloud.points[1, 0] == np.inf
    assert cloud.nan_count == 1


def test_a_count_line_and_a_header_together(tmp_path):
    cloud = read_quietly(
        write_bytes(tmp_path, "ch.pts", b"2\n# x y z intensity\n1 2 3 4\n5 6 7 8\n")
    )
    np.testing.assert_array_equal(cloud.fields["intensity"], [4, 8])


# ---------------------------------------------------------------------------------------------
# Round trips


def sample_cloud(n=30, points_dtype=np.float32):
    rng = np.random.default_rng(3)
    points = rng.normal(scale=1000, size=(n, 3)).astype(points_dtype)
    points[0] = [np.nan, np.inf, -np.inf]
    points[1] = [0.1, -0.0, 1e-30]
    return PointCloud(
        points,
        {
            "colors": rng.integers(0, 256, (n, 3), dtype=np.uint8),
            "normals": rng.normal(size=(n, 3)).astype(np.float32),
            "intensity": rng.random(n),
            "label": rng.integers(-5, 5, n).astype(np.int32),
            "descriptor": rng.random((n, 4)).astype(np.float32),
        },
    )


@pytest.mark.parametrize("suffix", [".xyz", ".txt", ".csv", ".xyzn", ".xyzrgb"])
@pytest.mark.parametrize("points_dtype", [np.float32, np.float64])
def test_write_then_read_gives_every_value_back_as_float64(tmp_path, suffix, points_dtype):
    cloud = sample_cloud(points_dtype=points_dtype)
    pointfield.write(tmp_path / f"round{suffix}", cloud)
    back = read_quietly(tmp_path / f"round{suffix}")
    np.testing.assert_array_equal(back.points, cloud.points.astype(np.float64))
    assert set(back.fields) == set(cloud.fields)
    assert back.fields["colors"].dtype == np.uint8
    for name, values in cloud.fields.items():
        assert back.fields[name].shape == values.shape
        np.testing.assert_array_equal(back.fields[name], values.astype(back.fields[name].dtype))


def test_csv_is_written_with_a_bare_header_and_xyz_with_a_comment_header(tmp_path):
    cloud = PointCloud(np.zeros((1, 3)), {"intensity": np.ones(1)})
    pointfield.write(tmp_path / "h.csv", cloud)
    pointfield.write(tmp_path / "h.xyz", cloud)
    assert (tmp_path / "h.csv").read_text().splitlines() == ["x,y,z,intensity", "0,0,0,1"]
    assert (tmp_path / "h.xyz").read_text().splitlines() == ["# x y z intensity", "0 0 0 1"]


def test_pts_is_written_as_leica_count_line_and_rows_dropping_other_fields(tmp_path):
    cloud = sample_cloud()
    with pytest.warns(UserWarning, match="'normals', 'label', 'descriptor'"):
        pointfield.write(tmp_path / "leica.pts", cloud)
    assert (tmp_path / "leica.pts").read_text().splitlines()[0] == str(len(cloud))
    back = read_quietly(tmp_path / "leica.pts")
    np.testing.assert_array_equal(back.points, cloud.points.astype(np.float64))
    np.testing.assert_array_equal(back.fields["intensity"], cloud.fields["intensity"])
    np.testing.assert_array_equal(back.fields["colors"], cloud.fields["colors"])


def test_an_empty_cloud_round_trips(tmp_path):
    empty = PointCloud(np.zeros((0, 3), np.float32), {"intensity": np.zeros(0)})
    for suffix in (".xyz", ".csv", ".pts"):
        pointfield.write(tmp_path / f"empty{suffix}", empty)
        back = read_quietly(tmp_path / f"empty{suffix}")
        assert len(back) == 0


def test_fields_text_cannot_hold_are_left_out_with_a_warning(tmp_path):
    cloud = PointCloud(np.zeros((2, 3)), {"name": np.array(["a", "b"]), "bad name": np.ones(2)})
    with pytest.warns(UserWarning, match="'name', 'bad name'"):
        pointfield.write(tmp_path / "w.xyz", cloud)
    assert read_quietly(tmp_path / "w.xyz").fields == {}


# ---------------------------------------------------------------------------------------------
# Hostile input: each is a FormatError naming the file


HOSTILE = {
    "empty": b"",
    "only blank lines": b"\n\n  \n",
    "random bytes": bytes(np.random.default_rng(0).integers(0, 256, 600, dtype=np.uint8)),
    "count line larger than the rows": b"1000000000000\n1 2 3\n",
    "negative count": b"-5\n1 2 3\n",
    "a row with too few values": b"1 2 3\n4 5\n6 7 8\n",
    "a row with too many values": b"1,2,3\n4,5,6,7\n",
    "an empty value": b"1,2,3\n4,,6\n",
    "a word among the numbers": b"1 2 3\n4 five 6\n",
    "two values per row": b"1 2\n3 4\n",
    "a header that names other columns": b"x y z\n1 2 3 4\n",
    "a header without x y z": b"a,b,c\n1,2,3\n",
    "a header naming a column twice": b"x y z z\n1 2 3 4\n",
    "text after the rows": b"1 2 3\nthe end\n",
    "a NUL inside a number": b"1 2 3\n4 5\x006\n",
    "only comments": b"# nothing here\n",
    "no rows in the first thousand lines": b"# c\n" * 1001 + b"1 2 3\n",
    "one line of two megabytes": b"1 " * 1_000_000,
    "twenty thousand values per row": b"1 " * 20_000 + b"\n",
}


@pytest.mark.parametrize("data", HOSTILE.values(), ids=HOSTILE.keys())
def test_hostile_text_is_a_format_error_naming_the_file(tmp_path, data):
    path = write_bytes(tmp_path, "hostile.xyz", data)
    with pytest.raises(FormatError) as error:
        pointfield.read(path)
    assert str(path) in str(error.value)


def test_errors_in_rows_name_the_line(tmp_path):
    path = write_bytes(tmp_path, "line.xyz", b"# x y z\n1 2 3\n4 5 6\n7 8\n")
    with pytest.raises(FormatError, match="line 4 has 2 values"):
        pointfield.read(path)
    path = write_bytes(tmp_path, "token.xyz", b"1 2 3\n4  5 6x\n")
    with pytest.raises(FormatError, match="line 2: b'6x' is not a number"):
        pointfield.read(path)


def test_a_columns_option_of_the_wrong_length_is_a_format_error(tmp_path):
    path = write_bytes(tmp_path, "cols.xyz", b"1 2 3 4\n")
    with pytest.raises(FormatError, match="names 3 columns"):
        pointfield.read(path, columns="x,y,z")
