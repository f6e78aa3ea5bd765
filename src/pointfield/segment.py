"""Per-point segmentation from Python: the functions behind ``pointfield segment``.

=======================================  =============================================
``pointfield segment train [DATA] ...``  :func:`train`
``pointfield segment eval RUN [DATA]``   :func:`evaluate` (``eval`` is Python's own)
``pointfield segment predict RUN FILE``  :func:`predict`
=======================================  =============================================

Training data is a folder of clouds whose per-point integer field ``label_field`` holds the
part (or semantic class) of each point, or None for the synthetic shapes and their 17 parts.
Predictions are written as clouds with an int32 ``label`` field.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

from pointfield.clouds import tasks
from pointfield.clouds.datasets import PART_LABEL_FIELD


def train(
    data: str | os.PathLike[str] | None = None,
    *,
    model: str = "pointnet",
    epochs: int | None = None,
    batch_size: int | None = None,
    points: int = tasks.DEFAULT_POINTS,
    out: str | os.PathLike[str] = "runs/segment",
    device: str | None = None,
    seed: int = 0,
    resume: bool = False,
    normals: bool = False,
    input_transform: bool = True,
    feature_transform: bool = True,
    learning_rate: float = tasks.LEARNING_RATE,
    workers: int = 0,
    on_error: str = "skip",
    label_field: str = PART_LABEL_FIELD,
    shapes_per_class: int | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Train a segmenter; returns the final test metrics (``accuracy`` over points,
    ``mean_class_accuracy``, ``miou``, ``per_class`` IoU, ...). See
    :func:`pointfield.classify.train` for the shared arguments."""
    return tasks.train(
        "segment", data, model=model, epochs=epochs, batch_size=batch_size, points=points,
        out=out, device=device, seed=seed, resume=resume, normals=normals,
        input_transform=input_transform, feature_transform=feature_transform,
        learning_rate=learning_rate, workers=workers, on_error=on_error,
        label_field=label_field, shapes_per_class=shapes_per_class, progress=progress,
    )


def evaluate(
    run: str | os.PathLike[str],
    data: str | os.PathLike[str] | None = None,
    *,
    device: str | None = None,
    on_error: str = "skip",
) -> dict[str, Any]:
    """Score the segmenter of ``run`` on the test split of ``data`` (default: its own data)."""
    return tasks.evaluate("segment", run, data, device=device, on_error=on_error)


def predict(
    run: str | os.PathLike[str],
    files: Sequence[str | os.PathLike[str]],
    *,
    device: str | None = None,
    out: str | os.PathLike[str] | None = None,
) -> list[dict[str, Any]]:
    """Label every point of each file; writes ``out/<stem>.ply`` (default ``RUN/predictions``)
    with an int32 ``label`` field and returns ``{file, output, points, parts}`` per file."""
    return tasks.predict("segment", run, files, device=device, out=out)
