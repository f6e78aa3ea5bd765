"""Scene-scale segmentation: crops drawn so rare classes are seen, windows that cover a scan and vote,
a PointNet++ that learns synthetic rooms from the command line, and a killed run that resumes."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from scene_rooms import TINY

import pointfield
from pointfield.cli import main
from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.scene_crops import CropFinder, SceneCrops, class_weights, cover, prepare_scene
from pointfield.clouds.scene_tasks import SceneSegmentTask, class_palette
from pointfield.clouds.synthetic_scenes import ROOM_CLASSES, synthetic_scene
from pointfield.clouds.transforms import ColourDrop, ColourJitter
from pointfield.training.loop import TrainingState
from pointfield.training.run import RunDirectory

pytestmark = pytest.mark.usefixtures("one_torch_thread")

@pytest.fixture
def run(rooms_run) -> Path:
    return rooms_run


def test_a_pointnet2_learns_rooms_loss_falls_and_miou_beats_the_majority_guess(run):
    final = json.loads((run / "metrics.json").read_text())
    losses = [json.loads(line)["train_loss"] for line in (run / "metrics.jsonl").read_text().splitlines()]
    assert losses[-1] < 0.8 * losses[0], losses
    majority_miou = final["majority_class_accuracy"] / len(ROOM_CLASSES)  # one class right, the rest 0
    assert final["miou"] > majority_miou + 0.1, (final["miou"], majority_miou)
    assert list(final["per_class"]) == list(ROOM_CLASSES)
    config = json.loads((run / "config.json").read_text())
    assert config["task"] == "segment-scenes" and config["model"] == "pointnet2"
    assert config["features"] == ["colour", "intensity", "height"]  # what the scans offer, and height
    assert (run / "confusion_matrix.png").is_file() and (run / "prediction.png").is_file()


def test_eval_reports_overall_accuracy_miou_and_each_class(run, capsys):
    assert main(["segment", "eval", str(run), "--device", "cpu"]) == 0
    out = capsys.readouterr().out
    assert "overall accuracy" in out and "mIoU" in out and "chair" in out and "ceiling" in out


def test_predict_writes_labels_and_confidence_that_do_not_depend_on_point_order(run, rooms, tmp_path):
    scan = pointfield.read(next((rooms / "test").glob("*.ply")))
    order = np.random.default_rng(1).permutation(len(scan))
    shuffled = tmp_path / "shuffled.ply"
    pointfield.write(shuffled, scan.select(order))
    first = pointfield.load_run(run, device="cpu").predict([next((rooms / "test").glob("*.ply"))],
                                                           out=tmp_path / "a.ply")[0]
    second = pointfield.load_run(run, device="cpu").predict([shuffled], out=tmp_path / "b.ply")[0]
    a, b = pointfield.read(first["output"]), pointfield.read(second["output"])
    assert a.fields["label"].dtype == np.int32 and len(a) == len(scan)
    assert np.array_equal(a.fields["label"][order], b.fields["label"])
    assert np.allclose(a.fields["confidence"][order], b.fields["confidence"], atol=1e-5)
    assert ((a.fields["confidence"] > 1 / len(ROOM_CLASSES)) & (a.fields["confidence"] <= 1)).all()
    assert json.loads((tmp_path / "a.ply.classes.json").read_text())["4"] == "chair"
    agree = (a.fields["label"] == scan.fields["label"]).mean()
    assert agree > 0.5, agree  # full-resolution labels, voted, against the truth


def test_predict_writes_las_classification_in_the_files_codes(run, rooms, tmp_path, capsys):
    source = next((rooms / "test").glob("*.ply"))
    assert main(["segment", "predict", str(run), str(source), "--out", str(tmp_path / "room.laz"),
                 "--device", "cpu", "--json"]) == 0
    (answer,) = json.loads(capsys.readouterr().out)
    labelled = pointfield.read(tmp_path / "room.laz")
    assert labelled.fields["classification"].dtype == np.uint8
    assert set(np.unique(labelled.fields["classification"])) <= set(range(len(ROOM_CLASSES)))
    assert "confidence" in labelled.fields and sum(answer["classes"].values()) == len(labelled)


def test_training_crops_centre_on_every_class_alike(rooms):
    scan = prepare_scene(pointfield.read(next((rooms / "train").glob("*.ply"))), 0.1, ["height"])
    crops = SceneCrops([scan], ROOM_CLASSES, radius=1.0, points=10_000, crops=600, seed=3)
    centres = []
    for i in range(len(crops)):
        crop, _ = crops[i]
        centres.append(crop.fields["label"][np.linalg.norm(crop.points, axis=1).argmin()])
    drawn = np.bincount(centres, minlength=6) / len(centres)
    share = np.bincount(scan.fields["label"], minlength=6) / len(scan)
    assert np.abs(drawn - 1 / 6).max() < 0.06, drawn  # uniform over classes ...
    assert share.min() < 0.06  # ... though some class has few points


def test_class_weights_favour_rare_classes():
    scan = PointCloud(np.zeros((100, 3), np.float32), {"label": np.array([0] * 90 + [1] * 10 + [])})
    weights = class_weights([scan], 3)
    assert weights[1] > 3 * weights[0] and weights[2] == 0 and np.isclose(weights[:2].mean(), 1)


def test_windows_cover_every_point_whatever_the_order():
    points = synthetic_scene("room", 2, 0.03).cloud.points
    finder = CropFinder(points, 1.0)
    counts = np.zeros(len(points), int)
    windows = list(cover(finder, 200))
    for _, chunk in windows:
        counts[chunk] += 1
        assert len(chunk) <= 200
    assert counts.min() >= 1
    order = np.random.default_rng(0).permutation(len(points))
    shuffled = list(cover(CropFinder(points[order], 1.0), 200))
    assert [sorted(map(tuple, points[c])) for _, c in windows] == [sorted(map(tuple, points[order][c]))
                                                                   for _, c in shuffled]


def test_colour_jitter_and_drop_touch_only_the_colour():
    cloud = PointCloud(np.zeros((50, 3), np.float32), {"colour": np.full((50, 3), 0.5, np.float32)})
    jittered = ColourJitter(0.05, seed=0)(cloud)
    assert 0.02 < np.std(jittered.fields["colour"]) < 0.08 and np.array_equal(jittered.points, cloud.points)
    assert (ColourDrop(1.0, seed=0)(cloud).fields["colour"] == 0).all()
    assert ColourDrop(0.0, seed=0)(cloud) is cloud


def test_an_unknown_feature_is_refused_before_anything_is_written(rooms, tmp_path, capsys):
    assert main(["segment", "train", str(rooms), "--out", str(tmp_path / "run"), "--features", "colours",
                 *TINY]) != 0
    assert "unknown features ['colours']" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


@pytest.mark.skipif(not hasattr(signal, "SIGKILL"), reason="needs POSIX signals")
def test_a_scene_run_killed_mid_training_resumes_and_finishes(rooms, tmp_path):
    out = tmp_path / "run"
    settings = {"grid": 0.12, "radius": 1.5, "points": 128, "crops": 16, "batch_size": 4, "epochs": 2,
                "device": "cpu"}
    script = ("from pointfield.clouds.scene_tasks import train_scenes\n"
              f"train_scenes([{str(rooms)!r}], out={str(out)!r}, checkpoint_seconds=0, progress=False, "
              f"**{settings!r})\n")
    environment = {**os.environ, "OMP_NUM_THREADS": "1"}
    process = subprocess.Popen([sys.executable, "-c", script], env=environment, stdout=subprocess.DEVNULL,
                               stderr=subprocess.PIPE)
    checkpoint = out / "checkpoints" / "last.pt"
    deadline = time.monotonic() + 300
    while not checkpoint.exists():
        assert process.poll() is None, process.stderr.read().decode()[-2000:]
        assert time.monotonic() < deadline, "no checkpoint was written"
        time.sleep(0.02)
    time.sleep(0.3)
    process.send_signal(signal.SIGKILL)
    process.wait()
    assert process.returncode == -signal.SIGKILL, "training ended before it could be killed"
    assert not (out / "metrics.json").exists()
    from pointfield.clouds.scene_tasks import train_scenes

    final = train_scenes([rooms], out=out, resume=True, progress=False, device="cpu")
    epochs = [json.loads(line)["epoch"] for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert epochs == [1, 2] and final["epochs"] == 2


def test_a_block_crop_is_a_column_of_square_section():
    points = np.random.default_rng(0).uniform(-3, 3, (2000, 3))
    inside = CropFinder(points, 1.0, "block").within(np.zeros(3))
    expected = np.flatnonzero((np.abs(points[:, :2]) <= 1.0).all(axis=1))
    assert np.array_equal(inside, expected) and np.ptp(points[inside, 2]) > 5  # every height


def test_the_prediction_picture_gives_the_first_ten_classes_ten_hues():
    """tab20 in its own order gives classes 0 and 1 (floor, wall) two shades of one blue."""
    import matplotlib

    palette = class_palette(20)
    tab10 = np.round(np.asarray(matplotlib.colormaps["tab10"].colors) * 255).astype(np.uint8)
    assert np.array_equal(palette[:10], tab10)
    assert len({tuple(c) for c in palette}) == 20
    assert np.array_equal(class_palette(23)[20:], palette[:3])  # past 20 classes, colours repeat


def test_the_final_scores_are_of_the_final_model_when_the_clock_skipped_its_evaluation(rooms, tmp_path):
    """An epoch's evaluation that ``max_time`` could not hold leaves an older model's confusion behind."""
    import torch

    config = SceneSegmentTask.configure({"data": [rooms], "grid": 0.12, "radius": 1.5, "points": 128, "crops": 4,
                                         "batch_size": 2, "epochs": 2})
    task = SceneSegmentTask(config, torch.device("cpu"), None, False)
    task.confusion = np.diag([1000] * len(ROOM_CLASSES))  # a perfect score, from an earlier model
    history = [{"epoch": 1, "step": 2, "train_loss": 1.0, "test_miou": 1.0},
               {"epoch": 2, "step": 4, "train_loss": 0.9}]  # epoch 2 trained, its evaluation skipped
    (tmp_path / "run").mkdir()
    final = task.finish(RunDirectory(tmp_path / "run"), TrainingState(epoch=2, step=4, history=history))
    assert final["test_points"] == sum(len(scene) for scene in task.test_scenes) != 1000 * len(ROOM_CLASSES)
    assert final["miou"] < 1.0


def test_a_run_stopped_by_its_training_time_ends_annealed_whatever_its_epochs(rooms, tmp_path):
    """A cosine over 1,000 epochs, stepped per epoch, left a run stopped by the clock after a few of them at
    0.99999 of the full rate; over the time limit, the rate falls step by step (to 1 % at the limit: the
    last step's rate is set before it runs, so it stops short of that, the more so the fewer the steps)."""
    from pointfield.clouds.scene_tasks import train_scenes

    out = tmp_path / "run"
    train_scenes([rooms], out=out, grid=0.12, radius=1.5, points=128, crops=8, batch_size=2, epochs=1000,
                 learning_rate=0.002, max_training_time=2.0, progress=False, device="cpu")
    records = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert records[-1]["epoch"] < 1000 and records[-1]["lr"] < 0.9 * 0.002, records[-1]
