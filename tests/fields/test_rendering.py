"""The compositor: against closed forms (issue 5, "What must hold"), padded and packed alike."""

import math

import pytest
import torch

from pointfield.fields.rays import RayBundle, RaySamples
from pointfield.fields.rendering import (
    composite,
    distortion_loss,
    render_rays,
    render_weights_from_density,
    transmittance_from_optical_depth,
)
from pointfield.fields.sampling.stratified import stratified_samples


def _slab(sigma: float, start: float, end: float):
    """A field of constant density ``sigma`` for start <= z < end, red, zero elsewhere."""

    def field(positions, directions):
        z = positions[..., 2]
        density = torch.where((z >= start) & (z < end), torch.full_like(z, sigma), torch.zeros_like(z))
        rgb = torch.zeros_like(positions)
        rgb[..., 0] = 1
        return density, rgb

    return field


def _rays_along_z(near: float, far: float, count: int = 4) -> RayBundle:
    origins = torch.zeros(count, 3, dtype=torch.float64)
    directions = torch.zeros(count, 3, dtype=torch.float64)
    directions[:, 2] = 1
    return RayBundle(origins, directions, torch.full((count,), near, dtype=torch.float64),
                     torch.full((count,), far, dtype=torch.float64))


def test_constant_density_slab_has_opacity_one_minus_exp_sigma_length():
    rays = _rays_along_z(0.0, 4.0)
    t = stratified_samples(0.0, 4.0, 4000, rays=4, jitter=False).double()
    sigma, start, end = 0.7, 1.0, 2.5
    out = render_rays(_slab(sigma, start, end), rays, RaySamples.from_points(t, rays.far))
    expected = 1 - math.exp(-sigma * (end - start))
    torch.testing.assert_close(out.opacity, torch.full((4,), expected, dtype=torch.float64), atol=1e-3, rtol=0)


def test_slab_filling_whole_interval_is_exact_for_any_sample_count():
    t = stratified_samples(1.0, 3.0, 7, rays=2, jitter=True).double()
    sigmas = torch.full_like(t, 0.4)
    weights, _, _ = render_weights_from_density(sigmas, RaySamples.from_points(t, 3.0).deltas)
    expected = 1 - torch.exp(-0.4 * (3.0 - t[:, 0]))
    torch.testing.assert_close(weights.sum(-1), expected, atol=1e-12, rtol=0)


def test_opaque_wall_gives_its_depth():
    rays = _rays_along_z(0.0, 6.0)
    t = stratified_samples(0.0, 6.0, 600, rays=4, jitter=False).double()
    wall = 3.0
    out = render_rays(_slab(1e4, wall, 10.0), rays, RaySamples.from_points(t, rays.far))
    torch.testing.assert_close(out.opacity, torch.ones(4, dtype=torch.float64))
    # The first sample at or past the wall stops the ray: depth within one sample spacing.
    assert torch.all((out.depth - wall).abs() <= 6.0 / 600)


def test_weights_sum_to_opacity_and_colour_blends_background():
    generator = torch.Generator().manual_seed(0)
    sigmas = torch.rand(8, 32, generator=generator, dtype=torch.float64) * 2
    colors = torch.rand(8, 32, 3, generator=generator, dtype=torch.float64)
    t = stratified_samples(2.0, 6.0, 32, rays=8, generator=generator).double()
    background = torch.tensor([1.0, 0.5, 0.25], dtype=torch.float64)
    out = composite(sigmas, colors, RaySamples.from_points(t, 6.0), background)
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
    out = composite(sigmas, colors, RaySamples.from_points(t, 5.0), torch.ones(3))
    assert torch.all(out.weights[0, 2:] == 0) and out.opacity.item() == 1.0
    (out.color.sum() + out.depth.sum()).backward()
    assert torch.all(torch.isfinite(sigmas.grad)) and torch.all(torch.isfinite(colors.grad))
    # Light that reaches a sample's front still depends on the densities before it.
    assert sigmas.grad[0, 0] != 0


def test_empty_space_shows_the_background():
    t = stratified_samples(2.0, 6.0, 8, rays=3, jitter=False)
    out = composite(torch.zeros(3, 8), torch.rand(3, 8, 3), RaySamples.from_points(t, 6.0), torch.ones(3))
    torch.testing.assert_close(out.color, torch.ones(3, 3))
    torch.testing.assert_close(out.opacity, torch.zeros(3))


# -- packed samples --------------------------------------------------------------------------------


