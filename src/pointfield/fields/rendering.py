"""Volumetric rendering: composite a field's densities and colours along rays into pixels.

The emission-absorption model of NeRF (Mildenhall et al. 2020, eq. 3). Along a ray with samples
at ``t_i`` on intervals of length ``delta_i`` (:class:`~pointfield.fields.rays.RaySamples`), a
field gives density ``sigma_i >= 0`` and colour ``c_i``; then

    alpha_i = 1 - exp(-sigma_i delta_i)              the interval's opacity
    T_i     = exp(-sum_{j<i} sigma_j delta_j)        transmittance: light reaching t_i
    w_i     = T_i alpha_i                            the sample's weight
    C       = sum_i w_i c_i + (1 - sum_i w_i) c_bg   colour over a background c_bg

``T_i`` is the exponential of an *exclusive* cumulative sum of ``sigma delta`` -- not the cumprod
of ``(1 - alpha_j + eps)`` that many implementations use -- so it is exact, and its gradient
stays finite and correct where an interval is fully opaque (alpha = 1): the same choice as
nerfacc's ``render_weight_from_density``.

Every function takes padded samples (``(R, K)``, samples on the last axis) or packed ones
(``(S,)`` with ``ray_indices`` ``(S,)``); packed transmittance takes each ray's exclusive sum from
one global cumulative sum, in float64 so that long batches do not lose precision.

Fields are callables ``field(positions (..., 3), directions (..., 3)) -> (sigma (...), rgb
(..., 3))``, so :func:`render_rays` works with any of them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch

from pointfield.fields.rays import RayBundle, RaySamples

Field = Callable[[torch.Tensor, torch.Tensor], tuple[torch.Tensor, torch.Tensor]]
"""``(positions (..., 3), unit directions (..., 3)) -> (sigma (...), rgb (..., 3))``."""

OPAQUE_OPTICAL_DEPTH = 800.0
"""Packed transmittance clamps each sample's optical depth to this: ``exp(-800)`` is 0 even in float64."""


@dataclass
class RenderedRays:
    """What compositing gives for R rays.

    ``color`` ``(R, 3)``; ``depth`` ``(R,)`` expected distance along the ray at which it stops,
    given that it stops (``sum w_i t_i / sum w_i``; 0 where nothing is hit); ``opacity`` ``(R,)``
    ``sum w_i``; ``weights`` shaped like the samples' ``t_starts`` (``(R, K)`` or ``(S,)``);
    ``samples`` the :class:`~pointfield.fields.rays.RaySamples` composited; ``median_depth``
    ``(R,)`` the ``t`` of the first sample at which the accumulated opacity reaches 0.5 (0 where
    it never does): the depth of a surface, where the expected depth of a semi-transparent or
    doubled one falls between the layers.
    """

    color: torch.Tensor
    depth: torch.Tensor
    opacity: torch.Tensor
    weights: torch.Tensor
    samples: RaySamples
    median_depth: torch.Tensor | None = None


def transmittance_from_optical_depth(
    optical_depth: torch.Tensor, ray_indices: torch.Tensor | None = None
) -> torch.Tensor:
    """``T_i = exp(-sum_{j<i} sigma_j delta_j)``, the sum over the earlier samples of i's ray.

    ``optical_depth`` ``sigma delta``: ``(R, K)`` padded (any leading shape, samples on the last
    axis), or ``(S,)`` packed with ``ray_indices`` ``(S,)`` non-decreasing. Same shape back.

    Example (packed: two samples of ray 0, one of ray 1)::

        >>> transmittance_from_optical_depth(torch.tensor([1.0, 2.0, 3.0]), torch.tensor([0, 0, 1]))
        tensor([1.0000, 0.3679, 1.0000])
    """
    if ray_indices is None:
        # sum_{j<i}: shift the inclusive sum right rather than subtracting sigma_i delta_i from it,
        # which would cancel catastrophically after a huge (opaque) interval.
        inclusive = torch.cumsum(optical_depth, dim=-1)
        exclusive = torch.cat([torch.zeros_like(inclusive[..., :1]), inclusive[..., :-1]], dim=-1)
        return torch.exp(-exclusive)
    if optical_depth.shape[0] == 0:
        return optical_depth
    # One global cumulative sum (float64) minus its value where each ray's run starts. Clamping
    # changes no transmittance (exp(-OPAQUE_OPTICAL_DEPTH) is already 0), but keeps one opaque
    # sample (up to inf) from swamping the global sum: the later samples of every later ray
    # would lose their own small terms to it, or get inf - inf = NaN.
    clamped = optical_depth.double().clamp(max=OPAQUE_OPTICAL_DEPTH)
    inclusive = torch.cumsum(clamped, dim=0)
    exclusive = inclusive - clamped
    first = torch.ones_like(ray_indices, dtype=torch.bool)
    first[1:] = ray_indices[1:] != ray_indices[:-1]
    run = torch.cumsum(first.long(), dim=0) - 1  # which run (ray) each sample is in
    base = exclusive[first][run]
    return torch.exp(-(exclusive - base)).to(optical_depth.dtype)


