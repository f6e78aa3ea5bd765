"""Nerfacto's proposal sampler, and mip-NeRF 360's interlevel loss."""

import pytest
import torch

from pointfield.errors import PointfieldError
from pointfield.fields.encodings.contraction import contract
from pointfield.fields.rays import RayBundle
from pointfield.fields.rendering import render_weights_from_density
from pointfield.fields.sampling.proposal import (
    ProposalNetwork,
    ProposalSampler,
    distance_from_spacing,
    initial_bin_edges,
    interlevel_loss,
    outer_weights,
    proposal_anneal,
    spacing_from_distance,
)

CENTER = torch.tensor([0.5, -1.0, 2.0])
RADIUS = 3.0


# -- initial samples ---------------------------------------------------------------------------------


def test_spacing_and_its_inverse_agree():
    t = torch.cat([torch.linspace(0, 2, 50), torch.logspace(0.3, 3, 50)]).double()
    torch.testing.assert_close(distance_from_spacing(spacing_from_distance(t, 2.0), 2.0), t)


def test_initial_edges_are_linear_then_linear_in_disparity():
    near, far = torch.tensor([0.0], dtype=torch.float64), torch.tensor([1000.0], dtype=torch.float64)
    edges = initial_bin_edges(near, far, 16, jitter=False, linear_until=2.0)[0]
    linear, disparity = edges[edges < 2.0], edges[edges >= 2.0]
    assert len(linear) == 9  # half the bins (8) within linear_until, edges 0 .. 8
    gaps = torch.diff(linear)
    torch.testing.assert_close(gaps, gaps[:1].expand_as(gaps))
    gaps = torch.diff(1 / disparity)
    torch.testing.assert_close(gaps, gaps[:1].expand_as(gaps))


def test_jittered_initial_edges_increase_from_near_to_far():
    near, far = torch.tensor([0.0, 0.5, 3.0]), torch.tensor([10.0, 1e3, 1e4])
    edges = initial_bin_edges(near, far, 64, generator=torch.Generator().manual_seed(0), linear_until=2.0)
    assert edges.shape == (3, 65)
    assert torch.all(torch.diff(edges, dim=-1) > 0)
    torch.testing.assert_close(edges[:, 0], near)
    torch.testing.assert_close(edges[:, -1], far)


def test_initial_edges_are_reproducible_with_a_generator():
    first = initial_bin_edges(0.1, 50.0, 8, rays=4, generator=torch.Generator().manual_seed(3))
    again = initial_bin_edges(0.1, 50.0, 8, rays=4, generator=torch.Generator().manual_seed(3))
    assert torch.equal(first, again)


# -- losses --------------------------------------------------------------------------------------


def _random_bins(rays, bins, low, high, generator, dtype=torch.float64):
    """Random increasing edges ``(rays, bins + 1)`` from low to high and weights summing to 0.9."""
    inner = torch.sort(low + (high - low) * torch.rand(rays, bins - 1, generator=generator, dtype=dtype), dim=-1).values
    ends = [torch.full((rays, 1), value, dtype=dtype) for value in (low, high)]
    edges = torch.cat([ends[0], inner, ends[1]], dim=-1)
    weights = torch.rand(rays, bins, generator=generator, dtype=dtype)
    return edges, weights / weights.sum(dim=-1, keepdim=True) * 0.9


def test_outer_weights_match_the_brute_force_sum_over_overlapping_bins():
    generator = torch.Generator().manual_seed(4)
    edges, _ = _random_bins(5, 9, -0.2, 1.3, generator)  # reaches beyond the proposal's range
    proposal_edges, proposal_weights = _random_bins(5, 13, 0.0, 1.0, generator)
    expected = torch.zeros(5, 9, dtype=torch.float64)
    for ray in range(5):
        for i in range(9):
            for j in range(13):
                if proposal_edges[ray, j + 1] > edges[ray, i] and proposal_edges[ray, j] <= edges[ray, i + 1]:
                    expected[ray, i] += proposal_weights[ray, j]
    torch.testing.assert_close(outer_weights(edges, proposal_edges, proposal_weights), expected)


