"""Classification and segmentation of point clouds: the training behind ``pointfield classify train``
and ``pointfield segment train``, as functions of a task name.

:func:`train` runs a :class:`CloudTask` through the one training lifecycle of
:mod:`pointfield.training`: the task opens the data (a folder, ModelNet, or the built-in
synthetic shapes), builds a model from :mod:`pointfield.clouds.models`, and gives the loop the
batches of an epoch and the loss of a batch. A finished run opens as a
:class:`~pointfield.clouds.run.CloudRun` (:func:`pointfield.load_run`), which evaluates and
predicts.

The recipe, the same for every model unless told otherwise:

- preparation: drop non-finite points, centre and scale into the unit sphere, sample
  ``points`` points (random in training; a fixed random subset per shape in evaluation);
- augmentation (training only): stretch each axis by 0.8..1.25, shift by up to 0.1, jitter
  every coordinate with N(0, 0.01²) clipped to 0.05 — PointNet++'s ModelNet recipe;
- optimisation: Adam, learning rate 0.001, weight decay 1e-4, cosine decay to 1 % of it over
  the epochs; cross-entropy loss plus the model's regulariser;
- BatchNorm momentum as in the PointNet papers' code: 0.5, halved every 200,000 training
  samples, never below 0.01. Running statistics start from mean 0 and variance 1; with
  PyTorch's default 0.1 a layer whose true variance is far from 1 needs hundreds of steps
  before evaluation sees it right, which a short run on a CPU may never take.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from pointfield.clouds.datasets import (
    DEFAULT_MESH_POINTS,
    PART_LABEL_FIELD,
    CloudCollate,
    CloudDataset,
    CloudFolder,
    ModelNet,
    ShapeNetPart,
    default_cache_dir,
    is_shapenetpart,
    modelnet_source,
)
from pointfield.clouds.models import MODEL_NAMES, MODEL_OPTIONS, SCENE_ONLY, build_model, count_parameters
from pointfield.clouds.shapes import SyntheticShapes
from pointfield.clouds.transforms import (
    Compose,
    NormaliseScale,
    RandomJitter,
    RandomScale,
    RandomShift,
    SamplePoints,
)
from pointfield.errors import PointfieldError
from pointfield.metrics import (
    accuracy,
    class_accuracies,
    class_iou,
    confusion_matrix,
    instance_mean_iou,
    mean_class_accuracy,
    mean_iou,
    restricted_argmax,
    shape_part_iou,
)
from pointfield.training import lifecycle
from pointfield.training.distributed import shard, wrap
from pointfield.training.loop import TrainingState
from pointfield.training.run import RunDirectory
from pointfield.training.task import Step, Task
from pointfield.version import __version__
from pointfield.viz.plots import plot_confusion_matrix, plot_training_curves

TASKS = ("classify", "segment")
DEFAULT_POINTS = 1024
DEFAULT_EPOCHS = {"pointnet": 10, "pointnet2": 5, "pointnet2-msg": 5}
DEFAULT_BATCH_SIZE = {"pointnet": 32, "pointnet2": 16, "pointnet2-msg": 16}
LEARNING_RATE = 1e-3
WEIGHT_DECAY = 1e-4
FINAL_LEARNING_RATE_FRACTION = 0.01
BATCHNORM_MOMENTUM = (0.5, 200_000, 0.01)  # start, samples per halving, floor
MAX_POINTS_PER_POINT = 16  # clouds keep at most 16 x `points` points in memory
CURVES_PNG = "training_curves.png"
CONFUSION_PNG = "confusion_matrix.png"


# ---------------------------------------------------------------------------------------------
# Data
# ---------------------------------------------------------------------------------------------


def training_transform(points: int) -> Compose:
    return Compose([
        NormaliseScale(), SamplePoints(points), RandomScale(0.8, 1.25), RandomShift(0.1),
        RandomJitter(0.01, clip=0.05),
    ])


def evaluation_transform(points: int) -> Compose:
    return Compose([NormaliseScale(), SamplePoints(points)])


def open_data(
    task: str,
    data: str | os.PathLike[str] | None,
    split: str,
    *,
    seed: int = 0,
    on_error: str = "skip",
    label_field: str = PART_LABEL_FIELD,
    shapes_per_class: int | None = None,
    classes: Sequence[str] | None = None,
    points: int = DEFAULT_POINTS,
    mesh_points: int = DEFAULT_MESH_POINTS,
    progress: bool = False,
) -> CloudDataset:
    """The ``split`` of ``data`` for ``task``, without transforms.

    ``data`` None: the synthetic shapes (``shapes_per_class`` training shapes per class, 30 %
    as many test shapes, each of ``points`` to ``2 * points`` points). A folder of ModelNet
    ``.h5`` or ``_normal_resampled`` files: :class:`ModelNet`. ShapeNetPart's folder, for
    segmentation: :class:`ShapeNetPart`. Any other folder: :class:`CloudFolder`, meshes sampled once and cached
    under :func:`default_cache_dir`; for segmentation its clouds need the per-point integer
    field ``label_field``. ``classes`` fixes the class order (that of a trained model).
    """
    if data is None:
        per_class = shapes_per_class or 100
        count = per_class if split == "train" else max(1, round(per_class * 0.3))
        return SyntheticShapes(split, count, points=(points, 2 * points), seed=seed)
    root = Path(data)
    if not root.is_dir():
        raise PointfieldError(f"{root}: DATA must be a folder of point clouds (or ModelNet)")
    if task == "classify" and modelnet_source(root) in ("h5", "txt"):
        dataset = ModelNet(root, split, seed=seed, on_error=on_error, progress=progress)
        if classes is not None and list(dataset.classes) != list(classes):
            raise PointfieldError(
                f"{root}: its classes {dataset.classes} are not those the model was trained on"
            )
        return dataset
    if task == "segment" and is_shapenetpart(root):
        dataset = ShapeNetPart(root, split, seed=seed, on_error=on_error, progress=progress)
        if classes is not None and list(dataset.classes) != list(classes):
            raise PointfieldError(f"{root}: its categories {dataset.classes} are not those the model was trained on")
        return dataset
    dataset = CloudFolder(
        root, split, seed=seed, on_error=on_error, mesh_points=mesh_points,
        max_points=MAX_POINTS_PER_POINT * points,
        label_field=label_field if task == "segment" else None,
        cache_dir=default_cache_dir() / "meshes", classes=classes, progress=progress,
    )
    if task == "classify" and (not dataset.classes or any(label < 0 for label in dataset.labels)):
        raise PointfieldError(
            f"{root}: classification needs one subfolder per class (e.g. {root}/chair/*.ply)"
        )
    return dataset


def check_not_empty(dataset: CloudDataset, split: str, data: Any) -> None:
    if len(dataset) == 0:
        where = data if data is not None else "the synthetic shapes"
        raise PointfieldError(f"{where}: no {split} clouds to use")


# ---------------------------------------------------------------------------------------------
# Training
# ---------------------------------------------------------------------------------------------


class CloudTask(Task):
    """Classification or segmentation of clouds, as the training lifecycle runs it (see the module doc)."""

    extendable = ("epochs",)

    @classmethod
    def configure(cls, settings: dict[str, Any]) -> dict[str, Any]:
        model = settings["model"]
        if model not in MODEL_NAMES:
            raise PointfieldError(f"unknown model {model!r}: expected one of {', '.join(MODEL_NAMES)}")
        if model in SCENE_ONLY:
            raise PointfieldError(f"model {model!r} segments scenes: give segment train a scene dataset or "
                                  "labelled scans")
        if settings["points"] < 1:
            raise PointfieldError(f"--points must be at least 1, got {settings['points']}")
        options = dict(MODEL_OPTIONS[model])
        if model == "pointnet":
            options.update(input_transform=settings["input_transform"],
                           feature_transform=settings["feature_transform"])
        data = settings["data"]
        return {
            "task": cls.name,
            "model": model,
            "model_options": options,
            "data": None if data is None else str(Path(data).resolve()),
            "points": settings["points"],
            "epochs": settings["epochs"] if settings["epochs"] is not None else DEFAULT_EPOCHS[model],
            "batch_size": settings["batch_size"] or DEFAULT_BATCH_SIZE[model],
            "learning_rate": settings["learning_rate"],
            "seed": settings["seed"],
            "features": ["normals"] if settings["normals"] else [],
            "label_field": settings["label_field"],
            "shapes_per_class": settings["shapes_per_class"],
            "mesh_points": DEFAULT_MESH_POINTS,
            "pointfield_version": __version__,
        }

    def __init__(self, config, device, distributed, progress, *, workers: int = 0, on_error: str = "skip"):
        super().__init__(config, device, distributed, progress)
        self.workers = workers
        train_set, test_set = _open_pair(config, on_error, progress)
        config.update(_data_summary(train_set, test_set, config))
        config["world_size"] = distributed.world_size if distributed else 1
        config["device"] = str(device)
        self.model = build_cloud_model(config).to(device)
        self.parameters = count_parameters(self.model)
        self.trained = wrap(self.model, distributed, device)
        self.optimizer = torch.optim.Adam(
            self.trained.parameters(), lr=config["learning_rate"], weight_decay=WEIGHT_DECAY
        )
        self.scheduler = torch.optim.lr_scheduler.CosineAnnealingLR(
            self.optimizer, T_max=max(config["epochs"], 1),
            eta_min=config["learning_rate"] * FINAL_LEARNING_RATE_FRACTION,
        )
        self.epochs = config["epochs"]
        self.identity = identity_of(config)
        self.collate = CloudCollate(config["features"], point_labels=self.name == "segment")
        self.train_set = train_set.with_transform(training_transform(config["points"]))
        self.test_set = test_set.with_transform(evaluation_transform(config["points"]))
        self.confusion: np.ndarray | None = None
        self.shape_totals: np.ndarray | None = None
        if distributed is None or distributed.is_main:
            print(f"{self.name} {config['model']}: {self.parameters:,} parameters on {device}; "
                  f"{config['data_description']}")

    def batches(self, epoch: int) -> torch.utils.data.DataLoader:
        set_batchnorm_momentum(self.model, epoch * len(self.train_set))
        self.train_set.set_epoch(epoch)
        return _training_loader(
            self.train_set, self.config, self.collate, epoch, self.workers, self.distributed, self.device
        )

    def step(self, batch: Any) -> Step:
        """Cross-entropy (per shape, or per real point), with the model's regulariser beside it."""
        batch = batch.to(self.device)
        logits, regulariser = self.trained(batch.points, batch.features, batch.mask, with_regulariser=True)
        if self.name == "classify":
            loss = F.cross_entropy(logits, batch.labels)
            correct = (logits.argmax(dim=-1) == batch.labels).float().mean()
        else:
            target = batch.point_labels.reshape(-1)
            flat = logits.reshape(-1, logits.shape[-1])
            loss = F.cross_entropy(flat, target, ignore_index=-1)
            real = target >= 0
            correct = (flat.argmax(-1)[real] == target[real]).float().mean()
        # A model without a regulariser (PointNet++, PointNet without its feature T-Net) returns a
        # constant 0: no loss term, and nothing to log.
        auxiliary = {"regulariser": regulariser} if regulariser.requires_grad else {}
        return Step(loss, {"accuracy": float(correct)}, auxiliary)

    def evaluate(self, epoch: int) -> dict[str, float]:
        if self.distributed is not None:
            self.distributed.broadcast_buffers(self.model)  # one model scored, and saved, on every rank
        self.confusion, self.shape_totals = confusion_on(
            self.model, self.test_set, self.name, self.config, self.collate, self.device, self.distributed,
            self.test_set.category_parts,
        )
        scores = {**scores_of(self.confusion, self.name), **shape_scores(self.shape_totals, self.config["classes"])}
        return {f"test_{k}": v for k, v in scores.items() if not isinstance(v, dict)}

    def draw(self, run: RunDirectory, history: list[dict[str, Any]]) -> None:
        plot_training_curves(history, run.path / CURVES_PNG, title=_title(self.config))

    def finish(self, run: RunDirectory, state: TrainingState) -> dict[str, Any]:
        confusion, totals = self.confusion, self.shape_totals
        if confusion is None:  # a resumed run that had already finished its epochs
            confusion, totals = confusion_on(self.model, self.test_set, self.name, self.config, self.collate,
                                             self.device, self.distributed, self.test_set.category_parts)
        if self.distributed is None or self.distributed.is_main:
            plot_confusion_matrix(confusion, label_names(self.config), run.path / CONFUSION_PNG,
                                  title=_title(self.config))
            if state.history:
                self.draw(run, state.history)
        return {
            **scores_of(confusion, self.name),
            "per_class": per_class_scores(confusion, self.name, label_names(self.config)),
            **shape_scores(totals, self.config["classes"]),
            "epochs": state.epoch,
            "test_samples": len(self.test_set),
            "train_samples": len(self.train_set),
            "model": self.config["model"],
            "parameters": self.parameters,
        }


