"""Volumetric rendering: composite a field's densities and colours along rays into pixels.

The emission-absorption model of NeRF (Mildenhall et al. 2020, eq. 3). Along a ray with samples
``t_i`` and interval lengths ``delta_i`` (see :mod:`pointfield.fields.sampling`), a field gives
density ``sigma_i >= 0`` and colour ``c_i``; then

    alpha_i = 1 - exp(-sigma_i delta_i)              the interval's opacity
    T_i     = exp(-sum_{j<i} sigma_j delta_j)        transmittance: light reaching t_i
    w_i     = T_i alpha_i                            the sample's weight
    C       = sum_i w_i c_i + (1 - sum_i w_i) c_bg   colour over a background c_bg

``T_i`` is the exponential of an *exclusive* cumulative sum of ``sigma delta`` -- not the cumprod
of ``(1 - alpha_j + eps)`` that many implementations use -- so it is exact, and its gradient
stays finite and correct where an interval is fully opaque (alpha = 1): the same choice as
nerfacc's ``render_weight_from_density``.

Fields are callables ``field(positions (..., 3), directions (..., 3)) -> (sigma (...), rgb
(..., 3))``, so :func:`render_rays` works with any of them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch

from pointfield.fields.sampling import sample_deltas

Field = Callable[[torch.Tensor, torch.Tensor], tuple[torch.Tensor, torch.Tensor]]
"""``(positions (..., 3), unit directions (..., 3)) -> (sigma (...), rgb (..., 3))``."""


@dataclass
class RenderedRays:
    """What compositing gives for R rays with K samples each.

    ``color`` ``(R, 3)``; ``depth`` ``(R,)`` expected distance along the ray at which it stops,
    given that it stops (``sum w_i t_i / sum w_i``; 0 where nothing is hit); ``opacity`` ``(R,)``
    ``sum w_i``; ``weights`` ``(R, K)``; ``t`` ``(R, K)`` the samples.
    """

    color: torch.Tensor
    depth: torch.Tensor
    opacity: torch.Tensor
    weights: torch.Tensor
    t: torch.Tensor


def render_weights_from_density(
    sigmas: torch.Tensor, deltas: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Weights ``w_i = T_i (1 - exp(-sigma_i delta_i))`` with ``T_i = exp(-sum_{j<i} sigma_j delta_j)``.

    ``sigmas``, ``deltas``: ``(R, K)`` (any leading shape, samples on the last axis). Returns
    ``(weights, transmittance, alphas)``, each shaped like ``sigmas``.

    Example::

        >>> w, T, a = render_weights_from_density(torch.tensor([[0.0, 1.0, 1e9]]), torch.ones(1, 3))
        >>> w
        tensor([[0.0000, 0.6321, 0.3679]])
    """
    optical_depth = sigmas * deltas  # sigma_i delta_i, the interval's optical thickness
    # sum_{j<i}: shift the inclusive sum right rather than subtracting sigma_i delta_i from it,
    # which would cancel catastrophically after a huge (opaque) interval.
    inclusive = torch.cumsum(optical_depth, dim=-1)
    exclusive = torch.cat([torch.zeros_like(inclusive[..., :1]), inclusive[..., :-1]], dim=-1)
    transmittance = torch.exp(-exclusive)
    alphas = -torch.expm1(-optical_depth)  # 1 - exp(-x), accurate for small x
    return transmittance * alphas, transmittance, alphas


def composite_along_rays(
    sigmas: torch.Tensor,
    colors: torch.Tensor,
    t: torch.Tensor,
    deltas: torch.Tensor,
    background: torch.Tensor | None = None,
) -> RenderedRays:
    """Composite ``(R, K)`` densities and ``(R, K, 3)`` colours at samples ``t`` into pixels.

    ``C = sum_i w_i c_i + (1 - sum_i w_i) background``; ``background`` is ``(3,)`` or ``(R, 3)``
    (None: black, i.e. nothing added). Depth is ``sum_i w_i t_i / sum_i w_i``.

    Example (an opaque wall at t = 3 in front of a red one at t = 4)::

        >>> t = torch.tensor([[2.0, 3.0, 4.0]])
        >>> sigma = torch.tensor([[0.0, 1e6, 1e6]])
        >>> rgb = torch.tensor([[[0.0, 0, 0], [0, 1, 0], [1, 0, 0]]])
        >>> out = composite_along_rays(sigma, rgb, t, sample_deltas(t, 5.0))
        >>> out.color, out.depth, out.opacity
        (tensor([[0., 1., 0.]]), tensor([3.]), tensor([1.]))
    """
    weights, _, _ = render_weights_from_density(sigmas, deltas)
    opacity = weights.sum(dim=-1)
    color = (weights[..., None] * colors).sum(dim=-2)
    if background is not None:
        color = color + (1 - opacity)[..., None] * background
    depth = (weights * t).sum(dim=-1) / opacity.clamp_min(1e-10)
    return RenderedRays(color, depth, opacity, weights, t)


def render_rays(
    field: Field,
    origins: torch.Tensor,
    directions: torch.Tensor,
    t: torch.Tensor,
    far: torch.Tensor | float,
    background: torch.Tensor | None = None,
) -> RenderedRays:
    """Evaluate ``field`` at samples ``t`` (``(R, K)``) of rays ``origins``, ``directions`` (``(R, 3)``), composite.

    Positions are ``o + t_i d`` (``(R, K, 3)``); every sample of a ray gets the ray's direction.
    """
    positions = origins[:, None, :] + t[..., None] * directions[:, None, :]
    sample_directions = directions[:, None, :].expand_as(positions)
    sigmas, colors = field(positions, sample_directions)
    return composite_along_rays(sigmas, colors, t, sample_deltas(t, far), background)
