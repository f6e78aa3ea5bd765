"""``pointfield classify``: train, eval and predict from the command line, end to end."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

import pointfield
from pointfield.cli import main
from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.shapes import make_shape

TINY = ["--shapes-per-class", "2", "--points", "64", "--epochs", "1", "--batch-size", "8",
        "--no-progress", "--device", "cpu"]


pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(autouse=True)
def private_cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("POINTFIELD_CACHE", str(tmp_path_factory.mktemp("cache")))


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    """One tiny trained run per model, shared by the tests of this file."""
    root = tmp_path_factory.mktemp("runs")
    trained = {}
    for model in ("pointnet", "pointnet2"):
        out = root / model
        assert main(["classify", "train", "--model", model, "--out", str(out), *TINY]) == 0
        trained[model] = out
    return trained


@pytest.fixture(scope="module")
def shape_files(tmp_path_factory) -> tuple[Path, Path]:
    """A cone as a PLY file, and the same cloud with its points shuffled."""
    folder = tmp_path_factory.mktemp("files")
    cone = make_shape("cone", 500, np.random.default_rng(7))
    cone = PointCloud(cone.points)
    shuffled = cone.select(np.random.default_rng(8).permutation(len(cone)))
    pointfield.write(folder / "cone.ply", cone)
    pointfield.write(folder / "cone_shuffled.ply", shuffled)
    return folder / "cone.ply", folder / "cone_shuffled.ply"


def test_train_writes_the_whole_run_folder(runs):
    run = runs["pointnet"]
    for name in ("config.json", "metrics.jsonl", "metrics.json", "checkpoints/last.pt",
                 "training_curves.png", "confusion_matrix.png"):
        assert (run / name).is_file(), name
    config = json.loads((run / "config.json").read_text())
    assert config["model"] == "pointnet" and len(config["classes"]) == 10
    lines = (run / "metrics.jsonl").read_text().splitlines()
    assert len(lines) == 1 and json.loads(lines[0])["epoch"] == 1
    final = json.loads((run / "metrics.json").read_text())
    assert {"accuracy", "mean_class_accuracy", "per_class", "parameters"} <= set(final)


def test_eval_prints_scores_as_json(runs, capsys):
    assert main(["classify", "eval", str(runs["pointnet"]), "--json", "--device", "cpu"]) == 0
    metrics = json.loads(capsys.readouterr().out)
    assert 0 <= metrics["accuracy"] <= 1 and metrics["samples"] == 10
    assert np.array(metrics["confusion"]).shape == (10, 10)


@pytest.mark.parametrize("model", ["pointnet", "pointnet2"])
def test_predict_gives_the_same_probabilities_for_a_shuffled_file(runs, shape_files, capsys, model):
    assert main(["classify", "predict", str(runs[model]), *map(str, shape_files), "--json"]) == 0
    original, shuffled = json.loads(capsys.readouterr().out)
    assert original["file"].endswith("cone.ply")
    assert set(original) == {"file", "class", "probability", "probabilities"}
    assert original["class"] == shuffled["class"]
    assert sum(original["probabilities"].values()) == pytest.approx(1.0, abs=1e-5)
    for name, p in original["probabilities"].items():
        assert shuffled["probabilities"][name] == pytest.approx(p, abs=1e-5)


def test_predict_prints_one_line_per_file(runs, shape_files, capsys):
    assert main(["classify", "predict", str(runs["pointnet"]), str(shape_files[0])]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1 and out[0].startswith(str(shape_files[0]))


def test_a_second_run_into_the_same_folder_needs_resume(runs, capsys):
    code = main(["classify", "train", "--out", str(runs["pointnet"]), *TINY])
    error = capsys.readouterr().err
    assert code == 1 and "pass --resume to continue it, or choose another --out" in error
    assert "resume=True" not in error


def test_python_callers_are_told_the_python_names_of_resume_and_out(runs):
    with pytest.raises(pointfield.PointfieldError, match="pass resume=True to continue it, or choose another out$"):
        pointfield.classify.train(out=runs["pointnet"], epochs=1, points=64, shapes_per_class=2, batch_size=8,
                                  device="cpu", progress=False)


def test_only_a_model_with_a_regulariser_logs_one(runs):
    def logged(model: str) -> set[str]:
        return set(json.loads((runs[model] / "metrics.jsonl").read_text().splitlines()[-1]))

    assert "train_regulariser" in logged("pointnet")  # the feature T-Net's orthogonality loss
    assert "train_regulariser" not in logged("pointnet2")  # PointNet++ has none: no "regulariser 0.0000"


def test_predict_with_an_interrupted_run_says_it_is_unfinished(runs, shape_files, tmp_path, capsys):
    interrupted = tmp_path / "interrupted"
    shutil.copytree(runs["pointnet"], interrupted)
    (interrupted / "metrics.json").unlink()  # as a run killed before its end leaves it
    assert main(["classify", "predict", str(runs["pointnet"]), str(shape_files[0])]) == 0
    assert "unfinished" not in capsys.readouterr().err
    assert main(["classify", "predict", str(interrupted), str(shape_files[0])]) == 0
    warning = capsys.readouterr().err
    assert "is an unfinished run (it stopped after epoch 1 of 1 and has no metrics.json)" in warning
    assert "predictions come from its last checkpoint" in warning


def test_resume_of_a_finished_run_trains_further_epochs(tmp_path, capsys):
    out = tmp_path / "run"
    args = ["classify", "train", "--out", str(out), "--no-input-transform",
            "--no-feature-transform", *TINY]
    assert main(args) == 0
    assert main([*args, "--resume", "--epochs", "2"]) == 0
    epochs = [json.loads(line)["epoch"] for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert epochs == [1, 2]


def test_a_checkpoint_of_another_model_is_a_clear_error(runs, tmp_path, shape_files, capsys):
    import shutil

    mixed = tmp_path / "mixed"
    shutil.copytree(runs["pointnet"], mixed)
    shutil.copy(runs["pointnet2"] / "checkpoints" / "last.pt", mixed / "checkpoints" / "last.pt")
    assert main(["classify", "predict", str(mixed), str(shape_files[0])]) == 1
    assert "checkpoint is of model 'pointnet2', expected 'pointnet'" in capsys.readouterr().err


def test_a_file_without_points_is_reported_by_name(runs, tmp_path, capsys):
    empty = tmp_path / "empty.xyz"
    pointfield.write(empty, PointCloud(np.full((3, 3), np.nan)))
    assert main(["classify", "predict", str(runs["pointnet"]), str(empty)]) == 1
    assert "empty.xyz" in capsys.readouterr().err


def test_modelnet_samples_train_and_predict_end_to_end(shared_data, tmp_path, capsys):
    root = shared_data / "modelnet" / "ModelNet10"
    out = tmp_path / "modelnet"
    args = ["classify", "train", str(root), "--out", str(out), "--points", "64", "--epochs", "1",
            "--batch-size", "4", "--no-progress", "--no-input-transform",
            "--no-feature-transform"]
    assert main(args) == 0
    files = sorted(root.rglob("*.off"))
    capsys.readouterr()
    assert main(["classify", "predict", str(out), *map(str, files), "--json"]) == 0
    answers = json.loads(capsys.readouterr().out)
    assert len(answers) == 7
    assert all(a["class"] in ("bathtub", "chair", "toilet") for a in answers)
    assert main(["classify", "eval", str(out), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["samples"] == 3