class ClassifyTask(CloudTask):
    name = "classify"


class SegmentTask(CloudTask):
    name = "segment"


TASK_CLASSES: dict[str, type[CloudTask]] = {"classify": ClassifyTask, "segment": SegmentTask}


def train(
    task: str,
    data: str | os.PathLike[str] | None = None,
    *,
    model: str = "pointnet",
    epochs: int | None = None,
    batch_size: int | None = None,
    points: int = DEFAULT_POINTS,
    out: str | os.PathLike[str] = "run",
    device: str | None = None,
    seed: int = 0,
    resume: bool = False,
    normals: bool = False,
    input_transform: bool = True,
    feature_transform: bool = True,
    learning_rate: float = LEARNING_RATE,
    workers: int = 0,
    on_error: str = "skip",
    label_field: str = PART_LABEL_FIELD,
    shapes_per_class: int | None = None,
    checkpoint_seconds: float | None = 300.0,
    progress: bool = True,
) -> dict[str, Any]:
    """Train a classifier or segmenter and write its run folder; returns the final metrics.

    ``data``: a folder of clouds (one subfolder per class), ModelNet, or None for the built-in
    synthetic shapes. The number of epochs and the batch size default to the model's recipe
    (PointNet 10 and 32, PointNet++ 5 and 16). ``input_transform`` / ``feature_transform``
    switch PointNet's T-Nets; ``normals`` feeds per-point normals as input features. With
    ``resume`` the run in ``out`` continues from its last checkpoint with the settings in its
    ``config.json`` (only ``epochs``, if given, may change). Launched by ``torchrun`` with
    several processes, this trains with DistributedDataParallel. Classification returns
    ``accuracy``, ``mean_class_accuracy``, ``per_class`` accuracy, ``epochs``, ``seconds``, ...;
    segmentation adds ``miou`` and gives IoU ``per_class``.
    """
    settings = {
        "data": data, "model": model, "epochs": epochs, "batch_size": batch_size, "points": points,
        "seed": seed, "normals": normals, "input_transform": input_transform,
        "feature_transform": feature_transform, "learning_rate": learning_rate,
        "label_field": label_field, "shapes_per_class": shapes_per_class,
    }
    return lifecycle.train(
        _task_class(task), settings, options={"workers": workers, "on_error": on_error}, out=out,
        resume=resume, device=device, checkpoint_seconds=checkpoint_seconds, progress=progress,
    )


