"""The fast field (issue 6): packed compositing, marching, the occupancy grid, scene boxes, training."""

import dataclasses
import json
import math
import shutil

import pytest
import torch

from pointfield.cli import main
from pointfield.compiling import compiler_available
from pointfield.fields import ngp
from pointfield.fields.ngp import (
    InstantNGP,
    OccupancyGrid,
    PackedSamples,
    composite_packed,
    march_rays,
    packed_transmittance,
    ray_box_intersection,
    scene_bounds,
)
from pointfield.fields.rendering import composite_along_rays
from pointfield.fields.train import train
from pointfield.scenes import read_scene, synthetic_scene

UNIT_BOX = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])


def _packed_and_dense(lengths, seed=0, dtype=torch.float64):
    """Random samples of rays with ``lengths`` samples each, packed and padded to an (R, K) block.

    The padding on the dense side is zero-length intervals at the ray's end, which composite to
    nothing. Returns ``(samples, sigmas (S,), colors (S, 3), t (R, K), deltas (R, K), where)``,
    ``where`` the ``(ray, slot)`` of each packed sample in the block.
    """
    generator = torch.Generator().manual_seed(seed)
    rays, width = len(lengths), max(lengths)
    ray_indices = torch.repeat_interleave(torch.arange(rays), torch.tensor(lengths))
    slots = torch.cat([torch.arange(n) for n in lengths])
    deltas_packed = torch.rand(len(ray_indices), generator=generator, dtype=dtype) * 0.3 + 0.01
    gaps = torch.rand(len(ray_indices), generator=generator, dtype=dtype) * 0.2  # skipped empty space
    t_starts = torch.zeros_like(deltas_packed)
    for ray in range(rays):  # per ray: start at 2, then each sample after the previous one and a gap
        members = (ray_indices == ray).nonzero()[:, 0]
        t_starts[members] = 2 + torch.cumsum(gaps[members] + deltas_packed[members], 0) - deltas_packed[members]
    samples = PackedSamples(ray_indices, t_starts, t_starts + deltas_packed)
    sigmas = torch.rand(len(ray_indices), generator=generator, dtype=dtype) * 8
    colors = torch.rand(len(ray_indices), 3, generator=generator, dtype=dtype)
    t = torch.full((rays, width), 10.0, dtype=dtype)
    t[ray_indices, slots] = 0.5 * (samples.t_starts + samples.t_ends)
    deltas = torch.zeros(rays, width, dtype=dtype)
    deltas[ray_indices, slots] = deltas_packed
    return samples, sigmas, colors, t, deltas, (ray_indices, slots)


# -- compositing packed samples ------------------------------------------------------------------------


def test_packed_compositing_equals_dense_compositing_for_rays_of_different_lengths():
    lengths = [3, 0, 5, 1, 2, 7]
    samples, sigmas, colors, t, deltas, where = _packed_and_dense(lengths)
    background = torch.tensor([1.0, 0.5, 0.25], dtype=torch.float64)
    dense_sigmas = torch.zeros_like(t)
    dense_sigmas[where] = sigmas
    dense_colors = torch.zeros(*t.shape, 3, dtype=torch.float64)
    dense_colors[where] = colors
    packed = composite_packed(sigmas, colors, samples, len(lengths), background)
    dense = composite_along_rays(dense_sigmas, dense_colors, t, deltas, background)
    for name in ("color", "opacity", "depth"):
        torch.testing.assert_close(getattr(packed, name), getattr(dense, name), atol=1e-12, rtol=0, msg=name)
    torch.testing.assert_close(packed.weights, dense.weights[where], atol=1e-12, rtol=0)
    torch.testing.assert_close(packed.color[1], background)  # the ray with no samples
    assert packed.opacity[1] == 0 and packed.depth[1] == 0


