"""Scores of predictions against ground truth: class labels, and rendered images.

Classification and segmentation scores all derive from one confusion matrix ``C`` of shape
``(K, K)`` whose entry ``C[t, p]`` counts the samples (shapes or points) of true class ``t``
predicted as ``p``. Confusion matrices add: sum them over batches, or over the processes of a
distributed run, and every score below is exact for the whole set.

Rendered views are scored by PSNR and SSIM, one view at a time (:func:`psnr`, :func:`ssim`); a
set of held-out views by the mean of the per-view scores (:func:`mean_psnr`, :func:`mean_ssim`),
the one held-out definition every model in pointfield reports.

Part segmentation (ShapeNetPart) is scored per shape as well, as PointNet, PointNet++ and Pointcept
report it (:func:`shape_part_iou`, :func:`instance_mean_iou`): a shape's IoU is the mean, over the
parts of *its category*, of each part's IoU, a part absent from both prediction and truth counting
1; the instance mIoU is the mean over shapes, the class mIoU the mean over categories of their
shapes' mean. These need each shape's category, which a confusion matrix forgets.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch
from torch.nn import functional as F

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


def shape_part_iou(target: ArrayLike, predicted: ArrayLike, parts: Sequence[int]) -> float:
    """One shape's IoU: the mean over ``parts`` (its category's part labels) of each part's IoU.

    ``target`` and ``predicted`` ``(N,)`` hold the part label of each of the shape's points. A part
    that neither holds a point nor is predicted counts as IoU 1 (PointNet's evaluation, which
    Pointcept keeps): a mug's prediction is not punished for a handle its scan does not show. A
    prediction outside ``parts`` is wrong for every part; Pointcept restricts the scores to the
    category's parts before the argmax (:func:`restricted_argmax`) so that it never happens.
    """
    target, predicted = _to_numpy(target).ravel(), _to_numpy(predicted).ravel()
    if target.shape != predicted.shape:
        raise ValueError(f"target and predicted differ in shape: {target.shape} vs {predicted.shape}")
    if len(parts) == 0:
        raise ValueError("a shape's category needs at least one part")
    ious = []
    for part in parts:
        truth, guess = target == part, predicted == part
        union = np.count_nonzero(truth | guess)
        ious.append(1.0 if union == 0 else np.count_nonzero(truth & guess) / union)
    return float(np.mean(ious))


def restricted_argmax(scores: torch.Tensor, parts: Sequence[int]) -> torch.Tensor:
    """``(N,)`` the best part among ``parts`` (global labels) of each row of ``scores`` ``(N, P)``:
    the prediction once the shape's category is known, as Pointcept scores ShapeNetPart."""
    allowed = torch.as_tensor(list(parts), dtype=torch.long, device=scores.device)
    return allowed[scores[:, allowed].argmax(dim=-1)]


