"""Training-curve and confusion-matrix pictures."""

from __future__ import annotations

import numpy as np
from PIL import Image

from pointfield.viz.plots import plot_confusion_matrix, plot_training_curves


def test_training_curves_are_a_png(tmp_path):
    records = [{"epoch": e, "step": 10 * e, "train_loss": 1 / e, "test_accuracy": 0.5 + e / 10,
                "lr": 0.001} for e in range(1, 6)]
    path = plot_training_curves(records, tmp_path / "curves.png", title="toy")
    with Image.open(path) as image:
        assert image.format == "PNG" and image.size == (1000, 400)


def test_confusion_matrix_is_a_png_even_for_many_classes(tmp_path):
    names = [f"class {i}" for i in range(40)]
    confusion = np.random.default_rng(0).integers(0, 5, (40, 40))
    confusion[3] = 0  # a class absent from the test set
    with Image.open(plot_confusion_matrix(confusion, names, tmp_path / "cm.png")) as image:
        assert image.format == "PNG"
    small = plot_confusion_matrix(np.array([[3, 1], [0, 4]]), ["a", "b"], tmp_path / "s.png")
    assert small.stat().st_size > 0 and not list(tmp_path.glob(".*tmp*"))