def _open_pair(
    config: dict[str, Any], on_error: str, progress: bool
) -> tuple[CloudDataset, CloudDataset]:
    options = dict(
        seed=config["seed"], on_error=on_error, label_field=config["label_field"],
        shapes_per_class=config["shapes_per_class"], points=config["points"],
        mesh_points=config["mesh_points"], progress=progress,
    )
    train_set = open_data(config["task"], config["data"], "train", **options)
    check_not_empty(train_set, "train", config["data"])
    test_set = open_data(
        config["task"], config["data"], "test", classes=train_set.classes, **options
    )
    check_not_empty(test_set, "test", config["data"])
    if config["task"] == "segment" and not train_set.parts:
        raise PointfieldError(f"{config['data']}: these clouds carry no per-point labels")
    return train_set, test_set


def _data_summary(
    train_set: CloudDataset, test_set: CloudDataset, config: dict[str, Any]
) -> dict[str, Any]:
    description = f"{train_set.describe()}; test: {len(test_set)} clouds"
    if getattr(train_set, "held_out", False):
        description += " (held out of the files: the data has no test split)"
    parts = None
    if config["task"] == "segment":
        # A test file may use a higher label than any training file: cover both.
        parts = max(list(train_set.parts or []), list(test_set.parts or []), key=len)
    return {
        "classes": list(train_set.classes),
        "parts": parts,
        "train_samples": len(train_set),
        "test_samples": len(test_set),
        "data_description": description,
    }


