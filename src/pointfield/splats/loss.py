"""The 3DGS photometric loss, ``0.8 L1 + 0.2 (1 - SSIM)``, differentiable.

:func:`pointfield.image_metrics.ssim` reports SSIM as a number (in float64, detached); training
needs its gradient, so the same definition -- 11 x 11 Gaussian window, sigma 1.5, population
statistics, mean over the pixels whose window lies inside the image -- is written here on
tensors that keep their graph.
"""

from __future__ import annotations

import torch
from torch.nn import functional as F

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_K1, SSIM_K2 = 0.01, 0.03
SSIM_WEIGHT = 0.2


def ssim(prediction: torch.Tensor, target: torch.Tensor, data_range: float = 1.0) -> torch.Tensor:
    """Differentiable SSIM of two ``(H, W, C)`` images (H, W >= 11): a scalar tensor.

    Per pixel ``(2 mu_x mu_y + C1)(2 s_xy + C2) / ((mu_x^2 + mu_y^2 + C1)(s_x^2 + s_y^2 + C2))``,
    ``C1 = (0.01 L)^2``, ``C2 = (0.03 L)^2``; equal to :func:`pointfield.image_metrics.ssim`.
    """
    x = prediction.permute(2, 0, 1)[:, None]
    y = target.permute(2, 0, 1)[:, None]
    offsets = torch.arange(SSIM_WINDOW, dtype=prediction.dtype, device=prediction.device) - SSIM_WINDOW // 2
    window = torch.exp(-0.5 * (offsets / SSIM_SIGMA) ** 2)
    window = window / window.sum()

    def local_mean(image: torch.Tensor) -> torch.Tensor:
        return F.conv2d(F.conv2d(image, window[None, None, :, None]), window[None, None, None, :])

    mu_x, mu_y = local_mean(x), local_mean(y)
    var_x = local_mean(x * x) - mu_x**2
    var_y = local_mean(y * y) - mu_y**2
    cov_xy = local_mean(x * y) - mu_x * mu_y
    c1, c2 = (SSIM_K1 * data_range) ** 2, (SSIM_K2 * data_range) ** 2
    numerator = (2 * mu_x * mu_y + c1) * (2 * cov_xy + c2)
    denominator = (mu_x**2 + mu_y**2 + c1) * (var_x + var_y + c2)
    return (numerator / denominator).mean()


def splat_loss(prediction: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """``(1 - 0.2) * mean |prediction - target| + 0.2 * (1 - SSIM)`` for ``(H, W, 3)`` images."""
    l1 = (prediction - target).abs().mean()
    return (1 - SSIM_WEIGHT) * l1 + SSIM_WEIGHT * (1 - ssim(prediction, target))
