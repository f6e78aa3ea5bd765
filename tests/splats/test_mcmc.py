"""3DGS-MCMC densification (``--strategy mcmc``): a hard cap, dead splats relocated, learning from a random start."""

import json

import pytest
import torch
from splat_strategy import model_and_optimizer, training_steps

from pointfield.errors import PointfieldError
from pointfield.splats.densification import DefaultStrategy, MCMCStrategy, make_strategy, relocation
from pointfield.splats.gaussians import PARAMETER_NAMES
from pointfield.splats.train import train


def test_the_count_grows_to_the_cap_and_never_past_it():
    gaussians, optimizer = model_and_optimizer(seed=2)
    strategy = MCMCStrategy(refine_start=0, refine_every=1, max_splats=112, log=lambda _: None)
    counts = []
    training_steps(gaussians, optimizer, strategy, 6, counts)
    # 5 % more per refinement: 100 -> 105 -> 110 -> 112, then held.
    assert counts == [105, 110, 112, 112, 112]
    for name in PARAMETER_NAMES:
        parameter = getattr(gaussians, name)
        assert optimizer.state[parameter]["exp_avg"].shape == parameter.shape


def test_dead_splats_are_moved_onto_live_ones_and_come_back_to_life():
    gaussians, optimizer = model_and_optimizer(20, seed=2)
    with torch.no_grad():
        gaussians.opacity_logits[:5] = -10.0                      # opacity 4.5e-5: dead
        gaussians.opacity_logits[5:] = 0.0                        # 0.5
    live_means = gaussians.means.detach()[5:].clone()
    strategy = MCMCStrategy(refine_start=0, refine_every=1, max_splats=20, noise_lr=0.0)
    changes = strategy.after_backward(gaussians, optimizer, {}, 1, 48, 48)
    assert changes == {"relocated": 5, "added": 0}
    assert len(gaussians) == 20
    assert float(gaussians.opacities.detach().min()) > strategy.min_opacity
    # Each former dead splat now sits exactly on one of the live ones.
    distances = torch.cdist(gaussians.means.detach()[:5], live_means)
    assert float(distances.min(dim=1).values.max()) == 0.0


def test_the_copies_of_a_relocated_splat_are_as_opaque_together_as_it_was():
    opacities = torch.tensor([0.2, 0.5, 0.9, 0.99])
    scales = torch.ones(4, 3)
    for copies in (1, 2, 3, 7):
        shared, new_scales = relocation(opacities, scales, torch.full((4,), copies))
        # 1 - (1 - o')^n = o: n copies in one place let through what the one did.
        assert torch.allclose(1 - (1 - shared) ** copies, opacities, atol=1e-6)
        if copies == 1:
            assert torch.equal(shared, opacities) and torch.allclose(new_scales, scales)
        else:
            assert bool((shared < opacities).all())


def test_noise_moves_nearly_transparent_splats_and_leaves_opaque_ones():
    gaussians, optimizer = model_and_optimizer(10, seed=2)
    with torch.no_grad():
        gaussians.opacity_logits[:5] = -8.0                       # 3e-4
        gaussians.opacity_logits[5:] = 2.0                        # 0.88
    before = gaussians.means.detach().clone()
    MCMCStrategy(refine_start=1000).after_backward(gaussians, optimizer, {}, 1, 48, 48)
    moved = (gaussians.means.detach() - before).norm(dim=1)
    assert bool((moved[:5] > 1e-4).all()), moved
    assert float(moved[5:].max()) < 1e-9, moved


def test_the_strategy_is_chosen_by_name_in_one_place():
    assert isinstance(make_strategy("default", scene_scale=1, max_splats=10, seed=0, steps=3000), DefaultStrategy)
    mcmc = make_strategy("mcmc", scene_scale=2, max_splats=10, seed=0, steps=3000)
    assert isinstance(mcmc, MCMCStrategy) and mcmc.max_splats == 10 and mcmc.refine_stop == 2500
    with pytest.raises(PointfieldError, match="--strategy must be one of default, mcmc"):
        train(None, out="unused", strategy="nonsense", steps=1, progress=False)


CUBE = {"cube_views": 12, "cube_size": 24}


@pytest.fixture(scope="module")
def mcmc_cube_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("splat-mcmc") / "run"
    train(None, out=out, strategy="mcmc", init="random", steps=120, eval_every=30, initial_splats=300,
          max_splats=600, seed=0, device="cpu", progress=False, **CUBE)
    records = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    config = json.loads((out / "config.json").read_text())
    return records, json.loads((out / "metrics.json").read_text()), config


def test_mcmc_learns_the_cube_from_a_random_start(mcmc_cube_run, best_flat_colour_psnr):
    records, final, config = mcmc_cube_run
    assert config["strategy"] == "mcmc"
    losses = [r["train_loss"] for r in records]
    assert losses[-1] < 0.75 * losses[0], losses
    assert final["psnr"] > best_flat_colour_psnr(CUBE["cube_views"], CUBE["cube_size"]) + 5.0, final
    assert final["splats"] <= 600
