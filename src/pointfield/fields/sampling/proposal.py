"""Unbounded scenes: the proposal-network sampler and its losses (mip-NeRF 360, nerfacto).

A real capture sees the background out to the horizon, which no box holds. Two ideas from
mip-NeRF 360 (Barron et al. 2022) make it tractable: the scene contraction
(:func:`~pointfield.fields.encodings.contraction.contract`), which fits all of space into the
unit cube a hash grid covers, and

- **Proposal sampling** (:class:`ProposalSampler`): small density-only fields
  (:class:`ProposalNetwork`) predict where along each ray the real field will put its weight, so
  that its few samples (48) land on surfaces instead of being spread over kilometres of empty
  space. Each round turns the previous round's samples into a histogram of weights and draws
  the next, fewer, bin edges from it by inverse-CDF sampling.

The proposal networks never see colour: they are trained by :func:`interlevel_loss` alone,
which asks each proposal histogram to *bound from above* the real field's weights (the real
field's weights are a constant there).

Conventions (as in :mod:`pointfield.fields.sampling.stratified`): R rays, distances ``t`` along the ray
directions, and bins given by their ``edges`` ``(R, K + 1)``, increasing; bin i is
``[t_i, t_{i+1})`` with weight ``w_i`` ``(R, K)``. Initial edges are spaced evenly in the
*spacing* ``s`` of :func:`spacing_from_distance` -- linear in ``t`` up to ``linear_until``,
linear in disparity ``1 / t`` beyond (nerfacto's ``UniformLinDisparityPiecewiseSampler``) --
and histograms are resampled in ``s`` too, so that a bin reaching from 100 to 1000 is not
sampled mostly at its far end.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch
from torch import nn

from pointfield.errors import PointfieldError
from pointfield.fields.activations import trunc_exp
from pointfield.fields.encodings.hashgrid import HashEncoding
from pointfield.fields.rays import RayBundle
from pointfield.fields.rendering import render_weights_from_density
from pointfield.fields.sampling.stratified import as_near_far, importance_samples, stratified_samples

INTERLEVEL_EPS = 1e-7
"""Keeps ``max(0, w - bound)^2 / w`` finite where the field's weight ``w`` is 0 (nerfacto's EPS)."""


# -- the proposal network ----------------------------------------------------------------------------


class ProposalNetwork(nn.Module):
    """Nerfacto's density-only proposal field: ``u (..., 3)`` in ``[0, 1]^3`` -> ``sigma (...)``.

    A small :class:`~pointfield.fields.encodings.hashgrid.HashEncoding` (``levels`` L x
    ``features_per_level`` F, ``2^log2_table_size`` entries per level, resolutions
    ``min_resolution`` .. ``max_resolution``) -> ``Linear(L F, hidden)`` -> ReLU ->
    ``Linear(hidden, 1)`` -> truncated exponential. Positions are already contracted
    (:func:`~pointfield.fields.encodings.contraction.contract`); ``backend`` is the hash grid's.
    """

    def __init__(
        self,
        levels: int = 5,
        features_per_level: int = 2,
        log2_table_size: int = 17,
        min_resolution: int = 16,
        max_resolution: int = 128,
        hidden: int = 16,
        backend: str = "auto",
    ):
        super().__init__()
        self.encoding = HashEncoding(
            levels, features_per_level, log2_table_size, min_resolution, max_resolution, backend=backend
        )
        self.mlp = nn.Sequential(nn.Linear(self.encoding.output_dim, hidden), nn.ReLU(), nn.Linear(hidden, 1))

    def forward(self, unit_positions: torch.Tensor) -> torch.Tensor:
        """Density ``sigma >= 0`` at ``unit_positions`` ``(..., 3)``: ``(...)``."""
        return trunc_exp(self.mlp(self.encoding(unit_positions))[..., 0])


# -- where the first samples go ----------------------------------------------------------------------


def spacing_from_distance(t: torch.Tensor, linear_until: float) -> torch.Tensor:
    """Nerfacto's piecewise spacing ``s(t)``: linear in ``t``, then linear in disparity ``1 / t``.

    With ``L = linear_until``: ``s = t / (2 L)`` for ``t < L`` and ``s = 1 - L / (2 t)`` beyond,
    so ``[0, L)`` maps to ``[0, 1/2)`` and ``[L, inf)`` to ``[1/2, 1)``; ``s`` and its slope are
    continuous at ``t = L``. ``t >= 0`` of any shape; same shape back.
    """
    linear = t / (2 * linear_until)
    disparity = 1 - linear_until / (2 * t.clamp_min(linear_until))
    return torch.where(t < linear_until, linear, disparity)


def distance_from_spacing(s: torch.Tensor, linear_until: float) -> torch.Tensor:
    """The inverse of :func:`spacing_from_distance`: ``t = 2 L s`` for ``s < 1/2``, ``L / (2 - 2 s)`` beyond.

    In float32, ``s`` resolves distances out to about ``1e4 L`` to better than 0.1 %.
    """
    linear = 2 * linear_until * s
    disparity = linear_until / (2 - 2 * s.clamp_max(1.0))
    return torch.where(s < 0.5, linear, disparity)


def initial_bin_edges(
    near: torch.Tensor | float,
    far: torch.Tensor | float,
    count: int,
    *,
    jitter: bool = True,
    generator: torch.Generator | None = None,
    linear_until: float = 1.0,
    rays: int | None = None,
    device: torch.device | None = None,
) -> torch.Tensor:
    """``count`` bins per ray from ``near`` to ``far``, evenly spaced in :func:`spacing_from_distance`.

    Edges ``e_k = t(s_near + (k + u_k - 1/2) / count (s_far - s_near))`` for ``k = 1 .. count - 1``
    with ``u_k ~ U[0, 1)`` when ``jitter`` (each edge stays within half a bin of its place, so
    the edges remain increasing), ``u_k = 1/2`` otherwise; ``e_0 = near`` and ``e_count = far``
    exactly. With ``near = 0`` half the bins lie in ``[0, linear_until)``, evenly spaced, and half
    beyond, evenly spaced in disparity: near geometry gets as many samples as the whole
    background. ``near``, ``far``: ``(R,)`` tensors or floats (then give ``rays``), ``0 <= near <
    far < inf``. Returns ``(R, count + 1)``, increasing along each ray.

    Example::

        >>> initial_bin_edges(0.0, 1000.0, 4, rays=1, jitter=False)
        tensor([[0.0000e+00, 4.9975e-01, 9.9950e-01, 1.9970e+00, 1.0000e+03]])
    """
    if count < 1:
        raise PointfieldError(f"need at least one bin per ray, got count={count}")
    if not linear_until > 0:
        raise PointfieldError(f"linear_until must be a positive distance, got {linear_until}")
    near, far = as_near_far(near, far, rays, device)
    s_near, s_far = spacing_from_distance(near, linear_until), spacing_from_distance(far, linear_until)
    # Interior edges at (k + u - 1/2) / count, k = 1 .. count-1: one stratified sample in each
    # of count - 1 equal bins of [1/2, count - 1/2] / count.
    fractions = stratified_samples(
        torch.full_like(near, 0.5 / count), torch.full_like(near, 1 - 0.5 / count), count - 1,
        jitter=jitter, generator=generator,
    )
    interior = distance_from_spacing(s_near[:, None] + fractions * (s_far - s_near)[:, None], linear_until)
    return torch.cat([near[:, None], interior, far[:, None]], dim=-1)


# -- the sampler ---------------------------------------------------------------------------------


def proposal_anneal(step: int, anneal_steps: int = 1000, slope: float = 10.0) -> float:
    """Nerfacto's exponent for the proposal weights at training ``step``: rises from 0 to 1.

    ``a = slope x / ((slope - 1) x + 1)`` with ``x = min(step / anneal_steps, 1)``. Resampling
    from ``w^a`` instead of ``w`` keeps early, still-uninformed proposals from collapsing the
    samples onto a wrong surface: ``w^0`` is uniform.
    """
    x = min(max(step / anneal_steps, 0.0), 1.0)
    return slope * x / ((slope - 1) * x + 1)


ToUnit = Callable[[torch.Tensor], torch.Tensor]
"""World positions ``(..., 3)`` -> the proposal networks' ``[0, 1]^3`` (e.g. a scene contraction)."""


