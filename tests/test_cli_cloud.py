"""`pointfield cloud info / convert / render`, errors as one line, --help and --version."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

import pointfield
from pointfield.cli import main
from pointfield.clouds import synthetic
from pointfield.clouds.cloud import same_fields

INFO_KEYS = {
    "path",
    "format",
    "encoding",
    "points",
    "nan_points",
    "fields",
    "bounds",
    "faces",
    "organised",
    "metadata",
    "bytes",
}


def _info(capsys, *args) -> dict:
    assert main(["cloud", "info", *map(str, args), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def _expect_one_line_error(capsys, argv, *fragments):
    assert main([str(a) for a in argv]) == 1
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    assert lines[0].startswith("pointfield: error:")
    assert "Traceback" not in captured.err
    assert captured.out == ""
    for fragment in fragments:
        assert str(fragment) in lines[0]


def test_version(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out.strip() == f"pointfield {pointfield.__version__}"


@pytest.mark.parametrize(
    "argv", [["--help"], ["cloud", "--help"], ["cloud", "render", "--help"], ["demo", "--help"]]
)
def test_help(capsys, argv):
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 0
    assert "usage: pointfield" in capsys.readouterr().out


def test_help_lists_the_verb_groups(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    out = capsys.readouterr().out
    assert "cloud" in out and "demo" in out


def test_info_json_of_an_organised_cloud_with_nan(shared_data, capsys):
    info = _info(capsys, shared_data / "pcd/pcl_table_scene_mug_organized.pcd")
    assert INFO_KEYS <= info.keys()
    assert info["format"] == "pcd" and info["encoding"] == "binary_compressed"
    assert info["points"] == 307200
    assert info["nan_points"] == 97920
    assert info["organised"] == [480, 640]
    assert info["fields"] == {"colors": "uint8"}
    assert info["field_components"]["colors"] in (3, 4)
    assert info["faces"] == 0
    assert info["bounds"]["min"][2] == pytest.approx(0.69001, abs=1e-4)
    assert info["bytes"] == (shared_data / "pcd/pcl_table_scene_mug_organized.pcd").stat().st_size


def test_info_json_of_a_mesh_counts_faces(shared_data, capsys):
    info = _info(capsys, shared_data / "modelnet/ModelNet10/chair/train/chair_0001.off")
    assert info["format"] == "off" and info["kind"] == "mesh"
    assert (info["points"], info["faces"]) == (2382, 2234)
    assert len(info["bounds"]["min"]) == 3


def test_info_json_of_records_without_coordinates(shared_data, capsys):
    info = _info(capsys, shared_data / "pcd/pcl_brisk_descriptors_count64.pcd")
    assert info["kind"] == "records" and info["points"] == 1534
    assert info["bounds"] is None and info["nan_points"] == 0
    assert info["fields"]["brisk_descriptor512"] == "uint8"
    assert info["field_components"]["brisk_descriptor512"] == 64


def test_info_json_keeps_las_coordinates_in_double_precision(shared_data, capsys):
    info = _info(capsys, shared_data / "las/simple.las")
    assert info["points"] == 1065 and info["points_dtype"] == "float64"
    assert info["bounds"]["min"][0] == pytest.approx(635619.85, abs=1e-6)
    assert info["metadata"]["scales"] == [0.01, 0.01, 0.01]


def test_info_columns_reads_a_scan_of_another_layout(shared_data, capsys):
    path = shared_data / "other_pointclouds/scannet_scene0000_00_xyzrgb.bin"
    info = _info(capsys, path, "--columns", "6")
    assert info["points"] == 40684 and "colors" in info["fields"]


def test_columns_is_refused_for_a_format_without_it(shared_data, capsys):
    path = shared_data / "ply/pcl_cube_binary_le.ply"
    _expect_one_line_error(capsys, ["cloud", "info", path, "--columns", "5"], path, "--columns")


def test_info_text_is_aligned_lines(shared_data, capsys):
    assert main(["cloud", "info", str(shared_data / "pcd/pcl_table_scene_mug_organized.pcd")]) == 0
    lines = capsys.readouterr().out.splitlines()
    by_label = {line.split()[0]: line for line in lines if line and not line[0].isspace()}
    assert "307,200" in by_label["points"] and "97,920 NaN" in by_label["points"]
    assert "organised 480 x 640" in by_label["points"]
    assert "binary_compressed" in by_label["format"]
    assert "colors" in by_label["fields"]
    starts = {
        len(line) - len(line[len(line.split()[0]) :].lstrip())
        for line in lines
        if line and not line[0].isspace()
    }
    assert len(starts) == 1  # every value starts in the same column


def test_convert_preserves_points_and_fields(tmp_path, capsys):
    source = tmp_path / "cloud.ply"
    cloud = synthetic.lidar_scan(8, 128, seed=0)
    pointfield.write(source, cloud)
    for flag, suffix, encoding in [
        ("--compressed", "pcd", "binary_compressed"),
        ("--ascii", "ply", "ascii"),
    ]:
        out = tmp_path / f"converted.{suffix}"
        assert main(["cloud", "convert", str(source), str(out), flag]) == 0
        printed = capsys.readouterr().out
        assert str(out) in printed and encoding in printed and "intensity" in printed
        back = pointfield.read(out)
        assert back.metadata["encoding"] == encoding
        assert np.array_equal(back.points, cloud.points)
        assert same_fields(back.fields, cloud.fields)


def test_convert_real_file_keeps_every_field(shared_data, tmp_path, capsys):
    source = shared_data / "pcd/pcl_colored_cloud_binary.pcd"
    out = tmp_path / "colored.ply"
    assert main(["cloud", "convert", str(source), str(out), "--binary"]) == 0
    original, back = pointfield.read(source), pointfield.read(out)
    assert np.array_equal(original.points, back.points)
    assert same_fields(original.fields, back.fields)


def test_convert_names_what_the_target_cannot_hold_in_one_warning_line(tmp_path, capsys):
    source = tmp_path / "mesh.ply"
    pointfield.write(source, synthetic.icosphere(1))
    assert main(["cloud", "convert", str(source), str(tmp_path / "mesh.pcd")]) == 0
    err = capsys.readouterr().err
    assert err.startswith("pointfield: warning:") and "faces" in err
    assert "Traceback" not in err and "warnings.warn" not in err


def test_convert_to_an_unknown_format_is_one_line_error(tmp_path, capsys):
    source = tmp_path / "cloud.ply"
    pointfield.write(source, synthetic.sphere(10))
    target = tmp_path / "cloud.unknown"
    _expect_one_line_error(capsys, ["cloud", "convert", source, target], target)


def test_render_writes_a_png_of_the_requested_size(shared_data, tmp_path, capsys):
    out = tmp_path / "bunny.png"
    argv = [
        "cloud",
        "render",
        str(shared_data / "pcd/pcl_bunny_ascii.pcd"),
        "--out",
        str(out),
        "--width",
        "200",
        "--height",
        "150",
    ]
    assert main(argv) == 0
    assert str(out) in capsys.readouterr().out
    with Image.open(out) as png:
        assert png.size == (200, 150)
        pixels = np.asarray(png.convert("RGB"))
    not_background = (pixels != 255).any(axis=2).mean()
    assert 0.05 < not_background < 0.95
    assert len(np.unique(pixels.reshape(-1, 3), axis=0)) > 20  # coloured and shaded, not flat


def test_render_options(shared_data, tmp_path):
    path = shared_data / "kitti/mmdet3d_demo/000008.bin"
    images = {}
    for name, options in {
        "default": [],
        "height": ["--color-by", "height"],
        "x_up": ["--up", "x"],
    }.items():
        out = tmp_path / f"{name}.png"
        assert (
            main(
                [
                    "cloud",
                    "render",
                    str(path),
                    "--out",
                    str(out),
                    "--width",
                    "120",
                    "--height",
                    "90",
                    *options,
                ]
            )
            == 0
        )
        images[name] = np.asarray(Image.open(out))
    assert not np.array_equal(images["default"], images["height"])
    assert not np.array_equal(images["default"], images["x_up"])


def test_render_by_a_missing_field_is_one_line_error(shared_data, tmp_path, capsys):
    path = shared_data / "pcd/pcl_bunny_ascii.pcd"
    argv = ["cloud", "render", path, "--out", tmp_path / "x.png", "--color-by", "nosuch"]
    _expect_one_line_error(capsys, argv, path, "nosuch")
    assert not (tmp_path / "x.png").exists()


def test_render_of_records_is_one_line_error(shared_data, tmp_path, capsys):
    path = shared_data / "pcd/pcl_brisk_descriptors_count64.pcd"
    _expect_one_line_error(capsys, ["cloud", "render", path, "--out", tmp_path / "x.png"], path)


@pytest.mark.parametrize("command", ["info", "render", "convert"])
def test_a_broken_file_is_one_line_error_naming_it(tmp_path, capsys, command):
    path = tmp_path / "broken.pcd"
    header = b"# .PCD v0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nPOINTS 1000000000\nDATA binary\n"
    path.write_bytes(header + b"\x00\x01")  # claims a billion points, holds two bytes
    argv = {
        "info": ["cloud", "info", path],
        "render": ["cloud", "render", path, "--out", tmp_path / "x.png"],
        "convert": ["cloud", "convert", path, tmp_path / "x.ply"],
    }[command]
    _expect_one_line_error(capsys, argv, path)


def test_random_bytes_are_one_line_error(tmp_path, capsys):
    path = tmp_path / "noise.ply"
    path.write_bytes(np.random.default_rng(0).bytes(512))
    _expect_one_line_error(capsys, ["cloud", "info", path, "--json"], path)


def test_a_missing_file_is_one_line_error(tmp_path, capsys):
    path = tmp_path / "nowhere.ply"
    _expect_one_line_error(capsys, ["cloud", "info", path], path)
