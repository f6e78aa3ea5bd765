"""NeRF's samplers: stratified samples, and importance samples from a coarse pass's weights.

Conventions: a batch of R rays, each sampled between ``near`` and ``far`` (distances along unit
directions). These building blocks return distances ``t`` ``(R, K)``, sorted along each ray;
:meth:`RaySamples.from_points(t, far) <pointfield.fields.rays.RaySamples.from_points>` turns
them into the samples a renderer takes, sample ``t_i`` standing for the interval
``[t_i, t_{i+1})`` of the ray and the last one for ``[t_{K-1}, far)``.

- :func:`stratified_samples`: K equal bins, one sample in each (uniformly at random within its
  bin while training, so that over many steps the field is queried everywhere; at the bin
  centres when rendering, so renders are repeatable).
- :func:`importance_samples`: draws from a piecewise-constant PDF over bins by inverting its
  CDF (NeRF's hierarchical sampling, section 5.2 of the paper).
- :func:`hierarchical_samples`: the fine pass of NeRF -- importance samples from the coarse
  pass's weights, merged with the coarse samples.
"""

from __future__ import annotations

import torch


def stratified_samples(
    near: torch.Tensor | float,
    far: torch.Tensor | float,
    count: int,
    *,
    rays: int | None = None,
    jitter: bool = True,
    generator: torch.Generator | None = None,
    device: torch.device | None = None,
) -> torch.Tensor:
    """``count`` samples per ray, one in each of ``count`` equal bins of ``[near, far]``.

    ``t_i = near + (i + u_i) (far - near) / count`` with ``u_i ~ U[0, 1)`` when ``jitter``, else
    ``u_i = 1/2``. ``near`` and ``far`` are floats or ``(R,)`` tensors; ``rays`` gives R when both
    are floats. Returns ``(R, count)``, increasing along each ray.

    Example::

        >>> stratified_samples(2.0, 6.0, 4, rays=1, jitter=False)
        tensor([[2.5000, 3.5000, 4.5000, 5.5000]])
    """
    near, far = as_near_far(near, far, rays, device)
    offsets = torch.arange(count, device=near.device, dtype=near.dtype)
    if jitter:
        offsets = offsets + torch.rand(
            (near.shape[0], count), generator=generator, device=near.device, dtype=near.dtype
        )
    else:
        offsets = (offsets + 0.5).expand(near.shape[0], count)
    return near[:, None] + (far - near)[:, None] * offsets / count


def importance_samples(
    bin_edges: torch.Tensor,
    weights: torch.Tensor,
    count: int,
    *,
    jitter: bool = True,
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """Draw ``count`` samples per ray from the piecewise-constant PDF ``weights`` over bins.

    ``bin_edges``: ``(R, B + 1)`` increasing; ``weights``: ``(R, B)`` non-negative (need not sum
    to 1). The PDF is ``p(t) = w_b / (sum w) / (e_{b+1} - e_b)`` on bin b. With CDF values
    ``F_b = sum_{j<b} w_j / sum w`` at the edges, a uniform ``u`` maps to
    ``t = e_b + (u - F_b) / (F_{b+1} - F_b) (e_{b+1} - e_b)`` in the bin b where
    ``F_b <= u < F_{b+1}`` (inverse transform sampling). ``u`` is uniform at random when
    ``jitter``, else the evenly spaced ``(k + 1/2) / count``. A ray whose weights are all zero
    samples uniformly. Returns ``(R, count)``, sorted along each ray; no gradient flows to the
    weights (they choose where to look, they are not a quantity being optimised here).
    """
    weights = weights.detach() + 1e-5  # keeps every bin reachable and all-zero rays uniform
    bin_edges = bin_edges.detach()
    pdf = weights / weights.sum(dim=-1, keepdim=True)
    cdf = torch.cat([torch.zeros_like(pdf[:, :1]), torch.cumsum(pdf, dim=-1)], dim=-1)  # (R, B + 1)
    cdf[:, -1] = 1.0
    rays = weights.shape[0]
    if jitter:
        u = torch.rand((rays, count), generator=generator, device=weights.device, dtype=weights.dtype)
    else:
        u = ((torch.arange(count, device=weights.device, dtype=weights.dtype) + 0.5) / count).expand(rays, count)
    u = u.contiguous()
    # Bin b with F_b <= u < F_{b+1}: searchsorted finds the first edge above u.
    upper = torch.searchsorted(cdf, u, right=True).clamp(1, cdf.shape[-1] - 1)
    lower = upper - 1
    cdf_lower, cdf_upper = cdf.gather(-1, lower), cdf.gather(-1, upper)
    edge_lower, edge_upper = bin_edges.gather(-1, lower), bin_edges.gather(-1, upper)
    fraction = ((u - cdf_lower) / (cdf_upper - cdf_lower).clamp_min(1e-12)).clamp(0, 1)
    samples = edge_lower + fraction * (edge_upper - edge_lower)
    return torch.sort(samples, dim=-1).values


def hierarchical_samples(
    t_coarse: torch.Tensor,
    weights_coarse: torch.Tensor,
    near: torch.Tensor | float,
    far: torch.Tensor | float,
    count: int,
    *,
    jitter: bool = True,
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """NeRF's fine samples: ``count`` importance samples from the coarse weights, plus the coarse ones.

    Coarse sample ``t_i`` (``(R, K)``) with weight ``w_i`` (``(R, K)``) owns the bin from the
    midpoint with its left neighbour to the midpoint with its right one (``near`` and ``far`` at
    the ends), so every coarse weight shapes the PDF. Returns ``(R, K + count)`` sorted.
    """
    near, far = as_near_far(near, far, t_coarse.shape[0], t_coarse.device)
    t_coarse = t_coarse.detach()
    midpoints = 0.5 * (t_coarse[:, 1:] + t_coarse[:, :-1])
    edges = torch.cat([near[:, None].to(t_coarse.dtype), midpoints, far[:, None].to(t_coarse.dtype)], dim=-1)
    fine = importance_samples(edges, weights_coarse, count, jitter=jitter, generator=generator)
    return torch.sort(torch.cat([t_coarse, fine], dim=-1), dim=-1).values


def as_near_far(near, far, rays: int | None, device) -> tuple[torch.Tensor, torch.Tensor]:
    """``near`` and ``far`` (floats or tensors) as ``(R,)`` tensors of one floating dtype; ``rays``: R for two floats."""
    near = torch.as_tensor(near, device=device)
    far = torch.as_tensor(far, device=near.device)
    if not near.is_floating_point():
        near = near.float()
    far = far.to(near.dtype)
    if near.ndim == 0 and far.ndim == 0:
        if rays is None:
            raise ValueError("give rays= when near and far are both scalars")
        return near.expand(rays), far.expand(rays)
    near, far = torch.broadcast_tensors(near.reshape(-1), far.reshape(-1))
    return near, far
