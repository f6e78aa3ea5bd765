"""Robust kernels: how much a correspondence counts given its residual (iteratively reweighted least squares).

Each kernel turns residuals ``r`` into weights ``w(r) = rho'(r) / r`` (open3d's
``pipelines.registration.HuberLoss`` / ``TukeyLoss``); the estimation then solves the weighted
least-squares problem. A kernel's scale ``k`` is in the residual's unit: with residuals of noise
sigma, ``k`` of a few sigma keeps the inliers at full weight.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class L2Loss:
    """Plain least squares: every correspondence weighs 1."""

    def weight(self, residual: np.ndarray) -> np.ndarray:
        return np.ones_like(residual, dtype=np.float64)


@dataclass(frozen=True)
class HuberLoss:
    """Huber: quadratic inside ``k``, linear outside; ``w = 1`` for ``|r| <= k`` else ``k / |r|``."""

    k: float

    def weight(self, residual: np.ndarray) -> np.ndarray:
        r = np.abs(residual)
        return np.where(r <= self.k, 1.0, self.k / np.maximum(r, 1e-300))


@dataclass(frozen=True)
class TukeyLoss:
    """Tukey's biweight: ``w = (1 - (r / k)^2)^2`` for ``|r| <= k``, 0 outside (outliers drop out)."""

    k: float

    def weight(self, residual: np.ndarray) -> np.ndarray:
        ratio = np.abs(residual) / self.k
        return np.where(ratio <= 1.0, (1.0 - ratio**2) ** 2, 0.0)


def kernel_named(name: str | None, scale: float) -> L2Loss | HuberLoss | TukeyLoss:
    """``"huber"`` / ``"tukey"`` with ``k = scale``, or :class:`L2Loss` for ``None`` / ``"l2"``."""
    if name in (None, "l2", "none"):
        return L2Loss()
    if name == "huber":
        return HuberLoss(scale)
    if name == "tukey":
        return TukeyLoss(scale)
    raise ValueError(f"unknown robust kernel {name!r}: expected huber, tukey or l2")
