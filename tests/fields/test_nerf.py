"""TinyNeRF and NeRF: shapes of what they render, parameter counts, the skip connection."""

import torch

from pointfield.fields.nerf import NeRF, RadianceMLP, TinyNeRF, build_model, render_in_chunks


def _rays(count: int):
    origins = torch.zeros(count, 3)
    origins[:, 2] = -4
    directions = torch.nn.functional.normalize(torch.randn(count, 3) * 0.1 + torch.tensor([0.0, 0.0, 1.0]), dim=-1)
    return origins, directions, torch.full((count,), 2.0), torch.full((count,), 6.0)


def test_field_maps_positions_and_directions_to_density_and_colour():
    field = RadianceMLP(depth=2, width=16, skips=(), color_width=8)
    sigma, rgb = field(torch.randn(5, 7, 3), torch.randn(5, 7, 3))
    assert sigma.shape == (5, 7) and rgb.shape == (5, 7, 3)
    assert torch.all(sigma >= 0) and torch.all((rgb >= 0) & (rgb <= 1))


def test_tiny_nerf_is_the_4_by_128_network_with_one_pass():
    model = TinyNeRF(samples=8)
    assert [layer.out_features for layer in model.field.trunk] == [128] * 4
    passes = model(*_rays(6), background=torch.ones(3), jitter=True)
    assert len(passes) == 1 and passes[0].color.shape == (6, 3) and passes[0].weights.shape == (6, 8)


def test_nerf_has_8_by_256_trunks_with_the_input_again_after_layer_4():
    model = NeRF(coarse_samples=8, fine_samples=16)
    for field in (model.coarse, model.fine):
        assert [layer.out_features for layer in field.trunk] == [256] * 8
        assert field.trunk[5].in_features == 256 + 63 and field.trunk[4].in_features == 256
    coarse, fine = model(*_rays(4), jitter=True)
    assert coarse.t.shape == (4, 8) and fine.t.shape == (4, 24)


def test_render_in_chunks_matches_one_pass():
    torch.manual_seed(0)
    model = build_model("tiny", samples=8)
    rays = _rays(10)
    whole = model(*rays, torch.ones(3))[-1]
    chunked = render_in_chunks(model, *rays, torch.ones(3), chunk=3)
    torch.testing.assert_close(chunked["color"], whole.color)
    torch.testing.assert_close(chunked["depth"], whole.depth)
