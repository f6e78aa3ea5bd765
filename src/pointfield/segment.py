"""Part segmentation with the PointNet family: a label per point, as Python: ``pointfield segment train|eval|predict``.

``import pointfield.segment`` (or ``import pointfield`` then ``pointfield.segment``); each function is
the command of the same name with the task filled in::

    import pointfield.segment
    metrics = pointfield.segment.train(out="runs/parts")
    pointfield.segment.predict("runs/parts", ["scan.ply"], out="labelled/")   # files with a label field

Whole scans (S3DIS, ScanNet v2, SemanticKITTI, labelled files, synthetic rooms and streets) train on
crops with :func:`train_scenes`, whose run :func:`pointfield.load_run` opens (docs/scenes.md).

torch is imported with this module, not with ``import pointfield``.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

from pointfield.clouds import run as _run
from pointfield.clouds import scene_tasks as _scene_tasks
from pointfield.clouds import tasks as _tasks

TASK = "segment"


def train(data: str | os.PathLike[str] | None = None, *, out: str | os.PathLike[str] = "runs/segment",
          **options: Any) -> dict[str, Any]:
    """Train on ``data`` into the run folder ``out`` and return the final metrics; the options are
    those of :func:`pointfield.clouds.tasks.train` (``model``, ``epochs``, ``resume``, ...)."""
    return _tasks.train(TASK, data, out=out, **options)


def evaluate(run: str | os.PathLike[str], data: str | os.PathLike[str] | None = None, **options: Any) -> dict[str, Any]:
    """Score the run in folder ``run`` on the test split of ``data`` (:meth:`~pointfield.clouds.run.CloudRun.evaluate`)."""
    return _run.evaluate(TASK, run, data, **options)


def predict(run: str | os.PathLike[str], files: Sequence[str | os.PathLike[str]], **options: Any) -> list[dict[str, Any]]:
    """Apply the run in folder ``run`` to ``files`` (:meth:`~pointfield.clouds.run.CloudRun.predict`)."""
    return _run.predict(TASK, run, files, **options)


def train_scenes(data: Sequence[str | os.PathLike[str]], *, out: str | os.PathLike[str] = "runs/segment-scenes",
                 **options: Any) -> dict[str, Any]:
    """Train semantic segmentation of whole scans in ``data`` on crops into the run folder ``out``; the
    options are those of :func:`pointfield.clouds.scene_tasks.train_scenes` (``model``, ``radius``, ...)."""
    return _scene_tasks.train_scenes(data, out=out, **options)