def _training_loader(
    dataset: CloudDataset, config: dict[str, Any], collate: CloudCollate, epoch: int,
    workers: int, dist_info: Any, device: torch.device,
) -> torch.utils.data.DataLoader:
    """This epoch's batches: shuffled by a generator seeded with (seed, epoch)."""
    if dist_info is not None:
        sampler = torch.utils.data.DistributedSampler(
            dataset, dist_info.world_size, dist_info.rank, shuffle=True, seed=config["seed"]
        )
        sampler.set_epoch(epoch)
        share = len(sampler)
    else:
        generator = torch.Generator().manual_seed(config["seed"] * 100_003 + epoch)
        sampler = torch.utils.data.RandomSampler(dataset, generator=generator)
        share = len(dataset)
    # BatchNorm cannot train on a batch of one; dropping the last partial batch avoids it.
    batch_size = max(2, min(config["batch_size"], share))
    return torch.utils.data.DataLoader(
        dataset, batch_size=batch_size, sampler=sampler, collate_fn=collate,
        num_workers=workers, drop_last=share >= 2, pin_memory=device.type == "cuda",
    )


def set_batchnorm_momentum(model: torch.nn.Module, samples_seen: int) -> float:
    """Set every BatchNorm's momentum to ``max(0.5 * 0.5^(samples / 200000), 0.01)``."""
    start, halving, floor = BATCHNORM_MOMENTUM
    momentum = max(start * 0.5 ** (samples_seen / halving), floor)
    for module in model.modules():
        if isinstance(module, torch.nn.modules.batchnorm._BatchNorm):
            module.momentum = momentum
    return momentum


