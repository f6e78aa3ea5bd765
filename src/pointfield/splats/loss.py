"""The 3DGS photometric loss, ``0.8 L1 + 0.2 (1 - SSIM)``, and three geometry terms, differentiable.

SSIM is :func:`pointfield.metrics.ssim`, the same function that scores held-out views, so the
loss and the reported metric cannot drift apart.

The geometry terms, :func:`opacity_entropy`, :func:`flatness` and :func:`depth_distortion`, are
off unless asked for (``--opacity-entropy``, ``--flatness``, ``--depth-distortion``;
``GEOMETRY_WEIGHTS`` are the weights measured): they trade appearance for geometry. What they
cost on lego and gain on the textured cube, ``make bench-geometry`` measures in one run
(benchmarks/RESULTS.md; docs/geometry.md, "Accuracy against known surfaces").
"""

from __future__ import annotations

import torch

from pointfield.metrics import ssim

SSIM_WEIGHT = 0.2
GEOMETRY_WEIGHTS = {"opacity_entropy": 0.1, "flatness": 1.0, "depth_distortion": 100.0}


def splat_loss(prediction: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """``(1 - 0.2) * mean |prediction - target| + 0.2 * (1 - SSIM)`` for ``(H, W, 3)`` images (H, W >= 11)."""
    l1 = (prediction - target).abs().mean()
    return (1 - SSIM_WEIGHT) * l1 + SSIM_WEIGHT * (1 - ssim(prediction, target))


def opacity_entropy(opacities: torch.Tensor) -> torch.Tensor:
    """Mean binary entropy of ``(N,)`` splat opacities, ``-o log o - (1 - o) log(1 - o)``.

    Zero for opacities of 0 or 1, largest (log 2) at 0.5. As a loss it makes each splat either
    part of a surface or nothing: colour alone lets a solid object be filled with faint splats
    that render its colour from inside it, and geometry from depth then lies inside the surface.
    """
    o = opacities.clamp(1e-6, 1 - 1e-6)
    return -(o * torch.log(o) + (1 - o) * torch.log(1 - o)).mean()


def flatness(scales: torch.Tensor, scene_scale: float) -> torch.Tensor:
    """Mean smallest axis of ``(N, 3)`` splat scales, in units of ``scene_scale``.

    As a loss it flattens splats into discs (as 2DGS and Gaussian surfels do), which lie along
    a surface instead of filling its inside, so that rendered depth is the surface's.
    """
    return scales.min(dim=1).values.mean() / scene_scale


def depth_distortion(depth_sum: torch.Tensor, depth_squared_sum: torch.Tensor, alpha: torch.Tensor,
                     scene_scale: float) -> torch.Tensor:
    """2DGS's depth distortion, ``sum_ij w_i w_j (z_i - z_j)^2`` per pixel, mean over pixels.

    With ``alpha = sum_i w_i`` (``(H, W)``), ``depth_sum = sum_i w_i z_i`` and ``depth_squared_sum
    = sum_i w_i z_i^2`` (the splats' camera z and its square composited), the double sum is
    ``2 (alpha sum w z^2 - (sum w z)^2)``: no pairs needed. Distances in units of
    ``scene_scale``. As a loss it draws each pixel's splats into one thin layer.
    """
    return (2 * (alpha * depth_squared_sum - depth_sum * depth_sum)).clamp_min(0).mean() / scene_scale**2
