"""A few splats trained for a few steps under a densification strategy, for the strategy tests
(tests/splats/test_training.py: the default one; tests/splats/test_mcmc.py: MCMC)."""

from __future__ import annotations

import torch

from pointfield.splats.gaussians import PARAMETER_NAMES, Gaussians
from pointfield.splats.loss import splat_loss
from pointfield.splats.rasterizer import rasterization

SIZE = 48


def model_and_optimizer(count: int = 100, seed: int = 0) -> tuple[Gaussians, torch.optim.Adam]:
    """``count`` random splats in front of the camera of :func:`training_steps`, and their Adam (one group each)."""
    gaussians = Gaussians.random_in_box(count, [-1, -1, 3], [1, 1, 5], seed=seed)
    optimizer = torch.optim.Adam([{"params": [getattr(gaussians, n)], "lr": 1e-2} for n in PARAMETER_NAMES])
    return gaussians, optimizer


def training_steps(gaussians, optimizer, strategy, steps: int, counts: list[int] | None = None) -> None:
    """``steps`` steps towards a random 48 x 48 picture from one camera at the origin, as training
    runs a strategy: its ``after_backward`` with the previous step's meta before each render, its
    ``regularization`` in the loss. ``counts`` gets the splat count after each refinement call."""
    K = torch.tensor([[[40.0, 0, SIZE / 2], [0, 40.0, SIZE / 2], [0, 0, 1]]])
    target = torch.rand(SIZE, SIZE, 3, generator=torch.Generator().manual_seed(1))
    meta = None
    for step in range(steps):
        if meta is not None:
            strategy.after_backward(gaussians, optimizer, meta, step, SIZE, SIZE)
            if counts is not None:
                counts.append(len(gaussians))
        colors, _, _, meta = rasterization(
            gaussians.means, gaussians.quats, gaussians.scales, gaussians.opacities,
            gaussians.sh_coefficients, torch.eye(4)[None], K, SIZE, SIZE, sh_degree=0,
        )
        meta["means2d"].retain_grad()  # the default strategy's statistic
        optimizer.zero_grad()
        (splat_loss(colors[0], target) + strategy.regularization(gaussians)).backward()
        optimizer.step()
