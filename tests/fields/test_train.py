"""`pointfield nerf train|eval|render`: the run folder, resuming, bad input (tiny scenes, few steps)."""

import json

import pytest
import torch

from pointfield.cli import main
from pointfield.errors import PointfieldError
from pointfield.fields.run import evaluate, render
from pointfield.fields.train import train
from pointfield.scenes import make_scene

TINY = dict(model="tiny", batch_rays=128, steps=4, eval_every=2, cube_views=12, cube_size=12, device="cpu",
            progress=False, model_options={"samples": 8})


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("nerf") / "run"
    metrics = train(out=out, **TINY)
    return out, metrics


def test_run_folder_holds_config_metrics_checkpoint_curves_and_heldout_renders(tiny_run):
    out, metrics = tiny_run
    for name in ("config.json", "metrics.jsonl", "metrics.json", "checkpoints/last.pt", "training_curves.png"):
        assert (out / name).is_file(), name
    assert sorted(p.name for p in (out / "heldout").iterdir()) == ["000.png"]
    final = json.loads((out / "metrics.json").read_text())
    assert {"psnr", "ssim", "steps", "seconds"} <= set(final) and final["steps"] == 4
    records = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in records] == [2, 4]
    assert all({"seconds", "loss", "train_loss", "train_psnr", "psnr"} <= set(r) for r in records)
    assert all(r["loss"] == r["train_loss"] for r in records)
    payload = torch.load(out / "checkpoints" / "last.pt", weights_only=True)
    assert payload["identity"]["model"] == "tiny"


def test_eval_scores_the_heldout_views_again(tiny_run):
    out, metrics = tiny_run
    again = evaluate(out, device="cpu")
    assert again["psnr"] == pytest.approx(metrics["psnr"], abs=1e-4)


def test_resume_continues_to_more_steps(tiny_run, tmp_path):
    out = tmp_path / "run"
    train(out=out, **{**TINY, "steps": 2})
    metrics = train(out=out, resume=True, **TINY)
    assert metrics["steps"] == 4
    assert len((out / "metrics.jsonl").read_text().splitlines()) == 2


def test_a_new_run_refuses_to_overwrite_an_old_one(tiny_run):
    out, _ = tiny_run
    before = (out / "metrics.json").read_bytes()
    with pytest.raises(PointfieldError, match="already holds a run"):
        train(out=out, **TINY)
    assert (out / "metrics.json").read_bytes() == before


@pytest.mark.parametrize("path, suffix", [("orbit", ".gif"), ("spiral", ""), ("dataset", ".gif")])
def test_render_paths_write_frames(tiny_run, tmp_path, path, suffix):
    out = tmp_path / f"frames{suffix}"
    result = render(tiny_run[0], path=path, frames=3, out=out, device="cpu")
    assert result["frames"] == 3
    if suffix:
        import imageio.v3 as iio

        frames = iio.imread(out, index=None)
        assert frames.shape[0] == 3 and frames.shape[2] == 3 * 12  # colour | depth | opacity
    else:
        assert len(list(out.glob("color_*.png"))) == 3 and len(list(out.glob("depth_*.png"))) == 3


def test_a_render_shows_a_bar_over_its_frames_unless_told_not_to(tiny_run, tmp_path, capsys):
    assert main(["nerf", "render", str(tiny_run[0]), "--frames", "2", "--out", str(tmp_path / "a.gif")]) == 0
    assert "2/2" in capsys.readouterr().err
    assert main(["nerf", "render", str(tiny_run[0]), "--frames", "2", "--out", str(tmp_path / "b.gif"),
                 "--no-progress"]) == 0
    assert "2/2" not in capsys.readouterr().err


def test_a_render_path_with_no_frames_is_an_error_and_writes_nothing(tiny_run, tmp_path, capsys):
    out = tmp_path / "none.gif"
    assert main(["nerf", "render", str(tiny_run[0]), "--frames", "0", "--out", str(out)]) == 1
    assert "needs at least one frame, got --frames 0" in capsys.readouterr().err
    assert not out.exists()


def test_a_render_path_with_no_frames_leaves_an_earlier_render_alone(tiny_run, tmp_path):
    out = tmp_path / "earlier.gif"
    out.write_bytes(b"an earlier render")
    with pytest.raises(PointfieldError, match="at least one frame"):
        render(tiny_run[0], path="orbit", frames=0, out=out, device="cpu")
    assert out.read_bytes() == b"an earlier render"


