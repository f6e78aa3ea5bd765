"""Plots of training: loss and score curves, and confusion matrices, as PNG files.

Drawn with matplotlib's Agg backend on figures that belong to no global pyplot state, so they
work without a display and from several threads; written atomically.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pointfield.atomic import atomic_path

# Largest number of classes whose names and counts are written in the confusion matrix cells.
ANNOTATE_MAX_CLASSES = 20


def plot_training_curves(
    records: Sequence[dict[str, Any]],
    path: str | os.PathLike[str],
    title: str | None = None,
    x: str = "epoch",
) -> Path:
    """Plot per-epoch records (``metrics.jsonl`` rows) to a PNG: losses left, scores right.

    Every numeric key whose name contains ``loss`` goes to the left panel (log scale when
    positive); the other numeric keys except the bookkeeping ones (``epoch``, ``step``,
    ``seconds``, ``lr``) go to the right panel.
    """
    from matplotlib.figure import Figure

    steps = [record.get(x) for record in records]
    keys = [k for k in _numeric_keys(records) if k not in ("epoch", "step", "seconds", "lr")]
    losses = [k for k in keys if "loss" in k]
    scores = [k for k in keys if "loss" not in k]
    figure = Figure(figsize=(10, 4), dpi=100, layout="constrained")
    left, right = figure.subplots(1, 2)
    for axes, names, label in ((left, losses, "loss"), (right, scores, "score")):
        for name in names:
            values = [record.get(name, np.nan) for record in records]
            axes.plot(steps, values, marker="o" if len(steps) < 30 else None, label=name)
        axes.set_xlabel(x)
        axes.set_ylabel(label)
        axes.grid(alpha=0.3)
        if names:
            axes.legend(fontsize="small")
        if label == "loss" and names and all(
            record.get(n, 1) > 0 for record in records for n in names
        ):
            axes.set_yscale("log")
    if title:
        figure.suptitle(title)
    return _save(figure, path)


def plot_confusion_matrix(
    confusion: np.ndarray,
    class_names: Sequence[str],
    path: str | os.PathLike[str],
    title: str | None = None,
) -> Path:
    """Draw a confusion matrix (rows: true class, columns: predicted) as a PNG.

    Cells are coloured by the row-normalised fraction (each true class sums to 1), so rare
    classes are as readable as common ones; with at most 20 classes each cell also shows its
    count.
    """
    from matplotlib.figure import Figure

    confusion = np.asarray(confusion)
    count = len(class_names)
    totals = confusion.sum(axis=1, keepdims=True)
    fractions = np.divide(confusion, totals, out=np.zeros(confusion.shape), where=totals > 0)
    size = min(4 + 0.35 * count, 24)
    figure = Figure(figsize=(size + 1.5, size), dpi=100, layout="constrained")
    axes = figure.subplots()
    image = axes.imshow(fractions, cmap="Blues", vmin=0, vmax=1)
    figure.colorbar(image, ax=axes, fraction=0.046, label="fraction of the true class")
    axes.set_xlabel("predicted")
    axes.set_ylabel("true")
    if count <= 60:
        axes.set_xticks(range(count), class_names, rotation=90, fontsize="small")
        axes.set_yticks(range(count), class_names, fontsize="small")
    if count <= ANNOTATE_MAX_CLASSES:
        for row in range(count):
            for column in range(count):
                if confusion[row, column]:
                    axes.text(
                        column, row, str(confusion[row, column]), ha="center", va="center",
                        fontsize="small",
                        color="white" if fractions[row, column] > 0.5 else "black",
                    )
    if title:
        axes.set_title(title)
    return _save(figure, path)


def _numeric_keys(records: Sequence[dict[str, Any]]) -> list[str]:
    keys: dict[str, None] = {}
    for record in records:
        for key, value in record.items():
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                keys[key] = None
    return list(keys)


def _save(figure, path: str | os.PathLike[str]) -> Path:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    path = Path(path)
    FigureCanvasAgg(figure)
    with atomic_path(path) as tmp:
        figure.savefig(tmp, format="png")
    return path
