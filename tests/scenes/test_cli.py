"""``pointfield scene info|convert|cameras|make``: thin layers over the Python functions."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from pointfield.cli import build_parser, main
from pointfield.scenes import read_scene, scene_info


def test_info_json_has_the_documented_keys(capsys, cube_dataset):
    assert main(["scene", "info", str(cube_dataset), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert {"format", "frames", "width", "height", "fx", "fy", "camera_model", "points"} <= set(info)
    assert info["format"] == "blender" and info["frames"] == 12 and info["points"] == 0
    assert (info["width"], info["height"], info["camera_model"]) == (32, 32, "PINHOLE")
    assert info == scene_info(cube_dataset)


def test_info_on_the_fox_counts_frames_with_images_and_prints_one_warning(capsys, shared_data):
    assert main(["scene", "info", str(shared_data / "nerf/fox_instant_ngp"), "--json"]) == 0
    captured = capsys.readouterr()
    info = json.loads(captured.out)
    assert (info["frames"], info["frames_listed"]) == (50, 67)
    assert (info["fx"], info["fy"], info["camera_model"]) == (1375.52, 1374.49, "OPENCV")
    assert captured.err.count("pointfield: warning:") == 1 and "17 of 67" in captured.err


def test_info_text_summarises_a_colmap_model(capsys, shared_data):
    assert main(["scene", "info", str(shared_data / "colmap/tiny_phone_scene"), "--format", "colmap"]) == 0
    out = capsys.readouterr().out
    assert "colmap scene" in out and "points    256" in out and "OPENCV" in out


def test_info_on_a_bad_dataset_prints_one_error_line_and_fails(capsys, tmp_path):
    (tmp_path / "transforms.json").write_text("{ not json")
    assert main(["scene", "info", str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("pointfield: error: ") and "transforms.json: malformed JSON" in err
    assert err.count("\n") == 1


def test_convert_writes_nerfstudio_then_blender(capsys, tmp_path, cube_dataset):
    assert main(["scene", "convert", str(cube_dataset), str(tmp_path / "ns")]) == 0
    assert (
        main(
            [
                "scene",
                "convert",
                str(tmp_path / "ns"),
                str(tmp_path / "bl"),
                "--format",
                "blender",
                "--downscale",
                "2",
            ]
        )
        == 0
    )
    back = read_scene(tmp_path / "bl")
    assert back.metadata["format"] == "blender" and back.cameras.width[0].item() == 16
    assert main(["scene", "convert", str(cube_dataset), str(tmp_path / "ns")]) == 1  # exists, no --overwrite
    assert "not empty" in capsys.readouterr().err


def test_cameras_draws_a_png(tmp_path, shared_data):
    out = tmp_path / "cams.png"
    assert (
        main(["scene", "cameras", str(shared_data / "colmap/tiny_phone_scene/sparse/0"), "--out", str(out)])
        == 0
    )
    with Image.open(out) as picture:
        assert picture.format == "PNG" and picture.size[0] >= 600
        pixels = np.asarray(picture.convert("RGB"))
    assert pixels.std() > 10  # something was drawn


def test_make_writes_the_cube_dataset(capsys, tmp_path):
    out = tmp_path / "cube"
    assert main(["scene", "make", "cube", "--views", "5", "--size", "16", "--out", str(out)]) == 0
    assert "5 views of 16x16" in capsys.readouterr().out
    scene = read_scene(out)
    assert len(scene) == 5 and scene.depth(0).shape == (16, 16)
    assert len(np.unique(scene.alpha(0))) > 2  # 2 x 2 rays per pixel by default: soft silhouettes


def test_make_with_one_ray_per_pixel_gives_hard_silhouettes(tmp_path):
    from pointfield.scenes.synthetic import SUPERSAMPLING

    out = tmp_path / "cube"
    assert main(["scene", "make", "cube", "--views", "3", "--size", "16", "--supersampling", "1", "--out", str(out)]) == 0
    assert set(np.unique(read_scene(out).alpha(0))) == {0.0, 1.0}
    # The command repeats the library's default so that `pointfield --help` does not import torch.
    arguments = build_parser().parse_args(["scene", "make", "cube", "--out", str(out)])
    assert arguments.supersampling == SUPERSAMPLING


@pytest.mark.parametrize("argv", [["scene"], ["scene", "make", "teapot", "--out", "x"], ["scene", "info"]])
def test_bad_command_lines_are_usage_errors(argv):
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2


@pytest.mark.parametrize("flag", ["--no-progress", "--quiet"])
def test_posing_takes_no_progress_as_every_command_does_and_still_takes_quiet(flag):
    for verb in (["from-images", "photos"], ["from-video", "clip.mp4"]):
        assert build_parser().parse_args(["scene", *verb, "--out", "scene", flag]).progress is False
        assert build_parser().parse_args(["scene", *verb, "--out", "scene"]).progress is True
