"""Semantic segmentation of whole scans: the training behind ``pointfield segment train DATA...`` on
scenes, and the run it leaves (:class:`SceneRun`), which scores test scans and labels new ones.

DATA is a dataset folder in its own layout (S3DIS, ScanNet v2, SemanticKITTI) or labelled
files and folders of them in any format (:func:`~pointfield.clouds.datasets.open_scenes`).
:class:`SceneSegmentTask` runs through the one training lifecycle of
:mod:`pointfield.training` (checkpoints, resuming, ``max_time``), as the object tasks of
:mod:`pointfield.clouds.tasks` do; what differs is the data (:mod:`pointfield.clouds.scene_crops`).

The recipe (Pointcept's and PointNet++'s choices, sized for a CPU):

- every scan on a grid of ``grid`` metres (0.05), features from :data:`~.scene_crops.FEATURES`
  (default: colour and intensity where the data has them, and height);
- ``crops`` training crops per epoch (256), each a ball of ``radius`` metres (2.0) around a
  point of a class drawn uniformly among those present, at most ``points`` points (4096);
- augmentation: a turn about z, scale 0.9..1.1, jitter 1 cm, colour jitter and drop;
- loss: cross-entropy with ENet's class-balanced weights ``1 / ln(1.02 + f_c)``; Adam at 0.001
  with weight decay 1e-4, cosine-decayed to 1 % over the epochs, or, given a time limit, warmed up
  and cosine-decayed step by step over it (:class:`~pointfield.training.schedules.BudgetCosine`);
- evaluation after each epoch on every test scan, each point's class the vote of the windows
  holding it: overall accuracy, mean IoU and the IoU of each class, on the grid-subsampled
  points (as Pointcept scores during training); the final scores are those of the final model,
  scored again if the last evaluation was of an earlier one; at the end ``confusion_matrix.png`` and
  ``prediction.png``, the first test scan coloured by truth beside prediction.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib
import numpy as np
import torch
import torch.nn.functional as F

from pointfield.atomic import atomic_path
from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.datasets import CloudCollate, SceneDataset, open_scenes, scene_layout
from pointfield.clouds.datasets.labelled import as_scan
from pointfield.clouds.datasets.loading import with_progress
from pointfield.clouds.datasets.scene_base import LABEL_FIELD
from pointfield.clouds.formats import format_of, read, write
from pointfield.clouds.mesh import Mesh
from pointfield.clouds.models import MODEL_NAMES, MODEL_OPTIONS, build_model, count_parameters
from pointfield.clouds.scene_crops import (
    CROP_SHAPES,
    FEATURES,
    SceneCrops,
    class_weights,
    default_features,
    prepare_scene,
    training_transform,
    vote,
)
from pointfield.clouds.tasks import (
    FINAL_LEARNING_RATE_FRACTION,
    LEARNING_RATE,
    WEIGHT_DECAY,
    per_class_scores,
    scores_of,
    set_batchnorm_momentum,
)
from pointfield.errors import FormatError, PointfieldError
from pointfield.metrics import confusion_matrix
from pointfield.streaming.jobs import progress_bar
from pointfield.training import lifecycle
from pointfield.training.distributed import wrap
from pointfield.training.lifecycle import restore_model
from pointfield.training.loop import TrainingState
from pointfield.training.run import Run, RunDirectory
from pointfield.training.schedules import BudgetCosine
from pointfield.training.task import Step, Task
from pointfield.version import __version__
from pointfield.viz.plots import plot_confusion_matrix, plot_training_curves
from pointfield.viz.render import render_cloud

TASK = "segment-scenes"
DEFAULTS = {"model": "pointnet2", "grid": 0.05, "radius": 2.0, "shape": "sphere", "points": 4096, "crops": 256,
            "epochs": 30, "batch_size": 8}
CURVES_PNG = "training_curves.png"
CONFUSION_PNG = "confusion_matrix.png"
PREDICTION_PNG = "prediction.png"
LAS_SUFFIXES = (".las", ".laz")
UNLABELLED_GREY = 160


# ---------------------------------------------------------------------------------------------
# Data
# ---------------------------------------------------------------------------------------------


def read_prepared(
    dataset: SceneDataset, config: dict[str, Any], progress: bool = False
) -> list[PointCloud]:
    """Every scan of ``dataset``, read and prepared as the config says (grid, features)."""
    return [prepare_scene(dataset.read(i), config["grid"], config["features"], dataset.names[i])
            for i in with_progress(range(len(dataset)), progress, f"reading {dataset.split} scans")]


def open_split(config: dict[str, Any], split: str, data: Sequence[str] | None = None) -> SceneDataset:
    """The ``split`` of ``data`` (default: the run's), with the run's classes once they are known."""
    return open_scenes(
        data if data is not None else config["data"], split, label_field=config["label_field"],
        classes=config.get("classes") or config["class_names"], codes=config.get("codes"),
        test_area=config["test_area"],
    )


def confusion_over(
    model: torch.nn.Module, scenes: Sequence[PointCloud], config: dict[str, Any], device: torch.device
) -> tuple[np.ndarray, list[np.ndarray]]:
    """The confusion matrix of the voted labels of every labelled point of ``scenes``, and those labels."""
    classes = len(config["classes"])
    confusion = np.zeros((classes, classes), np.int64)
    predictions = []
    for scene in scenes:
        predicted = vote_on(model, scene, config, device).argmax(axis=1)
        confusion += confusion_matrix(torch.from_numpy(scene.fields[LABEL_FIELD]), torch.from_numpy(predicted),
                                      classes)
        predictions.append(predicted)
    return confusion, predictions


def class_palette(classes: int) -> np.ndarray:
    """``(classes, 3)`` uint8 colours, one per class: tab20's ten strong colours, then their light
    partners. tab20 in its own order pairs each colour with its light shade, which gave
    neighbouring classes (floor and wall, chair and shelf) one hue; in this order the first ten
    classes have ten hues, and a class keeps its colour in every picture of a run."""
    colours = np.asarray(matplotlib.colormaps["tab20"].colors)
    ordered = np.concatenate([colours[0::2], colours[1::2]])
    return np.round(ordered[np.arange(classes) % len(ordered)] * 255).astype(np.uint8)


def draw_prediction(scene: PointCloud, predicted: np.ndarray, classes: Sequence[str], path: Path) -> Path:
    """Save the scan drawn twice from one viewpoint, coloured by its true classes (left; grey:
    unlabelled) and by the predicted ones (right), above a legend of the class colours."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch

    palette = class_palette(len(classes))
    truth = scene.fields[LABEL_FIELD]
    figure = Figure(figsize=(13, 5.6), dpi=100, layout="constrained")
    for axes, labels, title in zip(figure.subplots(1, 2), (truth, predicted), ("truth", "predicted")):
        colours = np.where((labels >= 0)[:, None], palette[np.clip(labels, 0, None)], UNLABELLED_GREY)
        axes.imshow(render_cloud(PointCloud(scene.points, {"colors": colours.astype(np.uint8)}), 640, 480,
                                 up="z", color_by="colors"))
        axes.set_title(title)
        axes.set_axis_off()
    handles = [Patch(color=palette[i] / 255, label=name) for i, name in enumerate(classes)]
    if (truth < 0).any():
        handles.append(Patch(color=np.full(3, UNLABELLED_GREY / 255), label="unlabelled"))
    figure.legend(handles=handles, loc="outside lower center", ncols=min(len(handles), 10), frameon=False)
    FigureCanvasAgg(figure)
    with atomic_path(path) as tmp:
        figure.savefig(tmp, format="png")
    return path


def vote_on(model: torch.nn.Module, scene: PointCloud, config: dict[str, Any], device: torch.device) -> np.ndarray:
    return vote(model, scene, radius=config["radius"], points=config["points"], shape=config["shape"],
                features=config["features"], classes=len(config["classes"]), device=device,
                batch_size=config["batch_size"])


# ---------------------------------------------------------------------------------------------
# Training
# ---------------------------------------------------------------------------------------------


class SceneSegmentTask(Task):
    """Semantic segmentation of scans, as the training lifecycle runs it (see the module doc)."""

    name = TASK
    extendable = ("epochs",)

    @classmethod
    def configure(cls, settings: dict[str, Any]) -> dict[str, Any]:
        config = {key: settings.get(key) if settings.get(key) is not None else value
                  for key, value in DEFAULTS.items()}
        if config["model"] not in MODEL_NAMES:
            raise PointfieldError(f"unknown model {config['model']!r}: expected one of {', '.join(MODEL_NAMES)}")
        if config["shape"] not in CROP_SHAPES:
            raise PointfieldError(f"unknown crop shape {config['shape']!r}: expected sphere or block")
        for name in ("radius", "points", "crops", "epochs", "batch_size"):
            if not config[name] > 0:
                raise PointfieldError(f"--{name.replace('_', '-')} must be positive, got {config[name]}")
        if config["grid"] < 0:
            raise PointfieldError(f"--grid must be 0 or more, got {config['grid']}")
        unknown = [f for f in settings.get("features") or () if f not in FEATURES]
        if unknown:
            raise PointfieldError(f"unknown features {unknown}: expected some of {', '.join(FEATURES)}")
        data = [str(Path(p).resolve()) for p in settings["data"]]
        if not data:
            raise PointfieldError("no DATA given: a dataset folder or labelled files")
        model_options = dict(MODEL_OPTIONS[config["model"]])
        if "voxel" in model_options and config["grid"] > 0:
            # PTv3's level-0 voxels are the data's own grid cells, in the unit-ball units crops reach it in.
            model_options["voxel"] = config["grid"] / config["radius"]
        return {
            "task": TASK,
            **config,
            "model_options": model_options,
            "data": data,
            "layout": scene_layout(data),
            "features": list(settings["features"]) if settings.get("features") else None,
            "label_field": settings.get("label_field"),
            "class_names": settings.get("class_names"),
            "test_area": settings.get("test_area") or 5,
            "learning_rate": settings.get("learning_rate") or LEARNING_RATE,
            "seed": settings.get("seed") or 0,
            "pointfield_version": __version__,
        }

    def __init__(self, config, device, distributed, progress, *, workers: int = 0):
        super().__init__(config, device, distributed, progress)
        if distributed is not None:
            raise PointfieldError("scene segmentation trains in one process; run it without torchrun")
        self.workers = workers
        train_split = open_split(config, "train")
        if len(train_split) == 0:
            raise PointfieldError(f"{', '.join(config['data'])}: no training scans")
        config["classes"] = list(train_split.classes)
        config["codes"] = [int(c) for c in train_split.class_codes()]
        if config["features"] is None:
            config["features"] = default_features(train_split.read(0))
        train_scenes = read_prepared(train_split, config, progress)
        test_split = open_split(config, "test")
        if len(test_split) == 0:
            raise PointfieldError(f"{', '.join(config['data'])}: no test scans")
        self.test_scenes = read_prepared(test_split, config, progress)
        if "class_weights" not in config:
            config["class_weights"] = class_weights(train_scenes, len(config["classes"])).round(6).tolist()
        points = sum(len(s) for s in train_scenes)
        config["data_description"] = (f"{train_split.describe()}, {points:,} points on a {config['grid']:g} m grid; "
                                      f"test: {len(test_split)} scans")
        config["device"] = str(device)
        channels = sum(FEATURES[f] for f in config["features"])
        self.model = build_model(config["model"], "segment", len(config["classes"]), channels,
                                 **config["model_options"]).to(device)
        self.parameters = count_parameters(self.model)
        self.trained = wrap(self.model, None, device)
        self.optimizer = torch.optim.Adam(self.trained.parameters(), lr=config["learning_rate"],
                                          weight_decay=WEIGHT_DECAY)
        self.epochs = config["epochs"]
        # A cosine over the epochs, stepped once an epoch; warm_up swaps it for one over the time
        # limits when the lifecycle has set any, so that a run stopped by the clock ends annealed.
        self.scheduler: Any = torch.optim.lr_scheduler.CosineAnnealingLR(
            self.optimizer, T_max=config["epochs"], eta_min=config["learning_rate"] * FINAL_LEARNING_RATE_FRACTION)
        self.identity = identity_of(config)
        self.weights = torch.tensor(config["class_weights"], dtype=torch.float32, device=device)
        self.crops = SceneCrops(
            train_scenes, config["classes"], radius=config["radius"], points=config["points"],
            crops=config["crops"], shape=config["shape"], seed=config["seed"],
            transform=training_transform(config["radius"], "colour" in config["features"]),
        )
        self.collate = CloudCollate(config["features"], point_labels=True)
        self.confusion: np.ndarray | None = None
        self.predictions: list[np.ndarray] = []
        self.evaluation_seconds: float | None = None
        if progress:
            print(f"segment scenes {config['model']}: {self.parameters:,} parameters on {device}; "
                  f"{config['data_description']}; features {', '.join(config['features'])}")

    def warm_up(self) -> None:
        if self.training_budget is not None or self.time_budget.limited:
            steps_per_epoch = len(self.crops) // max(2, min(self.config["batch_size"], len(self.crops))) or 1
            self.scheduler = BudgetCosine(
                self.optimizer, total_steps=self.epochs * steps_per_epoch, training_seconds=self.training_budget,
                wall=self.time_budget, final=FINAL_LEARNING_RATE_FRACTION)

    def batches(self, epoch: int) -> torch.utils.data.DataLoader:
        if isinstance(self.scheduler, BudgetCosine):
            self.scheduler.resume()
        set_batchnorm_momentum(self.model, epoch * len(self.crops))
        self.crops.set_epoch(epoch)
        return torch.utils.data.DataLoader(
            self.crops, batch_size=max(2, min(self.config["batch_size"], len(self.crops))), shuffle=False,
            collate_fn=self.collate, num_workers=self.workers, drop_last=len(self.crops) >= 2,
            pin_memory=self.device.type == "cuda",
        )

    def step(self, batch: Any) -> Step:
        """Class-weighted cross-entropy over every real, labelled point of the batch's crops."""
        if isinstance(self.scheduler, BudgetCosine):
            self.scheduler.advance()
        batch = batch.to(self.device)
        logits = self.trained(batch.points, batch.features, batch.mask)
        target = batch.point_labels.reshape(-1)
        flat = logits.reshape(-1, logits.shape[-1])
        loss = F.cross_entropy(flat, target, weight=self.weights, ignore_index=-1)
        real = target >= 0
        correct = (flat.argmax(-1)[real] == target[real]).float().mean()
        return Step(loss, {"accuracy": float(correct)})

    def evaluate(self, epoch: int) -> dict[str, float]:
        if isinstance(self.scheduler, BudgetCosine):
            self.scheduler.pause()
        started = time.perf_counter()
        self.confusion, self.predictions = confusion_over(self.model, self.test_scenes, self.config, self.device)
        self.evaluation_seconds = time.perf_counter() - started
        return {f"test_{k}": v for k, v in scores_of(self.confusion, "segment").items()}

    def finishing_seconds(self) -> float | None:
        """The final scores are one more evaluation of every test scan: as long as the last one took."""
        return self.evaluation_seconds

    def draw(self, run: RunDirectory, history: list[dict[str, Any]]) -> None:
        plot_training_curves(history, run.path / CURVES_PNG, title=_title(self.config))

    def finish(self, run: RunDirectory, state: TrainingState) -> dict[str, Any]:
        last = state.history[-1] if state.history else {}
        if self.confusion is None or "test_miou" not in last or last["step"] != state.step:
            # The last evaluation, if any, scored an earlier model: a resumed run that had finished
            # its epochs, an epoch cut short by the clock, or an evaluation the clock could not hold.
            self.confusion, self.predictions = confusion_over(self.model, self.test_scenes, self.config, self.device)
        confusion = self.confusion
        plot_confusion_matrix(confusion, self.config["classes"], run.path / CONFUSION_PNG, title=_title(self.config))
        draw_prediction(self.test_scenes[0], self.predictions[0], self.config["classes"], run.path / PREDICTION_PNG)
        if state.history:
            self.draw(run, state.history)
        return {
            **scores_of(confusion, "segment"),
            "per_class": per_class_scores(confusion, "segment", self.config["classes"]),
            "majority_class_accuracy": float(confusion.sum(axis=1).max() / max(confusion.sum(), 1)),
            "epochs": state.epoch,
            "test_scans": len(self.test_scenes),
            "test_points": int(confusion.sum()),
            "model": self.config["model"],
            "parameters": self.parameters,
        }


def identity_of(config: dict[str, Any]) -> dict[str, Any]:
    """What a scene run's checkpoints must match: model, options, features and classes."""
    return {"task": TASK, "model": config["model"], "model_options": config["model_options"],
            "features": config["features"], "outputs": len(config["classes"])}


def _title(config: dict[str, Any]) -> str:
    return f"segment scenes · {config['model']} · {config['radius']:g} m {config['shape']}s"


def train_scenes(
    data: Sequence[str | os.PathLike[str]],
    *,
    out: str | os.PathLike[str] = "runs/segment-scenes",
    model: str | None = None,
    features: Sequence[str] | None = None,
    grid: float | None = None,
    radius: float | None = None,
    shape: str | None = None,
    points: int | None = None,
    crops: int | None = None,
    epochs: int | None = None,
    batch_size: int | None = None,
    learning_rate: float | None = None,
    label_field: str | None = None,
    class_names: Sequence[str] | None = None,
    test_area: int | None = None,
    seed: int = 0,
    device: str | None = None,
    resume: bool = False,
    max_time: float | None = None,
    max_training_time: float | None = None,
    workers: int = 0,
    checkpoint_seconds: float | None = 300.0,
    progress: bool = True,
) -> dict[str, Any]:
    """Train a scene segmenter on ``data`` into the run folder ``out``; returns the final metrics.

    Settings left None take the recipe's defaults (module doc). ``label_field`` and
    ``class_names`` are for labelled files (:class:`~pointfield.clouds.datasets.LabelledClouds`),
    ``test_area`` for S3DIS (5). ``max_time``: the call returns within that many seconds of wall
    clock, reading the scans, the evaluations after each epoch and the final scores included (an
    evaluation the clock cannot hold is left to the final one); ``max_training_time``: training
    alone, evaluation excluded, summed over resumed sessions (what benchmarks compare);
    ``resume`` continues the run in ``out`` from its last checkpoint.
    The metrics: ``accuracy`` (overall), ``miou``, ``per_class`` IoU, ``mean_class_accuracy``,
    ``majority_class_accuracy`` (what always answering the commonest class would score),
    ``epochs``, ``seconds``, ...
    """
    settings = {
        "data": [os.fspath(p) for p in data], "model": model, "features": features, "grid": grid,
        "radius": radius, "shape": shape, "points": points, "crops": crops, "epochs": epochs,
        "batch_size": batch_size, "learning_rate": learning_rate, "label_field": label_field,
        "class_names": list(class_names) if class_names is not None else None, "test_area": test_area, "seed": seed,
    }
    return lifecycle.train(
        SceneSegmentTask, settings, options={"workers": workers}, out=out, resume=resume, device=device,
        max_time=max_time, max_training_time=max_training_time, checkpoint_seconds=checkpoint_seconds,
        progress=progress,
    )


# ---------------------------------------------------------------------------------------------
# The trained run
# ---------------------------------------------------------------------------------------------


class SceneRun(Run):
    """A trained scene segmenter, opened by :func:`pointfield.load_run`: ``evaluate`` and ``predict``."""

    tasks = (TASK,)

    @classmethod
    def open(cls, directory: RunDirectory, config: dict[str, Any], device: torch.device) -> SceneRun:
        if "classes" not in config:
            raise PointfieldError(f"{directory.path}: the run never got as far as opening its data")
        channels = sum(FEATURES[f] for f in config["features"])
        model = build_model(config["model"], "segment", len(config["classes"]), channels, **config["model_options"])
        return cls(directory, config, restore_model(directory, model, identity_of(config), device), device)

    def evaluate(self, data: Sequence[str | os.PathLike[str]] | None = None, *, progress: bool = False
                 ) -> dict[str, Any]:
        """Score the model on the test scans of ``data`` (default: the data it trained on).

        Returns ``accuracy``, ``mean_class_accuracy``, ``miou``, ``per_class`` IoU, the
        ``confusion`` matrix as rows, and the number of test ``scans`` and ``points``.
        """
        paths = [os.fspath(p) for p in data] if data else None
        dataset = open_split(self.config, "test", paths)
        scenes = read_prepared(dataset, self.config, progress)
        confusion, _ = confusion_over(self.module, scenes, self.config, self.device)
        return {
            **scores_of(confusion, "segment"),
            "per_class": per_class_scores(confusion, "segment", self.config["classes"]),
            "confusion": confusion.tolist(),
            "scans": len(scenes),
            "points": int(confusion.sum()),
        }

    def predict(
        self, files: Sequence[str | os.PathLike[str]], *, out: str | os.PathLike[str] | None = None,
        memory: str | int | None = None, progress: bool = False, scratch: str | os.PathLike[str] | None = None,
    ) -> list[dict[str, Any]]:
        """Label every point of each file and write it with its labels and their confidence.

        The scan is subsampled on the run's grid, covered with overlapping windows that vote
        (:func:`~pointfield.clouds.scene_crops.vote`), and every point takes the averaged
        probabilities of its grid cell: its label is the class code (the files' own codes for
        labelled data), written as LAS ``classification`` (uint8) or, in other formats, an int32
        ``label`` field; its ``confidence`` (float32) is the winning class's averaged
        probability. Points with a non-finite coordinate get label -1 (LAS: 0) and confidence
        0. ``out`` is a file (one input; its suffix picks the format) or a folder (default
        ``RUN/predictions``) where each output keeps its input's name. Beside each output,
        ``<output>.classes.json`` maps each code to its class name, and a LAS / LAZ output's header
        carries the same table as ASPRS's Classification Lookup VLR. Returns one dict per file:
        ``file``, ``output``, ``points`` and ``classes`` (name -> count).

        A file that reading whole would not fit in ``memory`` (``"2G"``, ``"512M"``; default: the
        memory the system has free) is predicted tile by tile within it, with the same labels
        (:mod:`~pointfield.clouds.scene_streaming`; ``scratch``: where its spills go, default
        beside the output); its dict adds ``tiles``, ``tile_size`` and ``halo``.
        """
        from pointfield.clouds.scene_streaming import predict_streamed, stream_info, wants_streaming

        paths = [Path(f) for f in files]
        if not paths:
            raise PointfieldError("no files to predict")
        targets = output_paths(paths, Path(out) if out is not None else self.path / "predictions")
        answers = []
        for path, target in zip(paths, targets):
            if not path.is_file():
                raise PointfieldError(f"{path}: no such file")
            info = stream_info(path)
            if info is not None and wants_streaming(*info, self.config, memory):
                answer = predict_streamed(self.module, self.config, self.device, path, target,
                                          memory if memory is not None else _free_memory(), progress=progress,
                                          scratch=scratch)
                write_class_table(target, self.config)
            else:
                answer = self._predict_file(path, target, progress)
            answers.append(answer)
        return answers

    def predict_tiles(
        self, inputs: Sequence[str | os.PathLike[str]], *, out: str | os.PathLike[str] | None = None,
        workers: int | None = None, scheduler: str | None = None, client: Any = None, progress: bool = False,
    ) -> list[dict[str, Any]]:
        """Label the tiles of one scan, a task per tile, each with its neighbours' points within a halo, so
        that the labels are those of the tiles merged into one cloud (:mod:`~pointfield.clouds.scene_tiles`).

        ``inputs`` are tile files and folders of them (their cloud files at any depth); each tile is
        written, as :meth:`predict` writes a file, to ``out`` (a folder, default ``RUN/predictions``)
        under its own name (a folder's files under their paths inside it). ``workers`` starts a
        local Dask cluster of that many processes, ``scheduler`` joins a running one, ``client`` is
        one the caller has; none of them: one tile after another in this process. Returns one dict
        per tile: ``file``, ``output``, ``points``, ``classes`` and ``neighbours``.
        """
        from pointfield.clouds.scene_tiles import predict_tiles, tile_targets

        paths, targets = tile_targets(inputs, Path(out) if out is not None else self.path / "predictions")
        return predict_tiles(self.module, self.config, self.device, paths, targets, workers=workers,
                             scheduler=scheduler, client=client, progress=progress)

    def _predict_file(self, path: Path, target: Path, progress: bool = False) -> dict[str, Any]:
        from pointfield.clouds.scene_streaming import frame_of

        config = self.config
        data = read(path)
        check_scan_fields(data, path, config)
        frame = frame_of(data, path)
        scan = as_scan(data, path, path.name, offset=frame.offset, intensity_scale=frame.intensity_scale)
        prepared, inverse = prepare_scene(scan, config["grid"], config["features"], path.name, return_inverse=True,
                                          origin=frame.origin, floor=frame.floor)
        with progress_bar(len(prepared), f"predict {path.name} (grid points)", progress) as bar:
            probabilities = vote(self.module, prepared, radius=config["radius"], points=config["points"],
                                 shape=config["shape"], features=config["features"],
                                 classes=len(config["classes"]), device=self.device,
                                 batch_size=config["batch_size"], bar=bar)
        return write_labelled(data, path, target, probabilities, inverse, config)


def check_scan_fields(data: Any, path: Path, config: dict[str, Any]) -> None:
    """Refuse a file that is not a point cloud, or lacks a field the run's features read."""
    if not isinstance(data, PointCloud):
        raise FormatError(path, "holds records without x y z coordinates, not a point cloud")
    for feature, field in (("colour", "colors"), ("intensity", "intensity")):
        if feature in config["features"] and field not in data.fields:
            raise FormatError(path, f"has no {field!r} field, which this model takes as input")


def write_labelled(data: PointCloud, path: Path, target: Path, probabilities: np.ndarray, inverse: np.ndarray,
                   config: dict[str, Any]) -> dict[str, Any]:
    """Write ``data`` (read from ``path``) to ``target`` with each point's label and confidence.

    ``probabilities`` ``(M, classes)`` are the voted grid points'; ``inverse`` ``(N,)`` each point's
    grid point, -1 for a non-finite one (label -1, LAS 0; confidence 0). Writes the class table
    beside the output; returns the answer :meth:`SceneRun.predict` gives for the file.
    """
    best = probabilities.argmax(axis=1)
    codes = np.asarray(config["codes"], np.int64)
    real = inverse >= 0
    labels = np.full(len(data), -1, np.int64)
    confidence = np.zeros(len(data), np.float32)
    labels[real] = codes[best[inverse[real]]]
    confidence[real] = probabilities[inverse[real], best[inverse[real]]]
    fields = dict(data.fields)
    metadata = dict(data.metadata)
    if target.suffix.lower() in LAS_SUFFIXES:
        from pointfield.clouds.datasets.labelled import with_class_lookup

        if codes.min() < 0 or codes.max() > 255:
            raise PointfieldError(f"{target}: LAS classification holds 0..255; this run's codes are "
                                  f"{codes.min()}..{codes.max()}: write .ply instead")
        fields["classification"] = np.where(real, labels, 0).astype(np.uint8)
        metadata = with_class_lookup(metadata, codes.tolist(), config["classes"])
    else:
        fields["label"] = labels.astype(np.int32)
    fields["confidence"] = confidence
    target.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(data, Mesh):
        labelled = Mesh(data.points, fields, data.shape, metadata, faces=data.faces,
                        face_fields=dict(data.face_fields))
    else:
        labelled = PointCloud(data.points, fields, data.shape, metadata)
    write(target, labelled)
    write_class_table(target, config)
    counts = np.bincount(best[inverse[real]], minlength=len(config["classes"]))
    return {"file": str(path), "output": str(target), "points": len(data),
            "classes": {n: int(c) for n, c in zip(config["classes"], counts) if c}}


def write_class_table(target: Path, config: dict[str, Any]) -> None:
    """``<target>.classes.json``: each code of the run's classes to its name."""
    table = target.with_name(target.name + ".classes.json")
    with atomic_path(table) as tmp:
        tmp.write_text(json.dumps({str(c): n for c, n in zip(config["codes"], config["classes"])}, indent=1))


def _free_memory() -> int:
    import psutil

    return int(psutil.virtual_memory().available)


def output_paths(paths: Sequence[Path], out: Path) -> list[Path]:
    """Where each prediction goes: ``out`` itself for one input and an ``out`` with a cloud format's
    suffix, else ``out/<input name>``."""
    if len(paths) == 1 and out.suffix and not out.is_dir():
        format_of(out, for_writing=True)  # an unknown suffix is refused before any work
        return [out]
    names = [p.name for p in paths]
    duplicate = next((n for n in names if names.count(n) > 1), None)
    if duplicate is not None:
        raise PointfieldError(f"two inputs are named {duplicate!r}: their outputs would clash")
    return [out / name for name in names]


def open_scene_run(run: str | os.PathLike[str], device: str | None = None) -> SceneRun:
    """The scene-segmentation run in folder ``run``, opened (refusing a run of another task)."""
    opened = lifecycle.open_run((SceneRun,), run, device)
    assert isinstance(opened, SceneRun)
    return opened
