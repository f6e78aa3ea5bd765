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
    given that it stops (``sum w_i s_i / sum w_i`` with ``s_i`` the expected stop inside
    interval i, :func:`expected_stop`; 0 where nothing is hit); ``opacity`` ``(R,)`` ``sum w_i``;
    ``weights`` shaped like the samples' ``t_starts`` (``(R, K)`` or ``(S,)``); ``samples`` the
    :class:`~pointfield.fields.rays.RaySamples` composited; ``median_depth`` ``(R,)`` the distance
    at which the accumulated opacity reaches 0.5 (0 where it never does): the depth of a
    surface, where the expected depth of a semi-transparent or doubled one falls between the
    layers.
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
        # Shifted rather than inclusive minus sigma_i delta_i, which would cancel catastrophically
        # after a huge (opaque) interval.
        return torch.exp(-_exclusive_cumsum(optical_depth))
    if optical_depth.shape[0] == 0:
        return optical_depth
    # One global cumulative sum (float64) minus its value where each ray's run starts. Clamping
    # changes no transmittance (exp(-OPAQUE_OPTICAL_DEPTH) is already 0), but keeps one opaque
    # sample (up to inf) from swamping the global sum: the later samples of every later ray
    # would lose their own small terms to it, or get inf - inf = NaN.
    clamped = optical_depth.double().clamp(max=OPAQUE_OPTICAL_DEPTH)
    return torch.exp(-exclusive_sum_along_rays(clamped, ray_indices)).to(optical_depth.dtype)


def exclusive_sum_along_rays(values: torch.Tensor, ray_indices: torch.Tensor) -> torch.Tensor:
    """``(S,)``: for each packed sample, the sum of ``values`` over the earlier samples of its ray.

    One global cumulative sum minus its value where each ray's run starts (``ray_indices``
    non-decreasing); pass float64 where the batch is long.
    """
    inclusive = torch.cumsum(values, dim=0)
    exclusive = inclusive - values
    first = torch.ones_like(ray_indices, dtype=torch.bool)
    first[1:] = ray_indices[1:] != ray_indices[:-1]
    run = torch.cumsum(first.long(), dim=0) - 1  # which run (ray) each sample is in
    return exclusive - exclusive[first][run]


def _exclusive_cumsum(values: torch.Tensor) -> torch.Tensor:
    """``sum_{j<i} values_j`` along the last axis (a shifted cumsum: no cancellation)."""
    return torch.cat([torch.zeros_like(values[..., :1]), torch.cumsum(values[..., :-1], dim=-1)], dim=-1)


