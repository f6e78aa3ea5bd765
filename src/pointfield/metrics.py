"""Scores of predictions against ground truth.

Classification and segmentation scores all derive from one confusion matrix ``C`` of shape
``(K, K)`` whose entry ``C[t, p]`` counts the samples (shapes or points) of true class ``t``
predicted as ``p``. Confusion matrices add: sum them over batches, or over the processes of a
distributed run, and every score below is exact for the whole set.
"""

from __future__ import annotations

import numpy as np
import torch

ArrayLike = np.ndarray | torch.Tensor


def confusion_matrix(
    target: ArrayLike, predicted: ArrayLike, num_classes: int, ignore_index: int = -1
) -> np.ndarray:
    """``(K, K)`` int64 counts ``C[t, p]`` of samples with true class t predicted as p.

    ``target`` and ``predicted`` hold class indices of any matching shape (``(B,)`` per shape or
    ``(B, N)`` per point). Entries whose target is ``ignore_index`` (the padding of variable-size
    batches) are not counted.

    Example::

        >>> confusion_matrix([0, 1, 1], [0, 1, 0], 2)
        array([[1, 0],
               [1, 1]])
    """
    t = _to_numpy(target).reshape(-1).astype(np.int64)
    p = _to_numpy(predicted).reshape(-1).astype(np.int64)
    if t.shape != p.shape:
        raise ValueError(f"target has {t.size} entries but predicted has {p.size}")
    keep = t != ignore_index
    t, p = t[keep], p[keep]
    if t.size and (t.min() < 0 or t.max() >= num_classes or p.min() < 0 or p.max() >= num_classes):
        raise ValueError(f"class indices must lie in 0..{num_classes - 1}")
    return np.bincount(t * num_classes + p, minlength=num_classes**2).reshape(
        num_classes, num_classes
    )


def accuracy(confusion: np.ndarray) -> float:
    """Overall accuracy ``trace(C) / sum(C)``: the fraction of samples predicted right (NaN if none)."""
    total = confusion.sum()
    return float(np.trace(confusion) / total) if total else float("nan")


def class_accuracies(confusion: np.ndarray) -> np.ndarray:
    """``(K,)`` recall of each class, ``C[k, k] / sum_p C[k, p]``; NaN for classes with no samples."""
    support = confusion.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(support > 0, np.diag(confusion) / support, np.nan)


def mean_class_accuracy(confusion: np.ndarray) -> float:
    """Mean over the classes present in the ground truth of each class's accuracy.

    Unlike :func:`accuracy` it weighs a rare class as much as a common one (ModelNet40 reports
    both: "overall" and "mean class" accuracy).
    """
    per_class = class_accuracies(confusion)
    present = ~np.isnan(per_class)
    return float(per_class[present].mean()) if present.any() else float("nan")


def class_iou(confusion: np.ndarray) -> np.ndarray:
    """``(K,)`` intersection over union of each class, ``C[k,k] / (row_k + col_k - C[k,k])``.

    That is TP / (TP + FP + FN). NaN for a class that is neither in the ground truth nor predicted.
    """
    true_positive = np.diag(confusion).astype(np.float64)
    union = confusion.sum(axis=0) + confusion.sum(axis=1) - true_positive
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(union > 0, true_positive / union, np.nan)


def mean_iou(confusion: np.ndarray) -> float:
    """mIoU: the mean of :func:`class_iou` over the classes that occur (in truth or prediction)."""
    iou = class_iou(confusion)
    present = ~np.isnan(iou)
    return float(iou[present].mean()) if present.any() else float("nan")


def _to_numpy(values: ArrayLike) -> np.ndarray:
    if isinstance(values, torch.Tensor):
        return values.detach().cpu().numpy()
    return np.asarray(values)
