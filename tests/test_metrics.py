"""Scores from confusion matrices, and PSNR / SSIM of rendered views (SSIM checked against scikit-image)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from tf32 import tf32_convolutions

from pointfield.metrics import (
    accuracy,
    class_accuracies,
    class_iou,
    confusion_matrix,
    instance_mean_iou,
    mean_class_accuracy,
    mean_iou,
    mean_psnr,
    mean_ssim,
    psnr,
    psnr_from_mse,
    restricted_argmax,
    shape_part_iou,
    ssim,
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


# -- images ------------------------------------------------------------------------------------------


def _pair(shape, noise=0.1, seed=0):
    rng = np.random.default_rng(seed)
    clean = rng.random(shape)
    return clean, np.clip(clean + noise * rng.standard_normal(shape), 0, 1)


def test_psnr_is_ten_log10_of_inverse_mse():
    a = np.zeros((4, 4, 3))
    b = np.full((4, 4, 3), 0.1)
    assert psnr(b, a) == pytest.approx(20.0)
    assert psnr(a, a) == math.inf
    assert psnr_from_mse(0.01) == pytest.approx(20.0)


def test_mean_psnr_is_the_mean_of_per_view_psnr():
    truths = [np.zeros((8, 8, 3))] * 3
    images = [np.full((8, 8, 3), level) for level in (0.1, 0.01, 0.05)]
    per_view = [psnr(image, truth) for image, truth in zip(images, truths)]
    assert mean_psnr(images, truths) == pytest.approx(np.mean(per_view))


def test_mean_psnr_differs_from_the_psnr_of_the_mean_mse():
    truths = [np.zeros((8, 8))] * 2
    images = [np.full((8, 8), 0.1), np.full((8, 8), 0.01)]  # MSE 1e-2 (20 dB) and 1e-4 (40 dB)
    assert mean_psnr(images, truths) == pytest.approx(30.0)
    assert psnr_from_mse((1e-2 + 1e-4) / 2) == pytest.approx(22.97, abs=0.01)


def test_mean_psnr_refuses_unmatched_or_no_views():
    with pytest.raises(ValueError, match="2 images but 1"):
        mean_psnr([np.zeros((4, 4))] * 2, [np.zeros((4, 4))])
    with pytest.raises(ValueError, match="no views"):
        mean_psnr([], [])


def test_ssim_of_an_image_with_itself_is_one():
    a, _ = _pair((16, 20, 3))
    assert float(ssim(a, a)) == pytest.approx(1.0)
    assert float(ssim(torch.from_numpy(a).float(), torch.from_numpy(a).float())) == pytest.approx(1.0)


@pytest.mark.parametrize("shape", [(32, 40, 3), (11, 13), (50, 30, 1)])
def test_ssim_agrees_with_scikit_image(shape):
    metrics = pytest.importorskip("skimage.metrics", reason="scikit-image not installed")
    a, b = _pair(shape)
    channel_axis = -1 if len(shape) == 3 else None
    expected = metrics.structural_similarity(
        a, b, gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1, channel_axis=channel_axis
    )
    assert abs(float(ssim(a, b)) - expected) < 1e-6
    assert abs(float(ssim(torch.from_numpy(a).float(), b)) - expected) < 1e-6  # a float32 render, float64 truth


def test_ssim_of_float32_tensors_stays_float32_and_close_to_float64():
    a, b = _pair((24, 24, 3))
    single = ssim(torch.from_numpy(a).float(), torch.from_numpy(b).float())
    assert single.dtype == torch.float32
    assert float(single) == pytest.approx(float(ssim(a, b)), abs=1e-5)


def test_ssim_gradient_flows_to_the_image():
    a, b = _pair((20, 17, 3))
    image = torch.from_numpy(a).requires_grad_()
    similarity = ssim(image, torch.from_numpy(b))
    similarity.backward()
    assert torch.isfinite(image.grad).all() and image.grad.abs().sum() > 0
    # Moving the image along the gradient raises SSIM: the gradient is the metric's own.
    with torch.no_grad():
        assert float(ssim(image + 1e-3 * image.grad.sign(), b)) > float(similarity)


def test_mean_ssim_is_the_mean_of_per_view_ssim():
    pairs = [_pair((16, 16, 3), seed=seed) for seed in range(3)]
    images, truths = [p[0] for p in pairs], [p[1] for p in pairs]
    assert mean_ssim(images, truths) == pytest.approx(np.mean([float(ssim(a, b)) for a, b in pairs]))


def test_ssim_refuses_images_smaller_than_its_window():
    with pytest.raises(ValueError, match="at least 11"):
        ssim(np.zeros((8, 8)), np.zeros((8, 8)))


def test_images_of_different_shapes_are_an_error():
    with pytest.raises(ValueError, match="differ in shape"):
        psnr(np.zeros((4, 4, 3)), np.zeros((4, 5, 3)))


def _smooth_object_on_white(size: int) -> torch.Tensor:
    """An ``(size, size, 3)`` float32 picture: a disc shaded smoothly, on a white background."""
    v, u = torch.meshgrid(torch.linspace(-1, 1, size), torch.linspace(-1, 1, size), indexing="ij")
    inside = ((u * u + v * v) < 0.5).float()[..., None]
    shade = torch.stack([0.5 + 0.3 * u, 0.4 + 0.2 * v, 0.3 + 0.1 * u * v], dim=-1)
    return inside * shade + (1 - inside)


def test_ssim_gradient_does_not_depend_on_tf32_convolutions():
    # On CUDA, float32 convolutions run in TF32 unless told not to; SSIM's variances, E[x^2] -
    # E[x]^2 over an 11 x 11 window, cancel badly then: on a lego view at 800 x 800 the splat
    # loss's SSIM gradient came out 47 times too large and random (cosine 0.02 with the true
    # one) -- the likely reason splats did not learn at lego's full size on a GPU (docs/splats.md).
    truth = _smooth_object_on_white(800)
    image = (0.7 * truth + 0.15).requires_grad_()
    ssim(image, truth).backward()
    exact = image.grad.clone()
    image.grad = None
    with tf32_convolutions():
        ssim(image, truth).backward()
    assert float((image.grad - exact).norm() / exact.norm()) < 1e-3


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_ssim_gradient_on_cuda_matches_the_cpu_at_800_px():
    truth = _smooth_object_on_white(800)
    gradients = []
    for device in ("cpu", "cuda"):
        image = (0.7 * truth + 0.15).to(device).requires_grad_()
        ssim(image, truth.to(device)).backward()
        gradients.append(image.grad.cpu())
    assert float((gradients[1] - gradients[0]).norm() / gradients[0].norm()) < 1e-3


# -- ShapeNetPart's per-shape scores ------------------------------------------------------------


def test_a_shapes_iou_is_the_mean_over_its_categorys_parts_an_absent_part_counting_one():
    # part 0: 1 shared of 2 -> 1/2; part 1: 2 of 3 -> 2/3; part 2 in neither truth nor prediction -> 1
    assert shape_part_iou([0, 0, 1, 1], [0, 1, 1, 1], (0, 1, 2)) == pytest.approx((1 / 2 + 2 / 3 + 1) / 3)
    # a part of another category predicted is wrong for every part of this one: 36 -> 1/2, 37 -> 1
    assert shape_part_iou([36, 36, 37], [36, 5, 37], (36, 37)) == pytest.approx(0.75)
    assert shape_part_iou([4, 4], [5, 5], (4, 5)) == 0.0


def test_the_restricted_argmax_picks_the_best_of_the_categorys_parts():
    scores = torch.tensor([[0.1, 0.9, 0.3, 0.2], [0.0, 0.9, 0.1, 0.8]])
    assert restricted_argmax(scores, (2, 3)).tolist() == [2, 3]  # part 1 wins overall, but is not theirs


def test_instance_miou_averages_shapes_and_class_miou_averages_categories():
    # category 0: shapes of IoU 0.5 and 1.0; category 1: one of 0.25; category 2: no test shape
    instance, by_class, per_category = instance_mean_iou(np.array([[1.5, 0.25, 0.0], [2, 1, 0]]))
    assert instance == pytest.approx(1.75 / 3)
    assert by_class == pytest.approx((0.75 + 0.25) / 2)
    assert per_category[:2].tolist() == [0.75, 0.25] and math.isnan(per_category[2])


def test_evaluation_scores_each_shape_on_its_categorys_parts_as_pointcept_does():
    """A model that always ranks part 3 first, then part 0: restricted to its category's parts, a
    shape of category 0 (parts 0, 1) is predicted all part 0, one of category 1 (parts 2, 3) all part 3."""
    from pointfield.clouds.cloud import PointCloud
    from pointfield.clouds.datasets import CloudCollate
    from pointfield.clouds.datasets.base import InMemoryClouds
    from pointfield.clouds.tasks import confusion_on, shape_scores

    class Fixed(torch.nn.Module):
        def forward(self, points, features, mask):
            return torch.tensor([0.2, 0.1, 0.0, 0.9]).expand(*points.shape[:2], 4)

    shapes = InMemoryClouds()
    for category, labels in ((0, [0, 0, 1, 1]), (1, [2, 2, 2, 3])):
        shapes.clouds.append(PointCloud(np.eye(4, 3, dtype=np.float32), {"label": np.array(labels)}))
        shapes.labels.append(category)
    config = {"task": "segment", "parts": ["a0", "a1", "b0", "b1"], "batch_size": 2}
    confusion, totals = confusion_on(Fixed(), shapes, "segment", config, CloudCollate([], point_labels=True),
                                     torch.device("cpu"), category_parts=[(0, 1), (2, 3)])
    assert confusion[:, 3].sum() == 8  # the plain argmax: part 3 everywhere
    # category 0: part 0 -> 2/4, part 1 -> 0: 0.25; category 1: part 2 -> 0, part 3 -> 1/4: 0.125
    scores = shape_scores(totals, ["a", "b"])
    assert scores["per_category"] == pytest.approx({"a": 0.25, "b": 0.125})
    assert scores["instance_miou"] == pytest.approx(0.1875) and scores["class_miou"] == pytest.approx(0.1875)
