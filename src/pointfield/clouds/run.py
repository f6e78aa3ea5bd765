"""A trained classifier or segmenter opened for use: :class:`CloudRun`, and the command line's functions over it.

========================================  ==============================================
``pointfield classify|segment eval RUN``  :func:`evaluate` (:meth:`CloudRun.evaluate`)
``pointfield classify|segment predict``   :func:`predict` (:meth:`CloudRun.predict`)
========================================  ==============================================

The modules ``pointfield.classify`` and ``pointfield.segment`` are :func:`~pointfield.clouds.tasks.train`,
:func:`evaluate` and :func:`predict` with the task filled in::

    import pointfield.classify
    metrics = pointfield.classify.train(model="pointnet", epochs=20, out="runs/shapes")
    for answer in pointfield.classify.predict("runs/shapes", ["scan.ply"]):
        print(answer["file"], answer["class"], answer["probability"])

Prediction never samples at random: it keeps the ``points`` points that
:func:`~pointfield.clouds.ops.canonical_sample` chooses from their coordinates, so a file and
the same file with its points shuffled get the same answer.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from pointfield.clouds import batched, ops
from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.datasets import PART_LABEL_FIELD, CloudCollate
from pointfield.clouds.formats import read, write
from pointfield.clouds.mesh import Mesh
from pointfield.clouds.tasks import (
    build_cloud_model,
    check_not_empty,
    confusion_on,
    evaluation_transform,
    identity_of,
    label_names,
    open_data,
    per_class_scores,
    scores_of,
    shape_scores,
)
from pointfield.errors import FormatError, PointfieldError
from pointfield.training.lifecycle import open_run as open_trained
from pointfield.training.lifecycle import restore_model
from pointfield.training.run import Run, RunDirectory


class CloudRun(Run):
    """A trained classifier or segmenter, opened by :func:`pointfield.load_run` (or :meth:`open`)."""

    tasks = ("classify", "segment")

    @classmethod
    def open(cls, directory: RunDirectory, config: dict[str, Any], device: torch.device) -> CloudRun:
        if "classes" not in config:
            raise PointfieldError(f"{directory.path}: the run never got as far as opening its data")
        model = restore_model(directory, build_cloud_model(config), identity_of(config), device)
        return cls(directory, config, model, device)

    def evaluate(
        self, data: str | os.PathLike[str] | None = None, *, on_error: str = "skip", progress: bool = False
    ) -> dict[str, Any]:
        """Score the model on the test split of ``data`` (default: the data it trained on).

        Returns ``accuracy``, ``mean_class_accuracy`` (and ``miou`` for segmentation), the score
        of each class (``per_class``: accuracy, or IoU for segmentation), the ``confusion``
        matrix as a list of rows, and the number of ``samples``. Part segmentation of categories
        with fixed parts (ShapeNetPart, the synthetic shapes) adds ShapeNetPart's per-shape scores:
        ``instance_miou``, ``class_miou`` and ``per_category`` (:func:`~pointfield.metrics.shape_part_iou`).
        """
        config, task = self.config, self.task
        self.warn_if_unfinished("these scores are")
        data = data if data is not None else config["data"]
        dataset = open_data(
            task, data, "test", seed=config["seed"], on_error=on_error,
            label_field=config["label_field"], shapes_per_class=config["shapes_per_class"],
            classes=config["classes"] if data is not None else None, points=config["points"],
            mesh_points=config["mesh_points"], progress=progress,
        )
        check_not_empty(dataset, "test", data)
        if task == "segment" and dataset.parts and len(dataset.parts) > len(config["parts"]):
            raise PointfieldError(
                f"{data}: its labels go up to {len(dataset.parts) - 1}, but the model knows "
                f"{len(config['parts'])} parts"
            )
        collate = CloudCollate(config["features"], point_labels=task == "segment")
        dataset = dataset.with_transform(evaluation_transform(config["points"]))
        confusion, totals = confusion_on(self.module, dataset, task, config, collate, self.device,
                                         category_parts=dataset.category_parts)
        return {
            **scores_of(confusion, task),
            "per_class": per_class_scores(confusion, task, label_names(config)),
            **shape_scores(totals, config["classes"]),
            "confusion": confusion.tolist(),
            "samples": len(dataset),
        }

    def predict(
        self, files: Sequence[str | os.PathLike[str]], *, out: str | os.PathLike[str] | None = None
    ) -> list[dict[str, Any]]:
        """Apply the model to files.

        Classification: one dict per file with ``file``, ``class``, ``probability`` and
        ``probabilities`` (class name -> probability). Segmentation: every point of each file
        gets the part of its nearest model-input point, and the cloud (a mesh keeps its faces)
        is written with an int32 ``label`` field to ``out/<stem>.ply`` (default
        ``RUN/predictions``); one dict per file with ``file``, ``output``, ``points`` and
        ``parts`` (part name -> count).
        """
        config, task = self.config, self.task
        paths = [Path(f) for f in files]
        if not paths:
            raise PointfieldError("no files to predict")
        self.warn_if_unfinished("predictions come from")
        collate = CloudCollate(config["features"])
        out_dir = Path(out) if out is not None else self.path / "predictions"
        if task == "segment":
            stems = [p.stem for p in paths]
            duplicate = next((s for s in stems if stems.count(s) > 1), None)
            if duplicate is not None:
                raise PointfieldError(f"two inputs are named {duplicate!r}: their outputs would clash")
        results = []
        for path in paths:
            data, prepared, centre, radius = prepare_for_prediction(path, config)
            batch = collate([(prepared, 0)]).to(self.device)
            with torch.inference_mode():
                logits = self.module(batch.points, batch.features, batch.mask)[0].float()
            if task == "classify":
                results.append(_class_answer(path, logits, config["classes"]))
            else:
                results.append(_write_parts(path, data, prepared, centre, radius, logits, config, out_dir))
        return results


def _class_answer(path: Path, logits: torch.Tensor, classes: Sequence[str]) -> dict[str, Any]:
    probabilities = torch.softmax(logits, dim=-1).cpu().numpy()
    best = int(probabilities.argmax())
    return {
        "file": str(path),
        "class": classes[best],
        "probability": float(probabilities[best]),
        "probabilities": {name: float(p) for name, p in zip(classes, probabilities)},
    }


def _write_parts(
    path: Path, data: PointCloud, prepared: PointCloud, centre: np.ndarray, radius: float,
    logits: torch.Tensor, config: dict[str, Any], out_dir: Path,
) -> dict[str, Any]:
    """Label every point of ``data`` by its nearest model input, write it, count the parts."""
    input_labels = logits.argmax(dim=-1).cpu()
    labels = np.full(len(data), -1, np.int32)
    targets = np.flatnonzero(ops.finite_rows(data.points))
    if len(targets):
        moved = (data.points[targets].astype(np.float64) - centre) / radius
        _, nearest = batched.knn(
            torch.from_numpy(moved.astype(np.float32))[None], torch.from_numpy(prepared.points)[None], 1,
        )
        labels[targets] = input_labels[nearest[0, :, 0]].numpy()
    out_dir.mkdir(parents=True, exist_ok=True)
    output = out_dir / f"{path.stem}.ply"
    write(output, _with_field(data, PART_LABEL_FIELD, labels))
    counts = np.bincount(labels[labels >= 0], minlength=len(config["parts"]))
    return {
        "file": str(path),
        "output": str(output),
        "points": int(len(labels)),
        "parts": {name: int(c) for name, c in zip(config["parts"], counts) if c},
    }


def prepare_for_prediction(
    path: Path, config: dict[str, Any]
) -> tuple[PointCloud, PointCloud, np.ndarray, float]:
    """Read a file as the model needs it: ``(as read, model input, centre, radius)``.

    Meshes are surface-sampled (seeded by file name). The model input is the canonical sample
    of ``points`` finite points, mapped by ``(p - centre) / radius`` into the unit sphere of
    all the finite points.
    """
    data = read(path)
    if not isinstance(data, PointCloud):
        raise FormatError(path, "holds records without x y z coordinates, not a point cloud")
    source = data
    if isinstance(data, Mesh) and len(data.faces):
        seed = int.from_bytes(hashlib.sha1(path.name.encode()).digest()[:4], "little")
        try:
            source = data.sample_surface(config["mesh_points"], seed=seed)
        except ValueError as error:
            raise FormatError(path, f"cannot sample the mesh surface: {error}") from None
    finite = ops.finite_rows(source.points)
    if not finite.any():
        raise FormatError(path, "has no points with finite coordinates")
    for name in config["features"]:
        if name not in source.fields:
            raise FormatError(path, f"has no {name!r} field, which this model takes as input")
    clean = source.select(finite)
    centre, radius = ops.unit_sphere_frame(clean.points)
    chosen = clean.select(ops.canonical_sample(clean.points, config["points"]))
    points = ((chosen.points.astype(np.float64) - centre) / radius).astype(np.float32)
    prepared = PointCloud(points, chosen.fields)
    return data, prepared, centre, radius


def open_run(task: str, run: str | os.PathLike[str], device: str | None = None) -> CloudRun:
    """The ``task`` run in folder ``run``, opened (refusing a run of another task)."""
    opened = open_trained((CloudRun,), run, device)
    if opened.task != task:
        raise PointfieldError(f"{opened.path} is a {opened.task!r} run, not {task!r}")
    return opened


def evaluate(
    task: str,
    run: str | os.PathLike[str],
    data: str | os.PathLike[str] | None = None,
    *,
    device: str | None = None,
    on_error: str = "skip",
    progress: bool = False,
) -> dict[str, Any]:
    """Score a trained run on the test split of ``data`` (see :meth:`CloudRun.evaluate`)."""
    return open_run(task, run, device).evaluate(data, on_error=on_error, progress=progress)


def predict(
    task: str,
    run: str | os.PathLike[str],
    files: Sequence[str | os.PathLike[str]],
    *,
    device: str | None = None,
    out: str | os.PathLike[str] | None = None,
) -> list[dict[str, Any]]:
    """Apply a trained run to files (see :meth:`CloudRun.predict`)."""
    return open_run(task, run, device).predict(files, out=out)


def _with_field(data: PointCloud, name: str, values: np.ndarray) -> PointCloud:
    fields = {**data.fields, name: values}
    if isinstance(data, Mesh):
        return Mesh(data.points, fields, data.shape, dict(data.metadata), faces=data.faces,
                    face_fields=dict(data.face_fields))
    return PointCloud(data.points, fields, data.shape, dict(data.metadata))


# ---------------------------------------------------------------------------------------------
