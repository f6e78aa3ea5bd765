"""Shape classification with the PointNet family: a class per file, as Python: ``pointfield classify train|eval|predict``.

``import pointfield.classify`` (or ``import pointfield`` then ``pointfield.classify``); each function is
the command of the same name with the task filled in::

    import pointfield.classify
    metrics = pointfield.classify.train(model="pointnet", epochs=20, out="runs/shapes")
    for answer in pointfield.classify.predict("runs/shapes", ["scan.ply"]):
        print(answer["file"], answer["class"], answer["probability"])

torch is imported with this module, not with ``import pointfield``.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

from pointfield.clouds import run as _run
from pointfield.clouds import tasks as _tasks

TASK = "classify"


def train(data: str | os.PathLike[str] | None = None, *, out: str | os.PathLike[str] = "runs/classify",
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
