"""Scores from confusion matrices."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from pointfield.metrics import (
    accuracy,
    class_accuracies,
    class_iou,
    confusion_matrix,
    mean_class_accuracy,
    mean_iou,
)


def test_confusion_counts_true_rows_and_predicted_columns():
    confusion = confusion_matrix([0, 0, 1, 2, 2, 2], [0, 1, 1, 2, 2, 0], 3)
    assert confusion.tolist() == [[1, 1, 0], [0, 1, 0], [1, 0, 2]]


def test_confusion_ignores_padding_and_accepts_tensors():
    target = torch.tensor([[0, 1, -1], [1, 1, -1]])
    predicted = torch.tensor([[0, 0, 1], [1, 1, 0]])
    assert confusion_matrix(target, predicted, 2).tolist() == [[1, 0], [1, 2]]


def test_out_of_range_classes_are_an_error():
    with pytest.raises(ValueError, match="0..1"):
        confusion_matrix([0, 2], [0, 1], 2)


def test_accuracy_and_mean_class_accuracy_weigh_differently():
    confusion = np.array([[90, 0], [5, 5]])
    assert accuracy(confusion) == pytest.approx(0.95)
    assert mean_class_accuracy(confusion) == pytest.approx((1.0 + 0.5) / 2)
    assert class_accuracies(confusion).tolist() == [1.0, 0.5]


def test_iou_is_true_positives_over_the_union():
    confusion = np.array([[3, 1, 0], [2, 4, 0], [0, 0, 0]])
    iou = class_iou(confusion)
    assert iou[0] == pytest.approx(3 / (3 + 1 + 2)) and iou[1] == pytest.approx(4 / (4 + 2 + 1))
    assert math.isnan(iou[2])  # a class nobody has or predicts does not count
    assert mean_iou(confusion) == pytest.approx((iou[0] + iou[1]) / 2)


def test_empty_confusions_give_nan_not_errors():
    empty = np.zeros((2, 2), np.int64)
    assert math.isnan(accuracy(empty)) and math.isnan(mean_class_accuracy(empty))
    assert math.isnan(mean_iou(empty))