def _packed_and_padded(lengths, seed=0, dtype=torch.float64):
    """Random samples of rays with ``lengths`` samples each, packed and padded to an (R, K) block.

    The padding on the padded side is zero-length intervals at the ray's end, which composite to
    nothing. Returns ``(packed, padded, sigmas (S,), colors (S, 3), where)``, ``where`` the
    ``(ray, slot)`` of each packed sample in the block.
    """
    generator = torch.Generator().manual_seed(seed)
    rays, width = len(lengths), max(lengths)
    ray_indices = torch.repeat_interleave(torch.arange(rays), torch.tensor(lengths))
    slots = torch.cat([torch.arange(n) for n in lengths])
    deltas = torch.rand(len(ray_indices), generator=generator, dtype=dtype) * 0.3 + 0.01
    gaps = torch.rand(len(ray_indices), generator=generator, dtype=dtype) * 0.2  # skipped empty space
    t_starts = torch.zeros_like(deltas)
    for ray in range(rays):  # per ray: start at 2, then each sample after the previous one and a gap
        members = (ray_indices == ray).nonzero()[:, 0]
        t_starts[members] = 2 + torch.cumsum(gaps[members] + deltas[members], 0) - deltas[members]
    packed = RaySamples(t_starts, t_starts + deltas, ray_indices, num_rays=rays)
    padded_starts = torch.full((rays, width), 10.0, dtype=dtype)
    padded_ends = padded_starts.clone()
    padded_starts[ray_indices, slots] = packed.t_starts
    padded_ends[ray_indices, slots] = packed.t_ends
    padded = RaySamples(padded_starts, padded_ends)
    sigmas = torch.rand(len(ray_indices), generator=generator, dtype=dtype) * 8
    colors = torch.rand(len(ray_indices), 3, generator=generator, dtype=dtype)
    return packed, padded, sigmas, colors, (ray_indices, slots)


def _padded_values(values, where, shape):
    block = values.new_zeros(*shape, *values.shape[1:])
    block[where] = values
    return block


def test_packed_compositing_equals_padded_compositing_for_rays_of_different_lengths():
    lengths = [3, 0, 5, 1, 2, 7]
    packed, padded, sigmas, colors, where = _packed_and_padded(lengths)
    background = torch.tensor([1.0, 0.5, 0.25], dtype=torch.float64)
    shape = padded.t_starts.shape
    from_packed = composite(sigmas, colors, packed, background)
    from_padded = composite(_padded_values(sigmas, where, shape), _padded_values(colors, where, shape), padded,
                            background)
    for name in ("color", "opacity", "depth"):
        torch.testing.assert_close(getattr(from_packed, name), getattr(from_padded, name), atol=1e-12, rtol=0,
                                   msg=name)
    torch.testing.assert_close(from_packed.weights, from_padded.weights[where], atol=1e-12, rtol=0)
    torch.testing.assert_close(from_packed.color[1], background)  # the ray with no samples
    assert from_packed.opacity[1] == 0 and from_packed.depth[1] == 0


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_the_same_samples_composite_alike_padded_and_packed(dtype):
    generator = torch.Generator().manual_seed(3)
    t = stratified_samples(2.0, 6.0, 24, rays=5, generator=generator).to(dtype)
    padded = RaySamples.from_points(t, 6.0)
    sigmas = torch.rand(5, 24, generator=generator, dtype=dtype) * 3
    colors = torch.rand(5, 24, 3, generator=generator, dtype=dtype)
    background = torch.tensor([0.2, 0.4, 0.6], dtype=dtype)
    from_padded = composite(sigmas, colors, padded, background)
    from_packed = composite(sigmas.reshape(-1), colors.reshape(-1, 3), padded.packed(), background)
    tolerance = 1e-6 if dtype == torch.float32 else 1e-12  # relative: depth is about 4
    for name in ("color", "depth", "opacity"):
        torch.testing.assert_close(getattr(from_packed, name), getattr(from_padded, name), atol=tolerance,
                                   rtol=tolerance, msg=name)
    torch.testing.assert_close(from_packed.weights, from_padded.weights.reshape(-1), atol=tolerance,
                               rtol=tolerance)


