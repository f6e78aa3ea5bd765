"""Activations of the hash-grid fields' density: the truncated exponential of Instant-NGP."""

from __future__ import annotations

import torch


class _TruncatedExp(torch.autograd.Function):
    """``exp(x)`` whose gradient uses ``exp(min(x, 15))``: a density that cannot blow up training."""

    @staticmethod
    def forward(ctx, x):
        ctx.save_for_backward(x)
        return torch.exp(x)

    @staticmethod
    def backward(ctx, grad):
        (x,) = ctx.saved_tensors
        return grad * torch.exp(x.clamp(max=15))


def trunc_exp(x: torch.Tensor) -> torch.Tensor:
    """Truncated exponential (Instant-NGP / nerfacto): ``exp(x)`` forward, gradient clamped at x = 15.

    Example::

        >>> trunc_exp(torch.tensor([0.0, 1.0]))
        tensor([1.0000, 2.7183])
    """
    return _TruncatedExp.apply(x)