# ---------------------------------------------------------------------------------------------
# Evaluation
# ---------------------------------------------------------------------------------------------


def confusion_on(
    model: torch.nn.Module,
    dataset: CloudDataset,
    task: str,
    config: dict[str, Any],
    collate: CloudCollate,
    device: torch.device,
    dist_info: Any = None,
    category_parts: Sequence[Sequence[int]] | None = None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """The confusion matrix of ``model`` over ``dataset`` (summed over processes), and for part
    segmentation with ``category_parts`` (each class's part labels), the ``(2, C)`` totals of the
    shapes' IoUs per category (:func:`~pointfield.metrics.instance_mean_iou`), each shape's
    prediction restricted to its category's parts as Pointcept scores ShapeNetPart; else None."""
    classes = len(label_names(config))
    subset = torch.utils.data.Subset(dataset, shard(len(dataset), dist_info))
    loader = torch.utils.data.DataLoader(
        subset, batch_size=config["batch_size"], shuffle=False, collate_fn=collate
    )
    confusion = np.zeros((classes, classes), np.int64)
    by_shape = task == "segment" and category_parts is not None
    totals = np.zeros((2, len(category_parts)), np.float64) if by_shape else None
    was_training = model.training
    model.eval()
    with torch.inference_mode():
        for batch in loader:
            batch = batch.to(device)
            scores = model(batch.points, batch.features, batch.mask)
            predicted = scores.argmax(dim=-1)
            target = batch.labels if task == "classify" else batch.point_labels
            confusion += confusion_matrix(target, predicted, classes)
            if totals is not None:
                for row, category in enumerate(batch.labels.tolist()):
                    real = batch.point_labels[row] >= 0
                    parts = category_parts[category]
                    guess = restricted_argmax(scores[row][real], parts)
                    totals[0, category] += shape_part_iou(batch.point_labels[row][real], guess, parts)
                    totals[1, category] += 1
    model.train(was_training)
    if dist_info is not None:
        confusion = dist_info.all_reduce_sum(torch.from_numpy(confusion).to(device)).cpu().numpy()
        if totals is not None:
            totals = dist_info.all_reduce_sum(torch.from_numpy(totals).to(device)).cpu().numpy()
    return confusion, totals


def scores_of(confusion: np.ndarray, task: str) -> dict[str, float]:
    scores = {"accuracy": accuracy(confusion), "mean_class_accuracy": mean_class_accuracy(confusion)}
    if task == "segment":
        scores["miou"] = mean_iou(confusion)
    return scores


def shape_scores(totals: np.ndarray | None, categories: Sequence[str]) -> dict[str, Any]:
    """``instance_miou``, ``class_miou`` and ``per_category`` mIoU (None: no test shape) from the
    totals of :func:`confusion_on`; nothing when there are none (no categories with fixed parts)."""
    if totals is None:
        return {}
    instance, by_class, per_category = instance_mean_iou(totals)
    return {"instance_miou": instance, "class_miou": by_class,
            "per_category": {name: None if np.isnan(v) else float(v) for name, v in zip(categories, per_category)}}


def per_class_scores(confusion: np.ndarray, task: str, names: Sequence[str]) -> dict[str, float | None]:
    values = class_iou(confusion) if task == "segment" else class_accuracies(confusion)
    return {name: None if np.isnan(v) else float(v) for name, v in zip(names, values)}


# ---------------------------------------------------------------------------------------------
# Helpers
# ---------------------------------------------------------------------------------------------


def identity_of(config: dict[str, Any]) -> dict[str, Any]:
    """What a run's checkpoints must match: task, model and its options, and the outputs."""
    return {
        "task": config["task"],
        "model": config["model"],
        "model_options": config["model_options"],
        "features": config["features"],
        "outputs": len(label_names(config)),
    }


def build_cloud_model(config: dict[str, Any]) -> torch.nn.Module:
    in_channels = 3 * len(config["features"])
    return build_model(
        config["model"], config["task"], len(label_names(config)), in_channels,
        **config["model_options"],
    )


def label_names(config: dict[str, Any]) -> list[str]:
    return config["classes"] if config["task"] == "classify" else config["parts"]


def _title(config: dict[str, Any]) -> str:
    return f"{config['task']} · {config['model']} · {config['points']} points"


def _task_class(task: str) -> type[CloudTask]:
    if task not in TASK_CLASSES:
        raise PointfieldError(f"unknown task {task!r}: expected one of {', '.join(TASK_CLASSES)}")
    return TASK_CLASSES[task]
