"""What a new scene run chooses for the user: held-out views (every 8th) and image size (``--downscale auto``)."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import torch

from pointfield.errors import PointfieldError
from pointfield.fields.run import evaluate
from pointfield.fields.train import train
from pointfield.scenes import Frame, Scene, SceneError, synthetic_scene, write_scene
from pointfield.scenes.synthetic import synthetic_cameras
from pointfield.scenes.training_defaults import auto_downscale, choose_scene_defaults

TINY = {"model": "tiny", "batch_rays": 64, "steps": 2, "eval_every": 2, "device": "cpu", "progress": False,
        "model_options": {"samples": 4}}


@pytest.fixture(scope="module")
def posed_photos(tmp_path_factory):
    """Sixteen 8 x 8 views with no test or val split, as a folder of posed photos has."""
    scene = synthetic_scene("cube", views=16, size=8)
    scene = replace(scene, splits={"train": np.arange(16)})
    return write_scene(scene, tmp_path_factory.mktemp("photos") / "cube", "blender")


def sized(width: int, height: int, images: bool = True) -> Scene:
    cameras = synthetic_cameras(2, 8)
    cameras = type(cameras)(cameras.camera_to_world, 100.0, 100.0, width / 2, height / 2, width, height)
    image = np.zeros((1, 1, 3), np.uint8) if images else None
    return Scene(cameras, [Frame(f"v{i}", image=image) for i in range(2)])


def test_a_scene_without_a_test_split_holds_every_eighth_view_out_and_records_it(posed_photos, tmp_path):
    metrics = train(posed_photos, out=tmp_path / "run", **TINY)
    config = json.loads((tmp_path / "run" / "config.json").read_text())
    assert config["holdout_every"] == 8 and "holdout_every" in config["scene_defaults"]
    assert metrics["views"] == 2  # views 0 and 8 of 16


def test_holdout_every_zero_trains_on_every_view_and_reports_training_psnr_only(posed_photos, tmp_path):
    metrics = train(posed_photos, out=tmp_path / "run", holdout_every=0, **TINY)
    assert "psnr" not in metrics and metrics["views"] == 0 and metrics["train_psnr"] > 0
    assert metrics["training_rays"] == 16 * 8 * 8
    with pytest.raises(PointfieldError, match="--holdout-every 0, so it has no held-out views"):
        evaluate(tmp_path / "run", device="cpu")


def test_auto_downscale_brings_the_longest_side_to_480_px_on_a_cpu_240_for_splats_and_1600_on_a_gpu():
    assert auto_downscale(sized(1920, 1080), torch.device("cpu"))[0] == 4  # 480 x 270
    assert auto_downscale(sized(1920, 1080), torch.device("cpu"), "splat")[0] == 8  # 240 x 135: cost follows pixels
    assert auto_downscale(sized(1920, 1080), torch.device("cuda"), "splat")[0] == 2
    assert auto_downscale(sized(1920, 1080), torch.device("cuda"))[0] == 2  # 960 x 540
    assert auto_downscale(sized(400, 300), torch.device("cpu"))[0] == 1
    assert auto_downscale(sized(4000, 3000), torch.device("cuda"))[0] == 4


def test_an_explicit_downscale_wins_and_the_choice_is_recorded_only_when_made(posed_photos):
    config = {"scene": str(posed_photos), "downscale": 2, "holdout_every": 4}
    assert choose_scene_defaults(config, torch.device("cpu"), say=False) == {}
    assert config["downscale"] == 2 and config["holdout_every"] == 4
    auto = {"scene": str(posed_photos), "downscale": "auto", "holdout_every": 4}
    chosen = choose_scene_defaults(auto, torch.device("cpu"), say=False)
    assert auto["downscale"] == 1 and chosen == auto["scene_defaults"] and "downscale" in chosen


def test_auto_downscale_of_a_scene_without_images_says_so_in_one_line():
    with pytest.raises(SceneError, match="--downscale auto .* has none") as caught:
        auto_downscale(sized(800, 800, images=False), torch.device("cpu"))
    assert "\n" not in str(caught.value)


@pytest.fixture(scope="module")
def posed_photos_16(tmp_path_factory):
    """Sixteen 16 x 16 views with no test or val split (splats' SSIM needs 11 x 11 at least)."""
    scene = synthetic_scene("cube", views=16, size=16)
    scene = replace(scene, splits={"train": np.arange(16)})
    return write_scene(scene, tmp_path_factory.mktemp("photos16") / "cube", "blender")


@pytest.mark.parametrize("command", [
    ["nerf", "train", "--model", "tiny", "--batch-rays", "64", "--steps", "2", "--eval-every", "2"],
    ["splat", "train", "--steps", "2", "--eval-every", "2"],
])
def test_the_command_closes_with_the_training_psnr_of_a_run_without_held_out_views(posed_photos_16, tmp_path,
                                                                                   capsys, command):
    from pointfield.cli import main

    out = tmp_path / "run"
    assert main([*command, str(posed_photos_16), "--out", str(out), "--holdout-every", "0", "--device", "cpu",
                 "--no-progress"]) == 0
    closing = capsys.readouterr().out.strip().splitlines()[-1]
    assert "training PSNR" in closing and "no held-out views" in closing and "held-out PSNR" not in closing