class ProposalSampler(nn.Module):
    """Nerfacto's proposal sampler: rounds of small density fields place the field's samples.

    Round i evaluates proposal network i at the midpoints of its ``proposal_samples[i]`` bins,
    composites their densities into weights ``w`` (``render_weights_from_density``) and draws the
    next round's ``proposal_samples[i + 1] + 1`` edges -- the field's ``final_samples + 1`` after
    the last round -- from the histogram ``w^anneal + histogram_padding`` by inverse-CDF sampling
    in the spacing ``s`` (``importance_samples``). Round 0's bins are :func:`initial_bin_edges`.

    One :class:`ProposalNetwork` per round, with hash-grid resolutions up to
    ``max_resolutions[i]`` (nerfacto's 128 and 256; give one per round). ``linear_until``: the
    distance out to which the initial bins are linear in ``t`` (the contraction's radius is a
    good choice: the default 1.0 suits only scenes scaled to about a unit ball).
    ``histogram_padding``: added to every proposal weight before resampling, so that a few
    samples always explore (nerfacto's 0.01). Nerfacto's defaults are ``(256, 96)`` proposal and
    48 final samples; ``(128, 64)`` is cheaper on a CPU.
    """

    def __init__(
        self,
        proposal_samples: Sequence[int] = (256, 96),
        final_samples: int = 48,
        max_resolutions: Sequence[int] = (128, 256),
        linear_until: float = 1.0,
        histogram_padding: float = 0.01,
        backend: str = "auto",
    ):
        super().__init__()
        self.proposal_samples = tuple(int(count) for count in proposal_samples)
        self.final_samples = int(final_samples)
        if not self.proposal_samples or min(self.proposal_samples + (self.final_samples,)) < 1:
            raise PointfieldError(
                f"need at least one proposal round and at least one sample per round, got proposal samples "
                f"{self.proposal_samples} and {self.final_samples} final samples"
            )
        if len(max_resolutions) != len(self.proposal_samples):
            raise PointfieldError(
                f"need one max resolution per proposal round ({len(self.proposal_samples)}), "
                f"got {len(max_resolutions)}: {tuple(max_resolutions)}"
            )
        if not linear_until > 0 or histogram_padding < 0:
            raise PointfieldError(
                f"need linear_until > 0 and histogram_padding >= 0, got {linear_until} and {histogram_padding}"
            )
        self.linear_until = float(linear_until)
        self.histogram_padding = float(histogram_padding)
        self.proposal_networks = nn.ModuleList(
            ProposalNetwork(max_resolution=int(resolution), backend=backend) for resolution in max_resolutions
        )

    def forward(
        self,
        rays: RayBundle,
        to_unit: ToUnit,
        *,
        jitter: bool = True,
        generator: torch.Generator | None = None,
        anneal: float = 1.0,
    ) -> tuple[torch.Tensor, list[tuple[torch.Tensor, torch.Tensor]]]:
        """Bin edges for the field on ``rays``, between each ray's ``near`` and ``far``.

        ``to_unit`` maps world positions into the proposal networks' unit cube. ``jitter``:
        random initial edges and inverse-CDF draws (training) or evenly spaced ones (rendering);
        ``generator`` seeds them. ``anneal``: exponent on the proposal weights before resampling
        (:func:`proposal_anneal`).

        Returns ``(edges (R, final_samples + 1), rounds)``: the field's bins (no gradient; see
        :meth:`RaySamples.from_bin_edges <pointfield.fields.rays.RaySamples.from_bin_edges>`) and,
        per proposal round, ``(edges (R, K_i + 1), weights (R, K_i))`` whose weights carry the
        proposal network's gradient, for :func:`interlevel_loss`.
        """
        origins, directions = rays.origins, rays.directions
        near, far = rays.near.to(origins.dtype), rays.far.to(origins.dtype)
        edges = initial_bin_edges(near, far, self.proposal_samples[0], jitter=jitter, generator=generator,
                                  linear_until=self.linear_until)
        next_counts = (*self.proposal_samples[1:], self.final_samples)
        rounds = []
        for network, next_count in zip(self.proposal_networks, next_counts):
            midpoints = 0.5 * (edges[:, 1:] + edges[:, :-1])
            positions = origins[:, None, :] + midpoints[..., None] * directions[:, None, :]
            sigmas = network(to_unit(positions))
            weights, _, _ = render_weights_from_density(sigmas, torch.diff(edges, dim=-1))
            rounds.append((edges, weights))
            histogram = weights.detach() ** anneal + self.histogram_padding
            spacing = importance_samples(
                spacing_from_distance(edges, self.linear_until), histogram, next_count + 1,
                jitter=jitter, generator=generator,
            )
            edges = distance_from_spacing(spacing, self.linear_until)
        return edges, rounds

    def extra_repr(self) -> str:
        return (f"proposal_samples={self.proposal_samples}, final_samples={self.final_samples}, "
                f"linear_until={self.linear_until}, histogram_padding={self.histogram_padding}")


