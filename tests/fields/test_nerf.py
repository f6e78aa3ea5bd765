"""TinyNeRF and NeRF: shapes of what they render, parameter counts, the skip connection."""

import torch

from pointfield.fields.nerf import NeRF, RadianceMLP, TinyNeRF
from pointfield.fields.rays import RayBundle


def _rays(count: int) -> RayBundle:
    origins = torch.zeros(count, 3)
    origins[:, 2] = -4
    directions = torch.nn.functional.normalize(torch.randn(count, 3) * 0.1 + torch.tensor([0.0, 0.0, 1.0]), dim=-1)
    return RayBundle(origins, directions, torch.full((count,), 2.0), torch.full((count,), 6.0))


def test_field_maps_positions_and_directions_to_density_and_colour():
    field = RadianceMLP(depth=2, width=16, skips=(), color_width=8)
    sigma, rgb = field(torch.randn(5, 7, 3), torch.randn(5, 7, 3))
    assert sigma.shape == (5, 7) and rgb.shape == (5, 7, 3)
    assert torch.all(sigma >= 0) and torch.all((rgb >= 0) & (rgb <= 1))


def test_tiny_nerf_is_the_4_by_128_network_with_one_pass():
    model = TinyNeRF(samples=8)
    assert [layer.out_features for layer in model.field.trunk] == [128] * 4
    output = model(_rays(6), background=torch.ones(3), jitter=True)
    assert len(output.passes) == 1 and output.final.color.shape == (6, 3) and output.final.weights.shape == (6, 8)
    assert output.samples == 6 * 8 and output.auxiliary_loss is None


def test_nerf_has_8_by_256_trunks_with_the_input_again_after_layer_4():
    model = NeRF(coarse_samples=8, fine_samples=16)
    for field in (model.coarse, model.fine):
        assert [layer.out_features for layer in field.trunk] == [256] * 8
        assert field.trunk[5].in_features == 256 + 63 and field.trunk[4].in_features == 256
    output = model(_rays(4), jitter=True)
    coarse, fine = output.passes
    assert output.final is fine
    assert coarse.samples.t.shape == (4, 8) and fine.samples.t.shape == (4, 24)
    assert output.samples == 4 * 8 + 4 * 24


def test_nerf_samples_are_evaluated_at_their_points_and_reach_to_the_next_one():
    model = TinyNeRF(samples=8)
    samples = model(_rays(3)).final.samples
    torch.testing.assert_close(samples.t, samples.t_starts)
    torch.testing.assert_close(samples.t_ends[:, :-1], samples.t_starts[:, 1:])
    torch.testing.assert_close(samples.t_ends[:, -1], torch.full((3,), 6.0))
