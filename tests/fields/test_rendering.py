"""Compositing against closed forms (issue 5, "What must hold")."""

import math

import torch

from pointfield.fields.rendering import composite_along_rays, render_rays, render_weights_from_density
from pointfield.fields.sampling import sample_deltas, stratified_samples


def _slab(sigma: float, start: float, end: float):
    """A field of constant density ``sigma`` for start <= z < end, red, zero elsewhere."""

    def field(positions, directions):
        z = positions[..., 2]
        density = torch.where((z >= start) & (z < end), torch.full_like(z, sigma), torch.zeros_like(z))
        rgb = torch.zeros_like(positions)
        rgb[..., 0] = 1
        return density, rgb

    return field


def _rays_along_z(count: int = 4):
    origins = torch.zeros(count, 3, dtype=torch.float64)
    directions = torch.zeros(count, 3, dtype=torch.float64)
    directions[:, 2] = 1
    return origins, directions


def test_constant_density_slab_has_opacity_one_minus_exp_sigma_length():
    origins, directions = _rays_along_z()
    t = stratified_samples(0.0, 4.0, 4000, rays=4, jitter=False).double()
    sigma, start, end = 0.7, 1.0, 2.5
    out = render_rays(_slab(sigma, start, end), origins, directions, t, 4.0)
    expected = 1 - math.exp(-sigma * (end - start))
    torch.testing.assert_close(out.opacity, torch.full((4,), expected, dtype=torch.float64), atol=1e-3, rtol=0)


def test_slab_filling_whole_interval_is_exact_for_any_sample_count():
    t = stratified_samples(1.0, 3.0, 7, rays=2, jitter=True).double()
    sigmas = torch.full_like(t, 0.4)
    weights, _, _ = render_weights_from_density(sigmas, sample_deltas(t, 3.0))
    expected = 1 - torch.exp(-0.4 * (3.0 - t[:, 0]))
    torch.testing.assert_close(weights.sum(-1), expected, atol=1e-12, rtol=0)


def test_opaque_wall_gives_its_depth():
    origins, directions = _rays_along_z()
    t = stratified_samples(0.0, 6.0, 600, rays=4, jitter=False).double()
    wall = 3.0
    out = render_rays(_slab(1e4, wall, 10.0), origins, directions, t, 6.0)
    torch.testing.assert_close(out.opacity, torch.ones(4, dtype=torch.float64))
    # The first sample at or past the wall stops the ray: depth within one sample spacing.
    assert torch.all((out.depth - wall).abs() <= 6.0 / 600)


def test_weights_sum_to_opacity_and_colour_blends_background():
    generator = torch.Generator().manual_seed(0)
    sigmas = torch.rand(8, 32, generator=generator, dtype=torch.float64) * 2
    colors = torch.rand(8, 32, 3, generator=generator, dtype=torch.float64)
    t = stratified_samples(2.0, 6.0, 32, rays=8, generator=generator).double()
    background = torch.tensor([1.0, 0.5, 0.25], dtype=torch.float64)
    out = composite_along_rays(sigmas, colors, t, sample_deltas(t, 6.0), background)
    torch.testing.assert_close(out.weights.sum(-1), out.opacity)
    assert torch.all((out.opacity > 0) & (out.opacity < 1))
    expected = (out.weights[..., None] * colors).sum(1) + (1 - out.opacity)[:, None] * background
    torch.testing.assert_close(out.color, expected)


def test_transmittance_is_exp_of_exclusive_cumulative_optical_depth():
    sigmas = torch.tensor([[1.0, 2.0, 3.0]], dtype=torch.float64)
    deltas = torch.tensor([[0.5, 0.25, 0.1]], dtype=torch.float64)
    weights, transmittance, alphas = render_weights_from_density(sigmas, deltas)
    torch.testing.assert_close(transmittance, torch.exp(-torch.tensor([[0.0, 0.5, 1.0]], dtype=torch.float64)))
    torch.testing.assert_close(alphas, 1 - torch.exp(-sigmas * deltas))
    torch.testing.assert_close(weights, transmittance * alphas)


def test_gradients_are_finite_where_alpha_is_one():
    sigmas = torch.tensor([[0.5, 1e6, 1e9, 3.0]], dtype=torch.float32, requires_grad=True)
    colors = torch.rand(1, 4, 3, requires_grad=True)
    t = torch.tensor([[1.0, 2.0, 3.0, 4.0]])
    out = composite_along_rays(sigmas, colors, t, sample_deltas(t, 5.0), torch.ones(3))
    assert torch.all(out.weights[0, 2:] == 0) and out.opacity.item() == 1.0
    (out.color.sum() + out.depth.sum()).backward()
    assert torch.all(torch.isfinite(sigmas.grad)) and torch.all(torch.isfinite(colors.grad))
    # Light that reaches a sample's front still depends on the densities before it.
    assert sigmas.grad[0, 0] != 0


def test_empty_space_shows_the_background():
    t = stratified_samples(2.0, 6.0, 8, rays=3, jitter=False)
    out = composite_along_rays(torch.zeros(3, 8), torch.rand(3, 8, 3), t, sample_deltas(t, 6.0), torch.ones(3))
    torch.testing.assert_close(out.color, torch.ones(3, 3))
    torch.testing.assert_close(out.opacity, torch.zeros(3))