def test_packed_compositing_has_the_gradients_of_dense_compositing():
    lengths = [4, 1, 0, 6, 2]
    samples, sigmas, colors, t, deltas, where = _packed_and_dense(lengths, seed=1)
    background = torch.tensor([0.2, 0.9, 0.4], dtype=torch.float64)
    generator = torch.Generator().manual_seed(5)
    upstream = [torch.randn(shape, generator=generator, dtype=torch.float64) for shape in ((5, 3), (5,), (5,))]

    def loss(rendered):
        return sum((value * weight).sum() for value, weight in
                   zip((rendered.color, rendered.opacity, rendered.depth), upstream))

    sigmas.requires_grad_(), colors.requires_grad_()
    packed_grads = torch.autograd.grad(loss(composite_packed(sigmas, colors, samples, 5, background)),
                                       (sigmas, colors))
    dense_sigmas = torch.zeros_like(t)
    dense_sigmas[where] = sigmas.detach()
    dense_colors = torch.zeros(*t.shape, 3, dtype=torch.float64)
    dense_colors[where] = colors.detach()
    dense_sigmas.requires_grad_(), dense_colors.requires_grad_()
    dense_grads = torch.autograd.grad(loss(composite_along_rays(dense_sigmas, dense_colors, t, deltas, background)),
                                      (dense_sigmas, dense_colors))
    torch.testing.assert_close(packed_grads[0], dense_grads[0][where], atol=1e-12, rtol=0)
    torch.testing.assert_close(packed_grads[1], dense_grads[1][where], atol=1e-12, rtol=0)
    assert packed_grads[0].abs().min() > 0


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("opaque", [1e30, math.inf])
def test_transmittance_is_exact_after_huge_optical_depths_and_other_rays_do_not_notice(dtype, opaque):
    optical_depth = torch.tensor([0.5, opaque, 2.0, 0.3, 0.2, opaque, 1.0, 0.7], dtype=dtype)
    ray_indices = torch.tensor([0, 0, 0, 1, 1, 2, 2, 3])
    transmittance = packed_transmittance(optical_depth, ray_indices)
    expected = torch.tensor([1.0, math.exp(-0.5), 0.0, 1.0, math.exp(-0.3), 1.0, 0.0, 1.0], dtype=dtype)
    assert not transmittance.isnan().any()
    torch.testing.assert_close(transmittance, expected, atol=0, rtol=1e-6 if dtype == torch.float32 else 1e-12)
    assert transmittance[2] == 0 and transmittance[6] == 0


def test_an_infinitely_dense_sample_gives_finite_gradients_and_an_opaque_pixel():
    samples = PackedSamples(torch.tensor([0, 0, 0, 1, 1]), torch.tensor([1.0, 1.1, 1.2, 1.0, 1.1]),
                            torch.tensor([1.1, 1.2, 1.3, 1.1, 1.2]))
    sigmas = torch.tensor([0.5, math.inf, 3.0, 0.5, 2.0], requires_grad=True)
    colors = torch.rand(5, 3, requires_grad=True)
    rendered = composite_packed(sigmas, colors, samples, 2, torch.ones(3))
    assert rendered.opacity[0] == 1 and rendered.weights[2] == 0
    torch.testing.assert_close(rendered.opacity[1], torch.tensor(1 - math.exp(-0.25)))
    (rendered.color.sum() + rendered.depth.sum()).backward()
    assert torch.isfinite(colors.grad).all() and torch.isfinite(sigmas.grad).all()


# -- boxes and marching --------------------------------------------------------------------------------


def test_ray_box_intersection_of_a_hit_a_miss_and_a_ray_starting_inside():
    origins = torch.tensor([[-3.0, 0.0, 0.0], [-3.0, 2.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 3.0], [-3.0, -3.0, -3.0]])
    directions = torch.nn.functional.normalize(
        torch.tensor([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 1.0, 1.0]]), dim=-1
    )
    enter, leave = ray_box_intersection(origins, directions, UNIT_BOX)
    root3 = math.sqrt(3)
    hits = [0, 2, 3, 4]
    torch.testing.assert_close(enter[hits], torch.tensor([2.0, -1.0, 2.0, 2 * root3]))
    torch.testing.assert_close(leave[hits], torch.tensor([4.0, 1.0, 4.0, 4 * root3]))
    assert enter[1] >= leave[1]  # passes above the box


