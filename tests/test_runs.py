"""``pointfield.load_run``: every kind of run opens through one call, and scene runs render alike."""

import json

import numpy as np
import pytest
import torch

import pointfield
from pointfield.clouds.run import CloudRun
from pointfield.errors import PointfieldError
from pointfield.fields.run import FieldRun
from pointfield.fields.train import train as train_field
from pointfield.splats.run import SplatRun
from pointfield.splats.train import train as train_splats

CUBE = dict(cube_views=12, cube_size=12, device="cpu", progress=False)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("runs")
    pointfield.classify.train(out=root / "classify", epochs=1, points=64, shapes_per_class=4,
                              batch_size=8, device="cpu", progress=False)
    train_field(out=root / "tiny", model="tiny", steps=4, eval_every=2, batch_rays=128, model_options={"samples": 8}, **CUBE)
    train_field(out=root / "ngp", model="ngp", steps=4, eval_every=2, **CUBE)
    train_splats(out=root / "splat", steps=4, eval_every=2, initial_splats=200, **CUBE)
    return root


@pytest.mark.parametrize(("name", "kind"), [
    ("classify", CloudRun), ("tiny", FieldRun), ("ngp", FieldRun), ("splat", SplatRun),
])
def test_load_run_opens_every_kind_of_run_with_its_settings_history_and_scores(runs, name, kind):
    run = pointfield.load_run(runs / name, device="cpu")
    assert isinstance(run, kind)
    assert run.path == runs / name
    assert run.config == json.loads((runs / name / "config.json").read_text())
    assert run.metrics == json.loads((runs / name / "metrics.json").read_text())
    assert len(run.history) == len((runs / name / "metrics.jsonl").read_text().splitlines())
    assert not run.module.training


@pytest.mark.parametrize("name", ["tiny", "ngp", "splat"])
def test_every_scene_run_renders_cameras_the_same_way(runs, name):
    run = pointfield.load_run(runs / name, device="cpu")
    cameras = run.scene.cameras[[0, 1]]
    views = run.render(cameras)
    assert len(views) == 2
    for view in views:
        assert set(view) == {"rgb", "depth", "median_depth", "opacity"}
        assert view["rgb"].shape == (12, 12, 3)
        assert view["depth"].shape == view["median_depth"].shape == view["opacity"].shape == (12, 12)
        assert float(view["rgb"].min()) >= 0 and float(view["rgb"].max()) <= 1
        assert float(view["opacity"].min()) >= 0 and float(view["opacity"].max()) <= 1
        assert bool(torch.isfinite(view["depth"]).all())
    only_depth = run.render(cameras[[0]], outputs=("depth",))
    assert set(only_depth[0]) == {"depth"}
    assert torch.equal(only_depth[0]["depth"], views[0]["depth"])


@pytest.mark.parametrize("name", ["tiny", "splat"])
def test_a_scene_runs_evaluation_is_the_score_training_wrote(runs, name):
    run = pointfield.load_run(runs / name, device="cpu")
    again = run.evaluate()
    assert again["psnr"] == pytest.approx(run.metrics["psnr"], abs=1e-4)
    assert again["ssim"] == pytest.approx(run.metrics["ssim"], abs=1e-4)


def test_a_cloud_run_predicts_files(runs, tmp_path):
    run = pointfield.load_run(runs / "classify", device="cpu")
    cloud = pointfield.PointCloud(np.random.default_rng(0).normal(size=(100, 3)).astype(np.float32))
    pointfield.write(tmp_path / "blob.ply", cloud)
    [answer] = run.predict([tmp_path / "blob.ply"])
    assert answer["class"] in run.config["classes"]
    assert sum(answer["probabilities"].values()) == pytest.approx(1, abs=1e-5)


def test_load_run_refuses_a_folder_that_is_not_a_run(tmp_path):
    with pytest.raises(PointfieldError, match="not a run folder"):
        pointfield.load_run(tmp_path)


def test_load_run_refuses_a_run_of_an_unknown_task(tmp_path):
    (tmp_path / "config.json").write_text(json.dumps({"task": "dance"}))
    with pytest.raises(PointfieldError, match="task 'dance'"):
        pointfield.load_run(tmp_path)
