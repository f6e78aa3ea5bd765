"""Shape classification from Python: the functions behind ``pointfield classify``.

========================================  ============================================
``pointfield classify train [DATA] ...``  :func:`train`
``pointfield classify eval RUN [DATA]``   :func:`evaluate` (``eval`` is Python's own)
``pointfield classify predict RUN FILE``  :func:`predict`
========================================  ============================================

Example::

    import pointfield.classify as classify
    metrics = classify.train(model="pointnet", epochs=20, out="runs/shapes")  # synthetic shapes
    print(metrics["accuracy"])
    for answer in classify.predict("runs/shapes", ["scan.ply"]):
        print(answer["file"], answer["class"], answer["probability"])

The recipe and the run folder are described in :mod:`pointfield.clouds.tasks`.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

from pointfield.clouds import tasks


def train(
    data: str | os.PathLike[str] | None = None,
    *,
    model: str = "pointnet",
    epochs: int | None = None,
    batch_size: int | None = None,
    points: int = tasks.DEFAULT_POINTS,
    out: str | os.PathLike[str] = "runs/classify",
    device: str | None = None,
    seed: int = 0,
    resume: bool = False,
    normals: bool = False,
    input_transform: bool = True,
    feature_transform: bool = True,
    learning_rate: float = tasks.LEARNING_RATE,
    workers: int = 0,
    on_error: str = "skip",
    shapes_per_class: int | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Train a classifier on ``data`` (a folder, ModelNet, or None for the synthetic shapes).

    Writes the run folder ``out`` and returns the final test metrics: ``accuracy``,
    ``mean_class_accuracy``, ``per_class`` accuracy, ``epochs``, ``seconds``, ... The number
    of epochs and the batch size default to the model's recipe (PointNet 10 and 32,
    PointNet++ 5 and 16). ``input_transform`` / ``feature_transform`` switch PointNet's
    T-Nets; ``normals`` feeds per-point normals as input features.
    """
    return tasks.train(
        "classify", data, model=model, epochs=epochs, batch_size=batch_size, points=points,
        out=out, device=device, seed=seed, resume=resume, normals=normals,
        input_transform=input_transform, feature_transform=feature_transform,
        learning_rate=learning_rate, workers=workers, on_error=on_error,
        shapes_per_class=shapes_per_class, progress=progress,
    )


def evaluate(
    run: str | os.PathLike[str],
    data: str | os.PathLike[str] | None = None,
    *,
    device: str | None = None,
    on_error: str = "skip",
) -> dict[str, Any]:
    """Score the classifier of ``run`` on the test split of ``data`` (default: its own data)."""
    return tasks.evaluate("classify", run, data, device=device, on_error=on_error)


def predict(
    run: str | os.PathLike[str],
    files: Sequence[str | os.PathLike[str]],
    *,
    device: str | None = None,
) -> list[dict[str, Any]]:
    """Classify files: one ``{file, class, probability, probabilities}`` dict per file."""
    return tasks.predict("classify", run, files, device=device)