# -- losses ------------------------------------------------------------------------------------------


def outer_weights(edges: torch.Tensor, proposal_edges: torch.Tensor, proposal_weights: torch.Tensor) -> torch.Tensor:
    """Mip-NeRF 360's bound ``w-outer``: for each bin of ``edges``, the proposal weight over it.

    ``bound_i = sum_j w^p_j`` over the proposal bins ``[p_j, p_{j+1})`` that meet ``[t_i, t_{i+1}]``
    (``p_{j+1} > t_i`` and ``p_j <= t_{i+1}``). With ``W_k = sum_{j<k} w^p_j`` (a cumulative sum),
    that is ``W[hi_i] - W[lo_i]``, where ``lo_i`` is the proposal bin holding ``t_i`` and
    ``hi_i - 1`` the one holding ``t_{i+1}`` -- found with ``searchsorted``: O((K + B) log B),
    not the O(K B) of comparing every pair. ``edges`` ``(R, K + 1)``, ``proposal_edges``
    ``(R, B + 1)``, ``proposal_weights`` ``(R, B)``; returns ``(R, K)``, differentiable in the
    proposal weights.
    """
    _check_bins(proposal_edges, proposal_weights, "proposal")
    cumulative = torch.cat([torch.zeros_like(proposal_weights[:, :1]), torch.cumsum(proposal_weights, dim=-1)], dim=-1)
    bins = proposal_weights.shape[-1]
    # at_or_below[k] = number of proposal edges <= edges[k]; the proposal bin holding edges[k] is that - 1.
    at_or_below = torch.searchsorted(proposal_edges.contiguous(), edges.to(proposal_edges.dtype).contiguous(),
                                     right=True)
    lower = (at_or_below[:, :-1] - 1).clamp(0, bins)
    upper = at_or_below[:, 1:].clamp(0, bins)
    return cumulative.gather(-1, upper) - cumulative.gather(-1, lower)


