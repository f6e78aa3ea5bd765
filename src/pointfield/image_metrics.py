"""Image quality metrics for rendered views: PSNR and SSIM.

Images are ``(H, W)`` or ``(H, W, C)`` arrays or tensors with values in ``[0, data_range]``
(1 for the float images pointfield renders). Both functions compute in float64 and return a
Python float.

LPIPS is not provided: it needs pretrained network weights (AlexNet / VGG plus the LPIPS
linear layers) that cannot be obtained offline, and a metric with made-up weights would only
mislead.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch.nn import functional as F

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_K1, SSIM_K2 = 0.01, 0.03


def psnr(prediction, target, data_range: float = 1.0) -> float:
    """Peak signal-to-noise ratio in dB: ``10 log10(data_range^2 / MSE)`` (inf for equal images)."""
    prediction, target = _as_float64_pair(prediction, target)
    mse = float(torch.mean((prediction - target) ** 2))
    return math.inf if mse == 0 else 10 * math.log10(data_range**2 / mse)


def psnr_from_mse(mse: float, data_range: float = 1.0) -> float:
    """PSNR of a mean squared error: ``10 log10(data_range^2 / mse)``."""
    return math.inf if mse <= 0 else 10 * math.log10(data_range**2 / mse)


def ssim(prediction, target, data_range: float = 1.0) -> float:
    """Structural similarity (Wang et al. 2004) with an 11 x 11 Gaussian window, sigma 1.5.

    Local statistics are Gaussian-weighted means ``mu``, variances ``s^2`` and covariance
    ``s_xy`` (population, not sample, estimates); per pixel

        SSIM = (2 mu_x mu_y + C1)(2 s_xy + C2) / ((mu_x^2 + mu_y^2 + C1)(s_x^2 + s_y^2 + C2))

    with ``C1 = (0.01 L)^2``, ``C2 = (0.03 L)^2``, ``L = data_range``; the result is the mean
    over the pixels whose window lies inside the image and over the channels. This matches
    ``skimage.metrics.structural_similarity(a, b, gaussian_weights=True, sigma=1.5,
    use_sample_covariance=False, data_range=1, channel_axis=-1)``. Images must be at least
    11 x 11.
    """
    prediction, target = _as_float64_pair(prediction, target)
    if prediction.ndim == 2:
        prediction, target = prediction[..., None], target[..., None]
    height, width = prediction.shape[:2]
    if height < SSIM_WINDOW or width < SSIM_WINDOW:
        raise ValueError(f"SSIM needs images of at least {SSIM_WINDOW} x {SSIM_WINDOW}, got {width} x {height}")
    # (C, 1, H, W): each channel filtered on its own. A "valid" convolution gives exactly the
    # pixels whose window is inside the image, which are the ones scikit-image averages.
    x = prediction.permute(2, 0, 1)[:, None]
    y = target.permute(2, 0, 1)[:, None]
    kernel = _gaussian_window()

    def local_mean(image: torch.Tensor) -> torch.Tensor:
        return F.conv2d(F.conv2d(image, kernel[None, None, :, None]), kernel[None, None, None, :])

    mu_x, mu_y = local_mean(x), local_mean(y)
    var_x = local_mean(x * x) - mu_x**2
    var_y = local_mean(y * y) - mu_y**2
    cov_xy = local_mean(x * y) - mu_x * mu_y
    c1, c2 = (SSIM_K1 * data_range) ** 2, (SSIM_K2 * data_range) ** 2
    numerator = (2 * mu_x * mu_y + c1) * (2 * cov_xy + c2)
    denominator = (mu_x**2 + mu_y**2 + c1) * (var_x + var_y + c2)
    return float((numerator / denominator).mean())


def _gaussian_window() -> torch.Tensor:
    """The normalised 1-D Gaussian of width 11, sigma 1.5 (scipy's gaussian_filter with truncate 3.5)."""
    offsets = torch.arange(SSIM_WINDOW, dtype=torch.float64) - SSIM_WINDOW // 2
    window = torch.exp(-0.5 * (offsets / SSIM_SIGMA) ** 2)
    return window / window.sum()


def _as_float64_pair(prediction, target) -> tuple[torch.Tensor, torch.Tensor]:
    prediction = _as_tensor(prediction)
    target = _as_tensor(target)
    if prediction.shape != target.shape:
        raise ValueError(f"images differ in shape: {tuple(prediction.shape)} and {tuple(target.shape)}")
    if prediction.ndim not in (2, 3):
        raise ValueError(f"expected an (H, W) or (H, W, C) image, got shape {tuple(prediction.shape)}")
    return prediction, target


def _as_tensor(image) -> torch.Tensor:
    if isinstance(image, torch.Tensor):
        return image.detach().to("cpu", torch.float64)
    return torch.from_numpy(np.asarray(image, dtype=np.float64))