def render_weights_from_density(
    sigmas: torch.Tensor, deltas: torch.Tensor, ray_indices: torch.Tensor | None = None
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Weights ``w_i = T_i (1 - exp(-sigma_i delta_i))`` with ``T_i = exp(-sum_{j<i} sigma_j delta_j)``.

    ``sigmas``, ``deltas``: ``(R, K)`` padded (any leading shape, samples on the last axis), or
    ``(S,)`` packed with ``ray_indices`` ``(S,)``. Returns ``(weights, transmittance, alphas)``,
    each shaped like ``sigmas``.

    Example::

        >>> w, T, a = render_weights_from_density(torch.tensor([[0.0, 1.0, 1e9]]), torch.ones(1, 3))
        >>> w
        tensor([[0.0000, 0.6321, 0.3679]])
    """
    optical_depth = sigmas * deltas  # sigma_i delta_i, the interval's optical thickness
    transmittance = transmittance_from_optical_depth(optical_depth, ray_indices)
    alphas = -torch.expm1(-optical_depth)  # 1 - exp(-x), accurate for small x
    return transmittance * alphas, transmittance, alphas


def composite(
    sigmas: torch.Tensor,
    colors: torch.Tensor,
    samples: RaySamples,
    background: torch.Tensor | None = None,
) -> RenderedRays:
    """Composite densities and colours at ``samples`` into ``samples.num_rays`` pixels.

    ``sigmas`` ``(R, K)`` and ``colors`` ``(R, K, 3)`` for padded samples, ``(S,)`` and ``(S, 3)``
    for packed ones. ``C = sum_i w_i c_i + (1 - sum_i w_i) background``; ``background`` is
    ``(3,)`` or ``(R, 3)`` (None: black, i.e. nothing added). Depth is ``sum_i w_i t_i / sum_i
    w_i`` at the samples' ``t``. A packed ray without samples gets the background, opacity 0 and
    depth 0.

    Example (an opaque wall at t = 3 in front of a red one at t = 4)::

        >>> samples = RaySamples.from_points(torch.tensor([[2.0, 3.0, 4.0]]), 5.0)
        >>> sigma = torch.tensor([[0.0, 1e6, 1e6]])
        >>> rgb = torch.tensor([[[0.0, 0, 0], [0, 1, 0], [1, 0, 0]]])
        >>> out = composite(sigma, rgb, samples)
        >>> out.color, out.depth, out.opacity
        (tensor([[0., 1., 0.]]), tensor([3.]), tensor([1.]))
    """
    weights, _, _ = render_weights_from_density(sigmas, samples.deltas, samples.ray_indices)
    t = samples.t
    if samples.ray_indices is None:
        opacity = weights.sum(dim=-1)
        color = (weights[..., None] * colors).sum(dim=-2)
        depth = (weights * t).sum(dim=-1) / opacity.clamp_min(1e-10)
    else:
        index, rays = samples.ray_indices, samples.num_rays
        opacity = sigmas.new_zeros(rays).index_add(0, index, weights)
        color = sigmas.new_zeros(rays, 3).index_add(0, index, weights[:, None] * colors)
        depth = sigmas.new_zeros(rays).index_add(0, index, weights * t) / opacity.clamp_min(1e-10)
    if background is not None:
        color = color + (1 - opacity)[..., None] * background
    return RenderedRays(color, depth, opacity, weights, samples, median_depth(weights, t, samples))


MEDIAN_OPACITY = 0.5


def median_depth(weights: torch.Tensor, t: torch.Tensor, samples: RaySamples) -> torch.Tensor:
    """``(R,)``: ``t`` of each ray's first sample where ``sum_{j<=i} w_j >= 0.5``; 0 if none (no gradient)."""
    weights, t = weights.detach(), t.detach()
    if samples.ray_indices is None:
        accumulated = torch.cumsum(weights, dim=-1)
        first = (accumulated < MEDIAN_OPACITY).sum(dim=-1, keepdim=True).clamp(max=max(t.shape[-1] - 1, 0))
        reached = accumulated[..., -1] >= MEDIAN_OPACITY if t.shape[-1] else torch.zeros_like(t[..., 0], dtype=torch.bool)
        median = t.gather(-1, first)[..., 0] if t.shape[-1] else torch.zeros(t.shape[:-1], dtype=t.dtype, device=t.device)
        return torch.where(reached, median, torch.zeros_like(median))
    index, rays = samples.ray_indices, samples.num_rays
    median = t.new_zeros(rays)
    if len(index) == 0:
        return median
    # Each ray's running sum, from one global cumulative sum minus its value where the ray starts.
    inclusive = torch.cumsum(weights.double(), dim=0)
    start = torch.ones_like(index, dtype=torch.bool)
    start[1:] = index[1:] != index[:-1]
    run = torch.cumsum(start.long(), dim=0) - 1
    accumulated = inclusive - (inclusive - weights.double())[start][run]
    before = accumulated - weights.double()
    crossing = (accumulated >= MEDIAN_OPACITY) & (before < MEDIAN_OPACITY)
    return median.index_put((index[crossing],), t[crossing])


def render_rays(
    field: Field,
    rays: RayBundle,
    samples: RaySamples,
    background: torch.Tensor | None = None,
) -> RenderedRays:
    """Evaluate ``field`` at ``samples`` of ``rays`` (every sample with its ray's direction), composite.

    Positions are ``o + t d``: ``(R, K, 3)`` for padded samples, ``(S, 3)`` for packed ones.
    """
    sigmas, colors = field(samples.positions(rays), samples.view_directions(rays))
    return composite(sigmas, colors, samples, background)