def interlevel_loss(
    final_edges: torch.Tensor,
    final_weights: torch.Tensor,
    proposal_rounds: Sequence[tuple[torch.Tensor, torch.Tensor]],
) -> torch.Tensor:
    """Mip-NeRF 360's proposal loss (eq. 13), summed over proposal rounds: trains only the proposals.

    For each round ``(edges_p (R, B + 1), weights_p (R, B))``::

        L_p = mean over rays of  sum_i max(0, w_i - bound_i)^2 / (w_i + eps)

    with ``bound`` = :func:`outer_weights` of the round on the field's bins ``final_edges``
    ``(R, K + 1)`` and ``w`` = ``final_weights`` ``(R, K)``. A proposal is penalised only where it
    *under*-estimates the field's weight; overestimates (a wider proposal) are free. The field's
    edges and weights are detached, so the field learns nothing from this loss. (Nerfacto takes
    the mean over bins as well, i.e. this divided by K.)
    """
    _check_bins(final_edges, final_weights, "field")
    edges, weights = final_edges.detach(), final_weights.detach()
    loss = weights.new_zeros(())
    for proposal_edges, proposal_weights in proposal_rounds:
        bound = outer_weights(edges, proposal_edges, proposal_weights)
        excess = (weights - bound).clamp_min(0)
        loss = loss + (excess**2 / (weights + INTERLEVEL_EPS)).sum(dim=-1).mean()
    return loss


def _check_bins(edges: torch.Tensor, weights: torch.Tensor, what: str) -> None:
    """Edges ``(R, K + 1)`` must frame weights ``(R, K)``: a mismatch would silently misalign bins."""
    if edges.ndim != 2 or weights.ndim != 2 or edges.shape != (weights.shape[0], weights.shape[1] + 1):
        raise PointfieldError(
            f"{what} bins: expected edges (R, K + 1) and weights (R, K), got edges {tuple(edges.shape)} "
            f"and weights {tuple(weights.shape)}"
        )