def test_interlevel_loss_is_zero_when_the_proposal_equals_the_field():
    edges, weights = _random_bins(4, 20, 0.0, 5.0, torch.Generator().manual_seed(5))
    assert float(interlevel_loss(edges, weights, [(edges, weights.clone())])) < 1e-12


def test_interlevel_loss_charges_the_mass_a_proposal_misses_and_trains_only_the_proposal():
    edges = torch.linspace(0, 1, 11)[None]
    field = torch.zeros(1, 10)
    field[0, 7] = 0.8
    proposal = torch.zeros(1, 10)
    proposal[0, 2] = 0.8  # all its mass on the wrong surface
    proposal.requires_grad_()
    field.requires_grad_()
    loss = interlevel_loss(edges, field, [(edges, proposal)])
    torch.testing.assert_close(loss, torch.tensor(0.8**2 / (0.8 + 1e-7)))
    loss.backward()
    assert field.grad is None
    assert proposal.grad[0, 7] < 0  # more proposal weight at bin 7 (or its neighbours) lowers the loss


def test_overestimating_proposals_are_not_penalised():
    edges, weights = _random_bins(3, 16, 0.0, 2.0, torch.Generator().manual_seed(6))
    proposal_edges, _ = _random_bins(3, 7, 0.0, 2.0, torch.Generator().manual_seed(7))
    everywhere = torch.ones(3, 7, dtype=torch.float64)  # an upper bound on every bin
    assert float(interlevel_loss(edges, weights, [(proposal_edges, everywhere)])) == 0.0


def test_losses_reject_edges_that_do_not_frame_the_weights():
    edges, weights = _random_bins(2, 5, 0.0, 1.0, torch.Generator().manual_seed(9))
    with pytest.raises(PointfieldError, match=r"expected edges \(R, K \+ 1\)"):
        interlevel_loss(edges, weights, [(edges, weights[:, :-1])])
    with pytest.raises(PointfieldError, match="field bins"):
        interlevel_loss(edges[:, :-1], weights, [(edges, weights)])


def _sampler(**options):
    torch.manual_seed(0)
    options = {"proposal_samples": (32, 24), "final_samples": 16, "linear_until": RADIUS, "backend": "eager"} | options
    return ProposalSampler(**options)


def _rays(count, seed):
    generator = torch.Generator().manual_seed(seed)
    origins = CENTER + torch.randn(count, 3, generator=generator) * 0.2 + torch.tensor([0.0, 0.0, -2.0])
    directions = torch.nn.functional.normalize(
        torch.tensor([0.0, 0.0, 1.0]) + 0.1 * torch.randn(count, 3, generator=generator), dim=-1
    )
    return origins, directions


def _to_unit(positions):
    return contract(positions, CENTER, RADIUS)


def test_sampler_returns_increasing_edges_between_near_and_far_and_one_round_per_network():
    sampler = _sampler()
    origins, directions = _rays(10, 0)
    near, far = torch.full((10,), 0.2), torch.full((10,), 1e3 * RADIUS)
    edges, rounds = sampler(RayBundle(origins, directions, near, far), _to_unit,
                            generator=torch.Generator().manual_seed(0))
    assert edges.shape == (10, 17) and not edges.requires_grad
    assert torch.all(torch.diff(edges, dim=-1) >= 0)
    assert torch.all(edges >= near[:, None] * (1 - 1e-5)) and torch.all(edges <= far[:, None] * (1 + 1e-5))
    assert [(e.shape, w.shape) for e, w in rounds] == [((10, 33), (10, 32)), ((10, 25), (10, 24))]
    for (round_edges, weights), network in zip(rounds, sampler.proposal_networks):
        assert torch.all(torch.diff(round_edges, dim=-1) >= 0)
        assert torch.all(weights.sum(-1) <= 1 + 1e-5)
        weights.sum().backward()
        assert network.encoding.table.grad is not None and network.mlp[0].weight.grad.abs().sum() > 0


def test_sampler_without_jitter_is_deterministic():
    sampler = _sampler()
    origins, directions = _rays(6, 1)
    rays = RayBundle(origins, directions, torch.full((6,), 0.1), torch.full((6,), 100.0))
    first, _ = sampler(rays, _to_unit, jitter=False)
    again, _ = sampler(rays, _to_unit, jitter=False)
    assert torch.equal(first, again)


