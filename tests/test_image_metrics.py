"""PSNR and SSIM (SSIM checked against scikit-image when it is installed)."""

import math

import numpy as np
import pytest
import torch

from pointfield.image_metrics import psnr, ssim


def _pair(shape, noise=0.1, seed=0):
    rng = np.random.default_rng(seed)
    clean = rng.random(shape)
    return clean, np.clip(clean + noise * rng.standard_normal(shape), 0, 1)


def test_psnr_is_ten_log10_of_inverse_mse():
    a = np.zeros((4, 4, 3))
    b = np.full((4, 4, 3), 0.1)
    assert psnr(b, a) == pytest.approx(20.0)
    assert psnr(a, a) == math.inf


def test_ssim_of_an_image_with_itself_is_one():
    a, _ = _pair((16, 20, 3))
    assert ssim(a, a) == pytest.approx(1.0)
    assert ssim(torch.from_numpy(a).float(), torch.from_numpy(a).float()) == pytest.approx(1.0)


@pytest.mark.parametrize("shape", [(32, 40, 3), (11, 13), (50, 30, 1)])
def test_ssim_agrees_with_scikit_image(shape):
    metrics = pytest.importorskip("skimage.metrics", reason="scikit-image not installed")
    a, b = _pair(shape)
    channel_axis = -1 if len(shape) == 3 else None
    expected = metrics.structural_similarity(
        a, b, gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1, channel_axis=channel_axis
    )
    assert abs(ssim(a, b) - expected) < 1e-4


def test_ssim_refuses_images_smaller_than_its_window():
    with pytest.raises(ValueError, match="at least 11"):
        ssim(np.zeros((8, 8)), np.zeros((8, 8)))