def _sphere_grid(resolution=8, radius=0.6):
    """An occupancy grid over the unit box whose occupied cells are those with centres in a ball."""
    grid = OccupancyGrid(UNIT_BOX, resolution)
    axis = (torch.arange(resolution) + 0.5) / resolution * 2 - 1
    x, y, z = torch.meshgrid(axis, axis, axis, indexing="ij")  # the grid's flat order: x major
    grid.occupied.copy_(((x**2 + y**2 + z**2) < radius**2).reshape(-1))
    return grid


def _rays_at_the_box(count, seed=0):
    generator = torch.Generator().manual_seed(seed)
    origins = torch.nn.functional.normalize(torch.randn(count, 3, generator=generator), dim=-1) * 3
    targets = (torch.rand(count, 3, generator=generator) - 0.5) * 1.6
    directions = torch.nn.functional.normalize(targets - origins, dim=-1)
    near = 1.0 + 1.5 * torch.rand(count, generator=generator)  # some rays start inside the box
    far = near + 0.5 + 3 * torch.rand(count, generator=generator)  # some end inside it
    return origins, directions, near, far


@pytest.mark.parametrize("backend", ["eager", "compiled"])
def test_marching_keeps_exactly_the_steps_in_occupied_cells_within_near_far_and_the_box(backend):
    if backend == "compiled" and not compiler_available(torch.device("cpu")):
        pytest.skip("no C++ compiler here for torch.compile")
    grid = _sphere_grid()
    origins, directions, near, far = _rays_at_the_box(40)
    step = 0.05
    samples = march_rays(origins, directions, near, far, grid, step, backend=backend)
    enter, leave = ray_box_intersection(origins, directions, grid.box)
    start, stop = torch.maximum(enter, near), torch.minimum(leave, far)
    for ray in range(len(origins)):
        mine = samples.ray_indices == ray
        # Step by step, as the docstring says: [start + k step, min(start + (k + 1) step, stop)).
        expected = []
        k = 0
        while float(start[ray]) + k * step < float(stop[ray]):
            t0 = start[ray] + k * step
            t1 = torch.minimum(t0 + step, stop[ray])
            if grid.occupied_at(origins[ray] + 0.5 * (t0 + t1) * directions[ray]):
                expected.append((float(t0), float(t1)))
            k += 1
        got = list(zip(samples.t_starts[mine].tolist(), samples.t_ends[mine].tolist()))
        assert len(got) == len(expected), f"ray {ray}"
        if expected:
            torch.testing.assert_close(torch.tensor(got), torch.tensor(expected), atol=1e-5, rtol=0)
    assert 0 < len(samples) < sum(math.ceil(max(float(s), 0) / step) for s in (stop - start))


def test_marched_samples_are_packed_in_increasing_t_inside_the_bounds():
    grid = _sphere_grid()
    origins, directions, near, far = _rays_at_the_box(64, seed=1)
    samples = march_rays(origins, directions, near, far, grid, 0.03, jitter=True,
                         generator=torch.Generator().manual_seed(2))
    rays = samples.ray_indices
    assert len(samples) > 0 and bool((rays[1:] >= rays[:-1]).all())
    same_ray = rays[1:] == rays[:-1]
    assert bool((samples.t_starts[1:][same_ray] >= samples.t_ends[:-1][same_ray] - 1e-6).all())
    assert bool((samples.t_ends > samples.t_starts).all())
    assert bool((samples.t_ends - samples.t_starts <= 0.03 + 1e-6).all())
    assert bool((samples.t_starts >= near[rays] - 1e-6).all() and (samples.t_ends <= far[rays] + 1e-6).all())
    assert bool(grid.occupied_at(samples.midpoints(origins, directions)).all())
    unit = ngp.box_to_unit(samples.midpoints(origins, directions), grid.box)
    assert bool(((unit >= 0) & (unit <= 1)).all())