def test_sampler_checks_its_settings():
    with pytest.raises(PointfieldError, match="max resolution per proposal round"):
        ProposalSampler(proposal_samples=(64, 32, 16), backend="eager")
    with pytest.raises(PointfieldError, match="at least one sample"):
        ProposalSampler(proposal_samples=(64, 0), backend="eager")


def test_proposal_anneal_rises_from_zero_to_one():
    assert proposal_anneal(0) == 0.0 and proposal_anneal(1000) == 1.0 and proposal_anneal(5000) == 1.0
    assert 0.5 < proposal_anneal(100) < proposal_anneal(500) < 1.0


# -- training ----------------------------------------------------------------------------------------

SURFACE_CENTER = CENTER
SURFACE_RADIUS = 0.6


def _surface_density(positions):
    """A solid ball in front of the rays: the field whose weights the proposals must learn to bound."""
    return 200.0 * ((positions - SURFACE_CENTER).norm(dim=-1) < SURFACE_RADIUS).to(positions.dtype)


def test_training_a_proposal_network_with_the_interlevel_loss_learns_where_the_surface_is():
    torch.manual_seed(0)
    network = ProposalNetwork(max_resolution=64, backend="eager")
    origins, directions = _rays(8, 2)
    near, far = torch.full((8,), 0.1), torch.full((8,), 6.0)
    proposal_edges = initial_bin_edges(near, far, 48, jitter=False, linear_until=RADIUS)
    field_edges = initial_bin_edges(near, far, 20, jitter=False, linear_until=RADIUS)
    field_mid = 0.5 * (field_edges[:, 1:] + field_edges[:, :-1])
    field_sigma = _surface_density(origins[:, None] + field_mid[..., None] * directions[:, None])
    target, _, _ = render_weights_from_density(field_sigma, torch.diff(field_edges, dim=-1))
    assert torch.all(target.sum(-1) > 0.99)  # every ray hits the ball

    proposal_mid = 0.5 * (proposal_edges[:, 1:] + proposal_edges[:, :-1])
    unit = _to_unit(origins[:, None] + proposal_mid[..., None] * directions[:, None])
    optimizer = torch.optim.Adam(network.parameters(), lr=1e-2)
    losses = []
    for _ in range(100):
        weights, _, _ = render_weights_from_density(network(unit), torch.diff(proposal_edges, dim=-1))
        loss = interlevel_loss(field_edges, target, [(proposal_edges, weights)])
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    assert losses[0] > 0.3
    assert losses[-1] < 0.05 * losses[0]


def test_a_trained_sampler_puts_the_field_samples_on_the_surface():
    sampler = _sampler()
    origins, directions = _rays(32, 3)
    near, far = torch.full((32,), 0.1), torch.full((32,), 1e3 * RADIUS)
    rays = RayBundle(origins, directions, near, far)
    # Distance to the ball's front surface along each ray.
    offset = origins - SURFACE_CENTER
    along = (offset * directions).sum(-1)
    hit = -along - torch.sqrt(along**2 - (offset.norm(dim=-1) ** 2 - SURFACE_RADIUS**2))

    def share_near_surface():
        with torch.no_grad():
            edges, _ = sampler(rays, _to_unit, jitter=False)
        midpoints = 0.5 * (edges[:, 1:] + edges[:, :-1])
        return float(((midpoints - hit[:, None]).abs() < 0.3).float().mean())

    before = share_near_surface()
    optimizer = torch.optim.Adam(sampler.parameters(), lr=1e-2)
    generator = torch.Generator().manual_seed(4)
    for _ in range(60):
        edges, rounds = sampler(rays, _to_unit, generator=generator)
        midpoints = 0.5 * (edges[:, 1:] + edges[:, :-1])
        sigma = _surface_density(origins[:, None] + midpoints[..., None] * directions[:, None])
        weights, _, _ = render_weights_from_density(sigma, torch.diff(edges, dim=-1))
        loss = interlevel_loss(edges, weights, rounds)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    after = share_near_surface()
    assert before < 0.2
    assert after > 2 * before and after > 0.3
