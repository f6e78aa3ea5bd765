"""NeRF's samplers: stratified and importance sampling."""

import numpy as np
import torch

from pointfield.fields.rays import RaySamples
from pointfield.fields.sampling.stratified import hierarchical_samples, importance_samples, stratified_samples


def test_stratified_samples_fall_one_in_each_bin_and_are_sorted():
    t = stratified_samples(torch.tensor([2.0, 1.0]), torch.tensor([6.0, 3.0]), 16, generator=torch.Generator().manual_seed(1))
    assert t.shape == (2, 16)
    for ray, (near, far) in enumerate(((2.0, 6.0), (1.0, 3.0))):
        bins = torch.floor((t[ray] - near) / (far - near) * 16)
        assert torch.equal(bins, torch.arange(16, dtype=t.dtype))
    assert torch.all(torch.diff(t, dim=-1) > 0)


def test_stratified_without_jitter_takes_bin_centres():
    torch.testing.assert_close(stratified_samples(2.0, 6.0, 4, rays=1, jitter=False), torch.tensor([[2.5, 3.5, 4.5, 5.5]]))


def test_deltas_of_stratified_samples_tile_the_ray_up_to_far():
    t = stratified_samples(2.0, 6.0, 5, rays=3)
    deltas = RaySamples.from_points(t, 6.0).deltas
    torch.testing.assert_close(t[:, 0] + deltas.sum(-1), torch.full((3,), 6.0))


def test_importance_sampling_draws_from_the_piecewise_constant_pdf():
    edges = torch.tensor([[0.0, 1.0, 1.5, 3.0, 4.0, 6.0]], dtype=torch.float64)
    weights = torch.tensor([[0.1, 0.4, 0.0, 0.3, 0.2]], dtype=torch.float64)
    draws = importance_samples(edges, weights, 20000, generator=torch.Generator().manual_seed(0))[0].numpy()
    assert np.all(np.diff(draws) >= 0)
    # Kolmogorov-Smirnov against the exact piecewise-linear CDF (weights get + 1e-5 each).
    w = weights[0].numpy() + 1e-5
    cdf_at_edges = np.concatenate([[0], np.cumsum(w / w.sum())])
    exact = np.interp(draws, edges[0].numpy(), cdf_at_edges)
    empirical = np.arange(1, len(draws) + 1) / len(draws)
    statistic = max(np.abs(empirical - exact).max(), np.abs(empirical - 1 / len(draws) - exact).max())
    assert statistic < 1.63 / np.sqrt(len(draws))  # KS critical value at the 1 % level
    # Chi-square over the bins (the empty bin excluded: it must get (almost) nothing).
    counts = np.histogram(draws, bins=edges[0].numpy())[0]
    assert counts[2] <= 5
    keep = [0, 1, 3, 4]
    expected = len(draws) * (w / w.sum())[keep]
    chi_square = ((counts[keep] - expected) ** 2 / expected).sum()
    assert chi_square < 11.34  # chi-square, 3 degrees of freedom, 1 % level


def test_importance_samples_of_all_zero_weights_are_uniform():
    edges = torch.linspace(0, 1, 5)[None]
    draws = importance_samples(edges, torch.zeros(1, 4), 8, jitter=False)
    torch.testing.assert_close(draws, ((torch.arange(8) + 0.5) / 8)[None])


def test_hierarchical_samples_concentrate_where_the_coarse_weights_are():
    t_coarse = stratified_samples(2.0, 6.0, 16, rays=1, jitter=False)
    weights = torch.zeros(1, 16)
    weights[0, 8] = 1.0  # all the mass in the bin around t = 4.125
    t = hierarchical_samples(t_coarse, weights, 2.0, 6.0, 32, generator=torch.Generator().manual_seed(0))
    assert t.shape == (1, 48) and torch.all(torch.diff(t, dim=-1) >= 0)
    fine = t[0][~torch.isin(t[0], t_coarse[0])]
    assert torch.all((fine >= 4.0) & (fine <= 4.25))
