"""The 3DGS photometric loss, ``0.8 L1 + 0.2 (1 - SSIM)``, differentiable.

SSIM is :func:`pointfield.metrics.ssim`, the same function that scores held-out views, so the
loss and the reported metric cannot drift apart.
"""

from __future__ import annotations

import torch

from pointfield.metrics import ssim

SSIM_WEIGHT = 0.2


def splat_loss(prediction: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """``(1 - 0.2) * mean |prediction - target| + 0.2 * (1 - SSIM)`` for ``(H, W, 3)`` images (H, W >= 11)."""
    l1 = (prediction - target).abs().mean()
    return (1 - SSIM_WEIGHT) * l1 + SSIM_WEIGHT * (1 - ssim(prediction, target))