def instance_mean_iou(totals: np.ndarray) -> tuple[float, float, np.ndarray]:
    """``(instance mIoU, class mIoU, (C,) mIoU per category)`` from per-category totals.

    ``totals`` ``(2, C)``: row 0 the sum of :func:`shape_part_iou` over the shapes of each
    category, row 1 their number (sums add over batches and processes, as confusion matrices
    do). Instance mIoU: the mean over all shapes; class mIoU: the mean over the categories with
    shapes of their own mean; a category without shapes is NaN and left out.
    """
    sums, counts = np.asarray(totals, np.float64)
    if counts.sum() == 0:
        return float("nan"), float("nan"), np.full(len(counts), np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        per_category = np.where(counts > 0, sums / counts, np.nan)
    present = counts > 0
    return float(sums.sum() / counts.sum()), float(per_category[present].mean()), per_category


def _to_numpy(values: ArrayLike) -> np.ndarray:
    if isinstance(values, torch.Tensor):
        return values.detach().cpu().numpy()
    return np.asarray(values)


# -- images ------------------------------------------------------------------------------------------
#
# Rendered views against their ground truth: ``(H, W)`` or ``(H, W, C)`` arrays or tensors with
# values in ``[0, data_range]`` (1 for the float images pointfield renders). LPIPS is not provided:
# it needs pretrained network weights (AlexNet / VGG plus the LPIPS linear layers) that cannot be
# obtained offline, and a metric with made-up weights would only mislead.

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_K1, SSIM_K2 = 0.01, 0.03


def psnr(image: ArrayLike, truth: ArrayLike, data_range: float = 1.0) -> float:
    """Peak signal-to-noise ratio of one view in dB: ``10 log10(data_range^2 / MSE)``, inf if equal.

    ``image`` and ``truth``: ``(H, W)`` or ``(H, W, C)``, numpy or torch; computed in float64.

    Example::

        >>> psnr(np.full((4, 4, 3), 0.1), np.zeros((4, 4, 3)))
        20.0
    """
    image, truth = _image_pair(image, truth)
    image, truth = image.detach().to("cpu", torch.float64), truth.detach().to("cpu", torch.float64)
    return psnr_from_mse(float(torch.mean((image - truth) ** 2)), data_range)


def psnr_from_mse(mse: float, data_range: float = 1.0) -> float:
    """PSNR of a mean squared error: ``10 log10(data_range^2 / mse)`` (inf for ``mse <= 0``)."""
    return math.inf if mse <= 0 else 10 * math.log10(data_range**2 / mse)


def mean_psnr(images: Sequence[ArrayLike], truths: Sequence[ArrayLike], data_range: float = 1.0) -> float:
    """The held-out PSNR of a set of views: the mean over the views of each view's :func:`psnr`.

    ``mean_v 10 log10(L^2 / MSE_v)``, as NeRF papers and nerfstudio report it -- not the PSNR of
    the mean MSE, ``10 log10(L^2 / mean_v MSE_v)``, which a single bad view pulls down more (it
    is never higher). Every model's held-out score in pointfield is this one. ``images`` and
    ``truths``: equally long sequences of ``(H, W)`` or ``(H, W, C)`` images (or ``(V, H, W[, C])``
    arrays), view by view.

    Example: one view at MSE 0.01 (20 dB), one at 0.0001 (40 dB)::

        >>> mean_psnr([np.full((2, 2), 0.1), np.full((2, 2), 0.01)], [np.zeros((2, 2))] * 2)
        30.0
        >>> round(psnr_from_mse((0.01 + 0.0001) / 2), 2)  # the PSNR of the mean MSE: not this
        22.97
    """
    scores = [psnr(image, truth, data_range) for image, truth in _views(images, truths)]
    return float(np.mean(scores))


def ssim(image: ArrayLike, truth: ArrayLike, data_range: float = 1.0) -> torch.Tensor:
    """Structural similarity (Wang et al. 2004), 11 x 11 Gaussian window of sigma 1.5: a 0-d tensor.

    Local statistics are Gaussian-weighted means ``mu``, variances ``s^2`` and covariance
    ``s_xy`` (population, not sample, estimates); per pixel

        SSIM = (2 mu_x mu_y + C1)(2 s_xy + C2) / ((mu_x^2 + mu_y^2 + C1)(s_x^2 + s_y^2 + C2))

    with ``C1 = (0.01 L)^2``, ``C2 = (0.03 L)^2``, ``L = data_range``; the result is the mean
    over the pixels whose window lies inside the image and over the channels. This matches
    ``skimage.metrics.structural_similarity(a, b, gaussian_weights=True, sigma=1.5,
    use_sample_covariance=False, data_range=1, channel_axis=-1)``.

    ``image`` and ``truth``: ``(H, W)`` or ``(H, W, C)`` with H, W >= 11, numpy or torch. Tensors
    keep their graph, device and dtype, so the result is differentiable (the splat loss,
    :mod:`pointfield.splats.loss`, trains on it); numpy arrays become float64 tensors, and a pair
    of mixed dtypes is returned in the wider one. The local statistics are computed in float64
    whatever the inputs' dtype (float32 on MPS): see the comment in the code for why. For a
    score, ``float(ssim(a, b))``.

    Example::

        >>> image = np.random.default_rng(0).random((16, 16, 3))
        >>> float(ssim(image, image))
        1.0
    """
    x, y = _image_pair(image, truth)
    if x.ndim == 2:
        x, y = x[..., None], y[..., None]
    height, width = x.shape[:2]
    if height < SSIM_WINDOW or width < SSIM_WINDOW:
        raise ValueError(f"SSIM needs images of at least {SSIM_WINDOW} x {SSIM_WINDOW}, got {width} x {height}")
    # (C, 1, H, W): each channel filtered on its own. A "valid" convolution gives exactly the
    # pixels whose window is inside the image, which are the ones scikit-image averages.
    # The local statistics in float64 (float32 on MPS, which has none): the variances E[x^2] -
    # E[x]^2 cancel where a window is smooth, and on CUDA float32 convolutions run in TF32 (a
    # 10-bit mantissa) by default, which made the splat loss's SSIM gradient noise (emulated:
    # off by 0.6 to 47 times its norm on lego views at 100 to 800 px) -- the likely reason
    # splats did not learn at lego's full size on a GPU (docs/splats.md). cuDNN never uses TF32
    # for float64. The result keeps the inputs' dtype.
    dtype = x.dtype
    work = torch.float32 if x.device.type == "mps" else torch.float64
    x = x.permute(2, 0, 1)[:, None].to(work)
    y = y.permute(2, 0, 1)[:, None].to(work)
    window = _gaussian_window(x.dtype, x.device)

    def local_mean(channels: torch.Tensor) -> torch.Tensor:
        return F.conv2d(F.conv2d(channels, window[None, None, :, None]), window[None, None, None, :])

    mu_x, mu_y = local_mean(x), local_mean(y)
    var_x = local_mean(x * x) - mu_x**2
    var_y = local_mean(y * y) - mu_y**2
    cov_xy = local_mean(x * y) - mu_x * mu_y
    c1, c2 = (SSIM_K1 * data_range) ** 2, (SSIM_K2 * data_range) ** 2
    numerator = (2 * mu_x * mu_y + c1) * (2 * cov_xy + c2)
    denominator = (mu_x**2 + mu_y**2 + c1) * (var_x + var_y + c2)
    return (numerator / denominator).mean().to(dtype)


def mean_ssim(images: Sequence[ArrayLike], truths: Sequence[ArrayLike], data_range: float = 1.0) -> float:
    """The held-out SSIM of a set of views: the mean over the views of each view's :func:`ssim`."""
    scores = [float(ssim(image, truth, data_range)) for image, truth in _views(images, truths)]
    return float(np.mean(scores))


def _gaussian_window(dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """The normalised 1-D Gaussian of width 11, sigma 1.5 (scipy's gaussian_filter with truncate 3.5)."""
    offsets = torch.arange(SSIM_WINDOW, dtype=dtype, device=device) - SSIM_WINDOW // 2
    window = torch.exp(-0.5 * (offsets / SSIM_SIGMA) ** 2)
    return window / window.sum()


def _image_pair(image: ArrayLike, truth: ArrayLike) -> tuple[torch.Tensor, torch.Tensor]:
    """Both as floating tensors of one dtype, on the device of whichever was a tensor."""
    x, y = _as_float_tensor(image), _as_float_tensor(truth)
    if x.shape != y.shape:
        raise ValueError(f"images differ in shape: {tuple(x.shape)} and {tuple(y.shape)}")
    if x.ndim not in (2, 3):
        raise ValueError(f"expected an (H, W) or (H, W, C) image, got shape {tuple(x.shape)}")
    dtype = torch.promote_types(x.dtype, y.dtype)
    device = x.device if isinstance(image, torch.Tensor) else y.device
    return x.to(device, dtype), y.to(device, dtype)


def _as_float_tensor(image: ArrayLike) -> torch.Tensor:
    if isinstance(image, torch.Tensor):
        return image if image.is_floating_point() else image.to(torch.float64)
    return torch.from_numpy(np.asarray(image, dtype=np.float64))


def _views(images: Sequence[ArrayLike], truths: Sequence[ArrayLike]) -> list[tuple[ArrayLike, ArrayLike]]:
    images, truths = list(images), list(truths)
    if len(images) != len(truths):
        raise ValueError(f"{len(images)} images but {len(truths)} ground-truth views")
    if not images:
        raise ValueError("no views to score")
    return list(zip(images, truths))
