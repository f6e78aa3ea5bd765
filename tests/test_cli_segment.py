"""``pointfield segment``: per-point labels trained, scored, and written back to files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import pointfield
from pointfield.cli import main
from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.mesh import Mesh
from pointfield.clouds.shapes import PART_NAMES, SHAPE_CLASSES, make_shape

TINY = ["--shapes-per-class", "2", "--points", "64", "--epochs", "1", "--batch-size", "8",
        "--no-progress", "--device", "cpu"]


pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(autouse=True)
def private_cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("POINTFIELD_CACHE", str(tmp_path_factory.mktemp("cache")))


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("runs") / "segment"
    assert main(["segment", "train", "--out", str(out), *TINY]) == 0
    return out


def test_train_writes_miou_and_part_names(run):
    final = json.loads((run / "metrics.json").read_text())
    assert {"accuracy", "mean_class_accuracy", "miou"} <= set(final)
    assert list(final["per_class"]) == list(PART_NAMES)
    assert json.loads((run / "config.json").read_text())["parts"] == list(PART_NAMES)
    assert "test_miou" in json.loads((run / "metrics.jsonl").read_text().splitlines()[0])


def test_train_writes_the_per_shape_scores_of_shapenetpart(run):
    final = json.loads((run / "metrics.json").read_text())
    assert list(final["per_category"]) == list(SHAPE_CLASSES)  # every test shape is scored on its own parts
    assert final["class_miou"] == pytest.approx(np.mean(list(final["per_category"].values())))
    # The sphere has one part: a shape of it predicted within its category is all right.
    assert final["per_category"]["sphere"] == 1.0 and 0 < final["instance_miou"] <= 1


def test_eval_reports_iou_per_part(run, capsys):
    assert main(["segment", "eval", str(run)]) == 0
    out = capsys.readouterr().out
    assert "mIoU" in out and "cylinder cap" in out and "instance mIoU" in out


def test_predict_writes_every_point_labelled(run, tmp_path, capsys):
    cloud = make_shape("mug", 300, np.random.default_rng(3))
    points = cloud.points.copy()
    points[5] = np.nan  # an invalid point keeps its place and gets label -1
    source = tmp_path / "mug.pcd"
    pointfield.write(source, PointCloud(points))
    out = tmp_path / "labelled"
    assert main(["segment", "predict", str(run), str(source), "--out", str(out), "--json"]) == 0
    (answer,) = json.loads(capsys.readouterr().out)
    labelled = pointfield.read(out / "mug.ply")
    labels = labelled.fields["label"]
    assert answer["output"] == str(out / "mug.ply") and answer["points"] == 300
    assert labels.dtype == np.int32 and labels[5] == -1
    assert (labels[np.arange(300) != 5] >= 0).all()
    assert sum(answer["parts"].values()) == 299


def test_predict_on_a_mesh_labels_its_vertices_and_keeps_its_faces(run, tmp_path):
    points = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], np.float32)
    mesh = Mesh(points, faces=np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))
    pointfield.write(tmp_path / "tetra.off", mesh)
    assert main(["segment", "predict", str(run), str(tmp_path / "tetra.off"),
                 "--out", str(tmp_path)]) == 0
    labelled = pointfield.read(tmp_path / "tetra.ply")
    assert isinstance(labelled, Mesh) and len(labelled.faces) == 4
    assert (labelled.fields["label"] >= 0).all()


def test_a_folder_of_labelled_clouds_trains(tmp_path):
    for split, count in (("train", 4), ("test", 2)):
        (tmp_path / "data" / split).mkdir(parents=True)
        for i in range(count):
            shape = make_shape("table", 100, np.random.default_rng(i))
            labels = (shape.fields["label"] - shape.fields["label"].min()).astype(np.int32)
            pointfield.write(tmp_path / "data" / split / f"{i}.ply",
                             PointCloud(shape.points, {"part": labels}))
    out = tmp_path / "run"
    assert main(["segment", "train", str(tmp_path / "data"), "--label-field", "part",
                 "--out", str(out), "--points", "64", "--epochs", "1", "--no-progress",
                 "--no-input-transform", "--no-feature-transform"]) == 0
    assert json.loads((out / "config.json").read_text())["parts"] == ["0", "1"]


def test_segment_refuses_a_classification_run(tmp_path, capsys):
    out = tmp_path / "cls"
    assert main(["classify", "train", "--out", str(out), "--no-input-transform",
                 "--no-feature-transform", *TINY]) == 0
    capsys.readouterr()
    assert main(["segment", "eval", str(out)]) == 1
    assert "is a 'classify' run" in capsys.readouterr().err