def test_packed_compositing_has_the_gradients_of_padded_compositing():
    lengths = [4, 1, 0, 6, 2]
    packed, padded, sigmas, colors, where = _packed_and_padded(lengths, seed=1)
    background = torch.tensor([0.2, 0.9, 0.4], dtype=torch.float64)
    generator = torch.Generator().manual_seed(5)
    upstream = [torch.randn(shape, generator=generator, dtype=torch.float64) for shape in ((5, 3), (5,), (5,))]

    def loss(rendered):
        return sum((value * weight).sum() for value, weight in
                   zip((rendered.color, rendered.opacity, rendered.depth), upstream))

    sigmas.requires_grad_(), colors.requires_grad_()
    packed_grads = torch.autograd.grad(loss(composite(sigmas, colors, packed, background)), (sigmas, colors))
    shape = padded.t_starts.shape
    padded_sigmas = _padded_values(sigmas.detach(), where, shape).requires_grad_()
    padded_colors = _padded_values(colors.detach(), where, shape).requires_grad_()
    padded_grads = torch.autograd.grad(loss(composite(padded_sigmas, padded_colors, padded, background)),
                                       (padded_sigmas, padded_colors))
    torch.testing.assert_close(packed_grads[0], padded_grads[0][where], atol=1e-12, rtol=0)
    torch.testing.assert_close(packed_grads[1], padded_grads[1][where], atol=1e-12, rtol=0)
    assert packed_grads[0].abs().min() > 0


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("opaque", [1e30, math.inf])
def test_packed_transmittance_is_exact_after_huge_optical_depths_and_other_rays_do_not_notice(dtype, opaque):
    optical_depth = torch.tensor([0.5, opaque, 2.0, 0.3, 0.2, opaque, 1.0, 0.7], dtype=dtype)
    ray_indices = torch.tensor([0, 0, 0, 1, 1, 2, 2, 3])
    transmittance = transmittance_from_optical_depth(optical_depth, ray_indices)
    expected = torch.tensor([1.0, math.exp(-0.5), 0.0, 1.0, math.exp(-0.3), 1.0, 0.0, 1.0], dtype=dtype)
    assert not transmittance.isnan().any()
    torch.testing.assert_close(transmittance, expected, atol=0, rtol=1e-6 if dtype == torch.float32 else 1e-12)
    assert transmittance[2] == 0 and transmittance[6] == 0


def test_an_infinitely_dense_packed_sample_gives_finite_gradients_and_an_opaque_pixel():
    samples = RaySamples(torch.tensor([1.0, 1.1, 1.2, 1.0, 1.1]), torch.tensor([1.1, 1.2, 1.3, 1.1, 1.2]),
                         ray_indices=torch.tensor([0, 0, 0, 1, 1]), num_rays=2)
    sigmas = torch.tensor([0.5, math.inf, 3.0, 0.5, 2.0], requires_grad=True)
    colors = torch.rand(5, 3, requires_grad=True)
    rendered = composite(sigmas, colors, samples, torch.ones(3))
    assert rendered.opacity[0] == 1 and rendered.weights[2] == 0
    torch.testing.assert_close(rendered.opacity[1], torch.tensor(1 - math.exp(-0.25)))
    (rendered.color.sum() + rendered.depth.sum()).backward()
    assert torch.isfinite(colors.grad).all() and torch.isfinite(sigmas.grad).all()


def _brute_force_distortion(weights, samples):
    middle, deltas = 0.5 * (samples.t_starts + samples.t_ends), samples.deltas
    pairs = weights[:, :, None] * weights[:, None, :] * (middle[:, :, None] - middle[:, None, :]).abs()
    return (pairs.sum((1, 2)) + (weights ** 2 * deltas).sum(-1) / 3).mean()


def test_distortion_loss_is_mip_nerf_360s_double_sum_padded_and_packed():
    generator = torch.Generator().manual_seed(0)
    edges = torch.cumsum(torch.rand(5, 9, generator=generator, dtype=torch.float64), dim=-1)
    samples = RaySamples.from_bin_edges(edges)
    weights = torch.rand(5, 8, generator=generator, dtype=torch.float64) / 8
    expected = _brute_force_distortion(weights, samples)
    torch.testing.assert_close(distortion_loss(weights, samples, 1.0), expected)
    torch.testing.assert_close(distortion_loss(weights.reshape(-1), samples.packed(), 1.0), expected)
    # Lengths in units of `length`: the same rays in a scene twice as large give the same loss.
    torch.testing.assert_close(distortion_loss(weights, RaySamples.from_bin_edges(2 * edges), 2.0), expected)


def test_distortion_loss_prefers_one_thin_layer_and_its_gradient_draws_weight_together():
    samples = RaySamples.from_bin_edges(torch.linspace(2.0, 4.0, 21, dtype=torch.float64)[None])
    spread = torch.full((1, 20), 0.9 / 20, dtype=torch.float64)
    thin = torch.zeros(1, 20, dtype=torch.float64)
    thin[0, 10] = 0.9
    assert distortion_loss(thin, samples, 2.0) < 0.1 * distortion_loss(spread, samples, 2.0)
    # Two layers: the gradient shrinks the fainter one faster (it pays for the heavier one's distance).
    two = torch.zeros(1, 20, dtype=torch.float64)
    two[0, 2], two[0, 17] = 0.6, 0.3
    two.requires_grad_(True)
    distortion_loss(two, samples, 2.0).backward()
    assert two.grad[0, 17] > two.grad[0, 2] > 0
