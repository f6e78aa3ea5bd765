"""The model contract: FieldOutput, the hooks' defaults, the ray budget, chunked rendering, the registry."""

import pytest
import torch

from pointfield.fields import MODELS, build_model
from pointfield.fields.field import FieldOutput, RadianceField, RayBudget, render_in_chunks
from pointfield.fields.nerf import NeRF, TinyNeRF
from pointfield.fields.ngp import InstantNGP
from pointfield.fields.rays import RayBundle
from pointfield.fields.sdf import NeuralSDF


def _rays(count: int) -> RayBundle:
    origins = torch.zeros(count, 3)
    origins[:, 2] = -4
    directions = torch.nn.functional.normalize(torch.randn(count, 3) * 0.1 + torch.tensor([0.0, 0.0, 1.0]), dim=-1)
    return RayBundle(origins, directions, torch.full((count,), 2.0), torch.full((count,), 6.0))


def test_every_model_is_a_radiance_field_and_only_the_marched_ones_ask_for_a_sample_budget():
    assert MODELS == {"tiny": TinyNeRF, "nerf": NeRF, "ngp": InstantNGP, "sdf": NeuralSDF}
    assert all(issubclass(model, RadianceField) for model in MODELS.values())
    assert TinyNeRF().target_samples is None and NeRF().target_samples is None
    assert InstantNGP(backend="eager", target_samples=1000).target_samples == 1000
    assert NeuralSDF(backend="eager", target_samples=1000).target_samples == 1000


def test_the_hooks_do_nothing_by_default():
    model = TinyNeRF(samples=4)
    before = {name: value.clone() for name, value in model.state_dict().items()}
    model.before_step(0, torch.Generator().manual_seed(0))
    model.warm_up()
    assert all(torch.equal(value, before[name]) for name, value in model.state_dict().items())


def test_the_final_pass_is_the_last():
    output = NeRF(coarse_samples=4, fine_samples=4)(_rays(2))
    assert isinstance(output, FieldOutput) and output.final is output.passes[-1] and len(output.passes) == 2


def test_build_model_rejects_an_unknown_name():
    with pytest.raises(ValueError, match="choose one of tiny, nerf, ngp"):
        build_model("mipnerf")


def test_render_in_chunks_matches_one_pass():
    torch.manual_seed(0)
    model = build_model("tiny", samples=8)
    rays = _rays(10)
    whole = model(rays, torch.ones(3)).final
    chunked = render_in_chunks(model, rays, torch.ones(3), chunk=3)
    assert set(chunked) == {"rgb", "depth", "median_depth", "opacity"} and not chunked["rgb"].requires_grad
    torch.testing.assert_close(chunked["rgb"], whole.color.detach())
    torch.testing.assert_close(chunked["depth"], whole.depth.detach())
    torch.testing.assert_close(chunked["median_depth"], whole.median_depth)
    torch.testing.assert_close(chunked["opacity"], whole.opacity.detach())


def test_the_ray_budget_moves_half_way_to_the_rays_that_meet_the_target():
    budget = RayBudget(4096)
    assert budget.rays() == 1024  # the first guess
    budget.update(1024, 8192.0)  # twice the target: 512 rays would have met it
    assert budget.rays() == (1024 + 512) // 2
    budget.update(768, 0.0)  # a step that cost nothing counts as one sample
    assert budget.rays() == 1 << 14  # capped


def test_the_ray_budget_stays_within_its_bounds():
    budget = RayBudget(100, smallest=300, largest=2000)
    for _ in range(10):
        budget.update(budget.rays(), 1e9)
    assert budget.rays() == 300
    assert repr(budget) == "RayBudget(target_samples=100, smallest=300, largest=2000)"