def test_a_checkpoint_of_another_model_is_refused(tiny_run, tmp_path):
    out = tmp_path / "other"
    out.mkdir()
    config = json.loads((tiny_run[0] / "config.json").read_text())
    (out / "config.json").write_text(json.dumps({**config, "model": "nerf", "model_options": {}}))
    (out / "checkpoints").mkdir()
    (out / "checkpoints" / "last.pt").write_bytes((tiny_run[0] / "checkpoints" / "last.pt").read_bytes())
    with pytest.raises(PointfieldError, match="model 'tiny', expected 'nerf'"):
        evaluate(out, device="cpu")
    with pytest.raises(PointfieldError, match="model 'tiny', expected 'nerf'"):
        render(out, frames=2, out=tmp_path / "other.gif", device="cpu")
    assert not (tmp_path / "other.gif").exists()


def test_a_run_of_another_task_is_refused_and_the_output_is_left_alone(tmp_path, capsys):
    classify_run = tmp_path / "classify"
    classify_run.mkdir()
    (classify_run / "config.json").write_text(json.dumps({"task": "classify", "model": "pointnet"}))
    out = tmp_path / "earlier.gif"
    out.write_bytes(b"an earlier render")
    assert main(["nerf", "render", str(classify_run), "--out", str(out), "--device", "cpu"]) == 1
    assert "a run of task 'classify', not 'nerf'" in capsys.readouterr().err
    assert out.read_bytes() == b"an earlier render"


def test_a_scene_without_images_is_a_clear_error_and_creates_no_run(tmp_path, capsys):
    scene = tmp_path / "scene"
    scene.mkdir()
    (scene / "transforms_train.json").write_text(json.dumps({
        "camera_angle_x": 0.69,
        "frames": [{"file_path": "./train/r_0", "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]}],
    }))
    out = tmp_path / "run"
    assert main(["nerf", "train", str(scene), "--model", "tiny", "--out", str(out), "--steps", "1", "--holdout-every", "2"]) == 1
    assert "no frame has its image" in capsys.readouterr().err
    assert not (out / "config.json").exists()


def test_cli_train_and_eval_json(tmp_path, capsys):
    scene = make_scene("cube", tmp_path / "cube", views=12, size=12)
    out = tmp_path / "cli"
    code = main(["nerf", "train", str(scene), "--model", "tiny", "--out", str(out), "--steps", "2", "--batch-rays", "64",
                 "--device", "cpu", "--no-progress", "--eval-every", "2"])
    assert code == 0
    capsys.readouterr()
    assert main(["nerf", "eval", str(out), "--json", "--device", "cpu"]) == 0
    assert json.loads(capsys.readouterr().out)["model"] == "tiny"


def test_render_writes_mp4_when_imageio_ffmpeg_is_installed(tiny_run, tmp_path):
    pytest.importorskip("imageio_ffmpeg", reason="imageio-ffmpeg not installed")
    import imageio.v2 as imageio

    out = tmp_path / "orbit.mp4"
    render(tiny_run[0], path="orbit", frames=4, out=out, device="cpu")
    with imageio.get_reader(out, format="FFMPEG") as reader:
        frames = [frame for frame in reader]
    assert len(frames) == 4 and frames[0].shape[1] == 3 * 12


def test_lego_at_100_pixels_holds_every_tenth_view_out(shared_data):
    from pointfield.scenes.heldout import open_scene, training_and_heldout

    scene = open_scene(shared_data / "nerf" / "lego_blender", downscale=8, holdout_every=10, background="white")
    train_frames, heldout = training_and_heldout(scene)
    assert (len(train_frames), len(heldout)) == (90, 10)
    assert int(scene.cameras.width[0]) == int(scene.cameras.height[0]) == 100
    assert scene.background.tolist() == [1.0, 1.0, 1.0]


def test_nerf_train_defaults_to_the_hash_grid_field_and_help_names_every_model(capsys):
    import inspect

    from pointfield.cli import build_parser

    assert build_parser().parse_args(["nerf", "train"]).model == "ngp"
    assert inspect.signature(train).parameters["model"].default == "ngp"
    with pytest.raises(SystemExit):
        main(["--help"])
    nerf_line = " ".join(capsys.readouterr().out.split()).split(" nerf ", 1)[1].split(" splat ", 1)[0]
    assert all(name in nerf_line for name in ("ngp", "TinyNeRF", "NeRF"))