def distortion_loss(weights: torch.Tensor, samples: RaySamples, length: float) -> torch.Tensor:
    """Mip-NeRF 360's distortion loss, the mean over rays: small when each ray's weight is one thin layer.

    ``sum_{i,j} w_i w_j |m_i - m_j| + 1/3 sum_i w_i^2 delta_i`` with ``m`` the intervals'
    midpoints and ``delta`` their lengths, both divided by ``length`` (e.g. the scene box's
    diagonal) so that the weight of the loss does not depend on the scene's units. The double
    sum is ``2 sum_i w_i (m_i W_i - M_i)``, with ``W_i`` and ``M_i`` the sums of ``w`` and ``w m``
    over the ray's earlier samples (intervals sorted along each ray, as samplers give them).
    ``weights`` ``(R, K)`` padded or ``(S,)`` packed, like ``samples``.
    """
    middle = 0.5 * (samples.t_starts + samples.t_ends) / length
    deltas = samples.deltas / length
    if samples.ray_indices is None:
        before, weighted_before = _exclusive_cumsum(weights), _exclusive_cumsum(weights * middle)
        per_ray = (2 * weights * (middle * before - weighted_before) + weights ** 2 * deltas / 3).sum(dim=-1)
        return per_ray.mean() if per_ray.numel() else weights.sum()
    rays = max(int(samples.num_rays), 1)
    # Float64 sums: one global running sum over a long batch would lose each ray's small terms.
    wide, middle = weights.double(), middle.double()
    before = exclusive_sum_along_rays(wide, samples.ray_indices)
    weighted_before = exclusive_sum_along_rays(wide * middle, samples.ray_indices)
    loss = (2 * wide * (middle * before - weighted_before) + wide ** 2 * deltas.double() / 3).sum() / rays
    return loss.to(weights.dtype)


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
    ``(3,)`` or ``(R, 3)`` (None: black, i.e. nothing added). Depth is ``sum_i w_i s_i / sum_i
    w_i``, with ``s_i`` where in interval i the ray stops on average (:func:`expected_stop`:
    the interval's start where it is opaque, its middle where it is faint). A packed ray
    without samples gets the background, opacity 0 and depth 0.

    Example (an opaque wall at t = 3 in front of a red one at t = 4)::

        >>> samples = RaySamples.from_points(torch.tensor([[2.0, 3.0, 4.0]]), 5.0)
        >>> sigma = torch.tensor([[0.0, 1e6, 1e6]])
        >>> rgb = torch.tensor([[[0.0, 0, 0], [0, 1, 0], [1, 0, 0]]])
        >>> out = composite(sigma, rgb, samples)
        >>> out.color, out.depth, out.opacity
        (tensor([[0., 1., 0.]]), tensor([3.]), tensor([1.]))
    """
    weights, transmittance, _ = render_weights_from_density(sigmas, samples.deltas, samples.ray_indices)
    t = expected_stop(sigmas, samples)
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
    return RenderedRays(color, depth, opacity, weights, samples,
                        median_depth(weights, transmittance, sigmas, samples))


MEDIAN_OPACITY = 0.5


def expected_stop(sigmas: torch.Tensor, samples: RaySamples) -> torch.Tensor:
    """Where in its interval a ray stops, on average, given that it stops there: ``t_start + delta g(sigma delta)``.

    The density is constant on each interval (the quadrature's own model), so the stopping
    distance inside it is exponentially distributed, truncated to ``delta``:
    ``g(x) = 1/x - 1/(e^x - 1)``, from 1/2 (transparent: the midpoint) down to ``1/x`` (opaque:
    the interval's start). Measuring depth at the samples' ``t`` instead puts an opaque surface
    up to half an interval behind where the rendering sees it. Shaped like ``sigmas``.
    """
    x = (sigmas * samples.deltas).clamp(min=0)
    small = x < 1e-3
    wide = x.clamp(min=1e-3)
    # Past x = 50, 1 / (e^x - 1) < 2e-22; capping it there keeps e^x (and its gradient) finite.
    g = torch.where(small, 0.5 - x / 12, 1 / wide - 1 / torch.expm1(wide.clamp(max=50.0)))
    return samples.t_starts + samples.deltas * g


def median_depth(weights: torch.Tensor, transmittance: torch.Tensor, sigmas: torch.Tensor,
                 samples: RaySamples) -> torch.Tensor:
    """``(R,)``: where along each ray the accumulated opacity reaches 0.5; 0 where it never does (no gradient).

    Inside the interval i where it crosses, the transmittance falls as ``T_i exp(-sigma_i (t -
    t_start))``, so it reaches 0.5 at ``t_start + ln(2 T_i) / sigma_i``.
    """
    weights, transmittance, sigmas = weights.detach(), transmittance.detach(), sigmas.detach()
    inside = (torch.log((2 * transmittance).clamp(min=1.0)) / sigmas.clamp(min=1e-10)).clamp(min=0)
    crossing_t = samples.t_starts.detach() + torch.minimum(inside, samples.deltas.detach())
    if samples.ray_indices is None:
        accumulated = torch.cumsum(weights, dim=-1)
        if not crossing_t.shape[-1]:
            return torch.zeros(crossing_t.shape[:-1], dtype=crossing_t.dtype, device=crossing_t.device)
        first = (accumulated < MEDIAN_OPACITY).sum(dim=-1, keepdim=True).clamp(max=crossing_t.shape[-1] - 1)
        median = crossing_t.gather(-1, first)[..., 0]
        return torch.where(accumulated[..., -1] >= MEDIAN_OPACITY, median, torch.zeros_like(median))
    index, rays = samples.ray_indices, samples.num_rays
    median = crossing_t.new_zeros(rays)
    if len(index) == 0:
        return median
    before = exclusive_sum_along_rays(weights.double(), index)
    crossing = (before + weights.double() >= MEDIAN_OPACITY) & (before < MEDIAN_OPACITY)
    return median.index_put((index[crossing],), crossing_t[crossing])


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