def test_rays_that_miss_the_box_or_see_only_empty_cells_get_no_samples():
    grid = _sphere_grid()
    origins = torch.tensor([[-3.0, 2.0, 0.0], [-3.0, 0.9, 0.9]])  # misses; crosses only corner cells
    directions = torch.tensor([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    samples = march_rays(origins, directions, torch.full((2,), 0.5), torch.full((2,), 6.0), grid, 0.05)
    assert len(samples) == 0


# -- the occupancy grid --------------------------------------------------------------------------------


def _dense_ball(positions):
    """Density 1000 inside the ball of radius 0.5 about the origin, 0 outside."""
    return torch.where(positions.norm(dim=-1) < 0.5, 1000.0, 0.0)


def _cell_bounds(resolution):
    """Each cell's min and max corner ``(cells, 3)`` over the unit box, in the grid's flat (x-major) order."""
    index = torch.arange(resolution**3)
    cell = torch.stack([index // resolution**2, (index // resolution) % resolution, index % resolution], dim=-1)
    return cell / resolution * 2 - 1, (cell + 1) / resolution * 2 - 1


def test_occupancy_grid_marks_a_dense_ball_occupied_and_the_far_corners_empty_after_warm_up():
    resolution = 16
    grid = OccupancyGrid(UNIT_BOX, resolution, update_every=2, warmup_steps=6)
    assert grid.occupancy == 1.0  # nothing is known to be empty yet
    generator = torch.Generator().manual_seed(0)
    updated = [grid.update(_dense_ball, step, step_size=0.01, generator=generator) for step in range(12)]
    assert updated == [step % 2 == 0 for step in range(12)]
    lower, upper = _cell_bounds(resolution)
    farthest = torch.maximum(lower.abs(), upper.abs()).norm(dim=-1)  # cell point farthest from the origin
    closest = torch.clamp(torch.zeros(3), lower, upper).norm(dim=-1)  # and the closest
    inside_ball, away_from_ball = farthest < 0.5, closest > 0.5
    assert int(inside_ball.sum()) > 0 and int(away_from_ball.sum()) > 0
    assert bool(grid.occupied[inside_ball].all())
    assert not bool(grid.occupied[away_from_ball].any())
    far_corners = torch.tensor([[-0.95, -0.95, -0.95], [0.95, 0.95, 0.95], [0.95, -0.95, 0.95]])
    assert not bool(grid.occupied_at(far_corners).any())
    assert bool(grid.occupied_at(torch.zeros(1, 3)).all())


def test_after_warm_up_only_a_fraction_of_the_cells_is_refreshed():
    grid = OccupancyGrid(UNIT_BOX, 16, decay=0.5, update_every=1, warmup_steps=1, update_fraction=0.25)
    generator = torch.Generator().manual_seed(0)
    grid.update(_dense_ball, 0, step_size=0.01, generator=generator)  # the warm-up step: every cell
    before = grid.density.clone()
    grid.update(lambda positions: torch.zeros(len(positions)), 1, step_size=0.01, generator=generator)
    changed = grid.density != before
    assert 0 < int(changed.sum()) <= 0.25 * 16**3
    refreshed_ball = changed & (before > 0)
    # Refreshed with density 0: the moving maximum decays.
    torch.testing.assert_close(grid.density[refreshed_ball], before[refreshed_ball] * 0.5)


# -- scene boxes ---------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def cube_scene():
    return synthetic_scene("cube", views=12, size=16)


def test_a_synthetic_scene_with_alpha_is_bounded_by_its_aabb(cube_scene):
    box, unbounded = scene_bounds(cube_scene)
    assert unbounded is False
    assert box == [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]]
    assert scene_bounds(cube_scene, "bounded") == (box, False)


def test_photos_without_alpha_are_unbounded_around_where_the_cameras_look(cube_scene):
    frames = [dataclasses.replace(frame, image=frame.image[..., :3]) for frame in cube_scene.frames]
    photos = dataclasses.replace(cube_scene, frames=frames)
    box, unbounded = scene_bounds(photos)
    assert unbounded is True
    box = torch.tensor(box, dtype=torch.float64)
    # Cameras 4 units from the origin, looking at it, field of view 0.6911 rad: half-width
    # 1.1 * 4 * tan(0.6911 / 2).
    torch.testing.assert_close(box.mean(dim=0), torch.zeros(3, dtype=torch.float64), atol=1e-6, rtol=0)
    torch.testing.assert_close(box[1] - box[0], torch.full((3,), 2 * 1.1 * 4 * math.tan(0.6911 / 2),
                                                          dtype=torch.float64), atol=2e-3, rtol=0)
    assert scene_bounds(cube_scene, "unbounded") == (box.tolist(), True)


def test_six_numbers_are_a_bounded_box(cube_scene):
    assert scene_bounds(cube_scene, [-1, -2, -3, 1, 2, 3.5]) == ([[-1.0, -2.0, -3.0], [1.0, 2.0, 3.5]], False)


@pytest.mark.parametrize("scene_box, message", [("everything", "auto, bounded, unbounded or six numbers"),
                                                ([1, 2, 3, 4, 5], "six numbers")])
def test_a_bad_scene_box_is_a_value_error(cube_scene, scene_box, message):
    with pytest.raises(ValueError, match=message):
        scene_bounds(cube_scene, scene_box)


def test_lego_is_bounded_by_a_box_around_the_model(shared_data):
    scene = read_scene(shared_data / "nerf" / "lego_blender")
    box, unbounded = scene_bounds(scene)
    assert unbounded is False
    box = torch.tensor(box, dtype=torch.float64)
    model_extent = torch.tensor([[-0.7, -1.2, -0.4], [0.7, 1.0, 1.1]], dtype=torch.float64)  # lego's bulldozer
    assert bool((box[0] < model_extent[0]).all() and (box[1] > model_extent[1]).all())
    assert bool((box[1] - box[0] < 4).all())


# -- the model -----------------------------------------------------------------------------------------


def _opaque_model():
    """A small bounded model whose field is varied and dense: most rays stop within a few steps."""
    torch.manual_seed(0)
    model = InstantNGP(UNIT_BOX, levels=4, log2_table_size=12, min_resolution=4, max_resolution=32,
                       grid_resolution=16, backend="eager")
    with torch.no_grad():
        model.field.encoding.table.uniform_(-1, 1)
        model.field.density_mlp[2].bias[0] += 5.0
    return model.eval()


def test_early_termination_does_not_change_the_render(monkeypatch):
    model = _opaque_model()
    origins, directions, near, far = _rays_at_the_box(256, seed=3)
    far = far + 4
    background = torch.tensor([0.3, 0.6, 0.9])
    with torch.no_grad():
        early = model(origins, directions, near, far, background)[0]
        early_samples = model.last_samples
        monkeypatch.setattr(ngp, "EARLY_STOP_TRANSMITTANCE", 0.0)
        full = model(origins, directions, near, far, background)[0]
        full_samples = model.last_samples
    assert early_samples < 0.5 * full_samples  # it did stop rays early
    assert float(early.opacity.max()) > 0.999
    for name in ("color", "opacity"):
        torch.testing.assert_close(getattr(early, name), getattr(full, name), atol=1e-3, rtol=0, msg=name)
    hit = full.opacity > 0.5
    torch.testing.assert_close(early.depth[hit], full.depth[hit], atol=1e-3, rtol=1e-3)


def test_a_render_reusing_the_probe_pass_equals_one_that_evaluates_the_field_again():
    # Without gradients the kept samples' density and features come from the early-termination
    # probe; with them, the field runs again on those samples. The pixels must not differ.
    model = _opaque_model()
    origins, directions, near, far = _rays_at_the_box(128, seed=6)
    background = torch.tensor([0.3, 0.6, 0.9])
    with torch.no_grad():
        reused = model(origins, directions, near, far + 4, background)[0]
    again = model(origins, directions, near, far + 4, background)[0]
    assert again.color.requires_grad
    for name in ("color", "opacity", "depth"):
        torch.testing.assert_close(getattr(reused, name), getattr(again, name).detach(), atol=1e-5, rtol=1e-5)


def test_the_ray_budget_adapts_so_that_a_step_processes_about_the_target_samples():
    model = _opaque_model().train()
    model.target_samples = 4096
    origins, directions, near, far = _rays_at_the_box(1 << 14, seed=4)
    samples = []
    for _ in range(14):  # the budget is smoothed: it halves its distance to the target per step
        rays = model.rays_for_next_step(smallest=16)
        model(origins[:rays], directions[:rays], near[:rays], far[:rays] + 4)
        samples.append(model.last_cost)
    assert abs(samples[0] - 4096) > 1500  # the first guess (1024 rays) was far off
    assert all(0.7 * 4096 < count < 1.4 * 4096 for count in samples[-3:]), samples


def test_unbounded_interlevel_loss_trains_the_proposal_networks_only():
    torch.manual_seed(0)
    model = InstantNGP(UNIT_BOX, unbounded=True, levels=4, log2_table_size=12, max_resolution=64,
                       backend="eager", proposal_samples=(32, 16), field_samples=16).train()
    origins, directions, _, _ = _rays_at_the_box(64, seed=5)
    rendered = model(origins, directions, torch.full((64,), 0.1), torch.full((64,), 6.0), torch.ones(3), jitter=True)
    auxiliary = model.auxiliary_loss()
    assert auxiliary is not None and bool(torch.isfinite(auxiliary)) and float(auxiliary.detach()) > 0
    auxiliary.backward()
    assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in model.proposal.parameters())
    assert all(p.grad is None or p.grad.abs().sum() == 0 for p in model.field.parameters())
    assert rendered[0].color.shape == (64, 3) and bool(torch.isfinite(rendered[0].color).all())


# -- training --------------------------------------------------------------------------------------


# A thick start (e^2 across the box): this small, coarse cube lets a thinner one (the default
# 1.2) lose its colour network before density forms -- measured: 16.0 dB at step 60 with 1.2,
# 21.4 dB with e^2.
NGP_OPTIONS = {"backend": "eager", "levels": 8, "log2_table_size": 14, "max_resolution": 128, "target_samples": 8192,
               "initial_optical_depth": 7.4}
CUBE = dict(model="ngp", cube_views=24, cube_size=32, device="cpu", progress=False, model_options=NGP_OPTIONS)
TRAIN_STEPS = 120


@pytest.fixture(scope="module")
def ngp_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("ngp") / "run"
    metrics = train(None, out=out, steps=TRAIN_STEPS, eval_every=TRAIN_STEPS // 2, **CUBE)
    return out, metrics


def test_ngp_learns_the_cube(ngp_run):
    # A healthy run reaches about 22 dB held-out here (30 dB on its training views); a run whose
    # colour network has died renders the silhouette only, about 17 dB.
    _, metrics = ngp_run
    assert metrics["psnr"] > 19, metrics


def test_ngp_run_folder_holds_metrics_and_a_checkpoint(ngp_run):
    out, metrics = ngp_run
    for name in ("config.json", "metrics.jsonl", "metrics.json", "checkpoints/last.pt"):
        assert (out / name).is_file(), name
    records = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in records] == [TRAIN_STEPS // 2, TRAIN_STEPS]
    assert all(r["train_rays"] >= 256 and r["train_samples_per_ray"] > 0 for r in records)
    config = json.loads((out / "config.json").read_text())
    assert config["model_options"]["box"] == [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]]
    assert config["model_options"]["unbounded"] is False
    assert json.loads((out / "metrics.json").read_text())["steps"] == TRAIN_STEPS


def test_ngp_run_resumes_to_more_steps(ngp_run, tmp_path):
    out = tmp_path / "resumed"
    shutil.copytree(ngp_run[0], out)
    before = (out / "metrics.jsonl").read_text().splitlines()
    metrics = train(None, out=out, resume=True, steps=TRAIN_STEPS + 10, eval_every=TRAIN_STEPS // 2, **CUBE)
    assert metrics["steps"] == TRAIN_STEPS + 10
    after = (out / "metrics.jsonl").read_text().splitlines()
    assert after[:2] == before and json.loads(after[2])["step"] == TRAIN_STEPS + 10
    # Ten more steps from the checkpoint, not from scratch: about where the run was.
    assert metrics["psnr"] > ngp_run[1]["psnr"] - 1.5


def test_ngp_run_evaluates_and_renders_from_the_command_line(ngp_run, tmp_path, capsys):
    out, metrics = ngp_run
    assert main(["nerf", "eval", str(out), "--json", "--device", "cpu"]) == 0
    scores = json.loads(capsys.readouterr().out)
    assert scores["model"] == "ngp" and scores["psnr"] == pytest.approx(metrics["psnr"], abs=1e-3)
    gif = tmp_path / "orbit.gif"
    assert main(["nerf", "render", str(out), "--frames", "3", "--out", str(gif), "--device", "cpu"]) == 0
    import imageio.v3 as iio

    frames = iio.imread(gif, index=None)
    assert frames.shape[0] == 3 and frames.shape[2] == 3 * 32  # colour | depth | opacity


def test_unbounded_ngp_trains_a_few_steps_with_a_finite_interlevel_loss(tmp_path):
    options = {**NGP_OPTIONS, "unbounded": True, "levels": 4, "log2_table_size": 12,
               "proposal_samples": [32, 16], "field_samples": 16, "target_samples": 2048}
    metrics = train(None, out=tmp_path / "run", steps=4, eval_every=2,
                    **{**CUBE, "cube_views": 12, "cube_size": 16, "model_options": options})
    records = [json.loads(line) for line in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert len(records) == 2
    assert all(math.isfinite(r["train_auxiliary_loss"]) and r["train_auxiliary_loss"] >= 0 for r in records)
    assert json.loads((tmp_path / "run" / "config.json").read_text())["model_options"]["unbounded"] is True
    assert math.isfinite(metrics["psnr"])


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
@pytest.mark.parametrize("unbounded", [False, True])
def test_the_fast_field_gives_the_same_renders_and_gradients_on_cuda_as_on_cpu(unbounded):
    torch.manual_seed(0)
    model = InstantNGP(UNIT_BOX, unbounded=unbounded, levels=4, log2_table_size=12, min_resolution=4,
                       max_resolution=32, backend="eager")
    with torch.no_grad():  # a field with structure, not the near-constant initial one
        model.field.encoding.table.normal_(0, 0.5)
    origins, directions, near, far = _rays_at_the_box(256, seed=3)
    results = {}
    for device in ("cpu", "cuda"):
        copy = InstantNGP(UNIT_BOX, unbounded=unbounded, levels=4, log2_table_size=12, min_resolution=4,
                          max_resolution=32, backend="eager").to(device)
        copy.load_state_dict(model.state_dict())
        copy.eval()  # the occupancy grid stays all occupied: the same samples on both devices
        rays = [t.to(device) for t in (origins, directions, near, far)]
        rendered = copy(*rays, background=torch.ones(3, device=device))[-1]
        rendered.color.sum().backward()
        results[device] = (rendered.color.detach().cpu(), rendered.opacity.detach().cpu(),
                           copy.field.encoding.table.grad.cpu())
    for name, on_cpu, on_cuda in zip(("colour", "opacity", "table gradient"), results["cpu"], results["cuda"]):
        torch.testing.assert_close(on_cuda, on_cpu, atol=1e-4, rtol=1e-3, msg=name)
