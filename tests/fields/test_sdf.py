"""The neural SDF field (``nerf train --model sdf``) and its zero-level mesh (``nerf export --mesh``)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

import pointfield
from pointfield.cli import main
from pointfield.clouds.formats.registry import read
from pointfield.errors import PointfieldError
from pointfield.fields.encodings.hashgrid import HashEncoding, reference_hash_encoding
from pointfield.fields.models import build_model
from pointfield.fields.rays import RayBundle
from pointfield.fields.sampling.occupancy import march_rays
from pointfield.fields.sdf import MIN_WEIGHT, NeuralSDF, first_of_ray, tetrahedral_gradient
from pointfield.fields.train import train
from pointfield.geometry import export_mesh
from pointfield.geometry.compare import sample_mesh, surface_scores
from pointfield.volumes.voxels import mesh_openness

pytestmark = pytest.mark.usefixtures("one_torch_thread")  # small models: steadier on busy cores

SMALL = {"backend": "eager", "levels": 8, "log2_table_size": 14, "max_resolution": 128, "grid_resolution": 32}


def cube_surface(count: int) -> np.ndarray:
    """Uniform samples of the synthetic cube's surface (side 1, centred at the origin)."""
    generator = np.random.default_rng(0)
    face = generator.integers(0, 6, count)
    points = generator.uniform(-0.5, 0.5, (count, 3))
    points[np.arange(count), face // 2] = np.where(face % 2 == 0, 0.5, -0.5)
    return points


def _directions(count: int, seed: int = 0) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    return torch.nn.functional.normalize(torch.randn(count, 3, generator=generator), dim=-1)


# -- the field --------------------------------------------------------------------------------------


@pytest.mark.parametrize("gradient", ["finite-difference", "autograd"])
def test_the_untrained_field_is_the_signed_distance_of_a_sphere(gradient):
    torch.manual_seed(0)
    model = NeuralSDF(sphere_radius=0.5, gradient=gradient, **SMALL)
    directions = _directions(2000)
    for radius in (0.3, 0.5, 0.8):
        f, gradient, _ = model.sdf_and_gradient(directions * radius, create_graph=False)
        # Measured: within 0.02 of |p| - 0.5 at 90 % of the points, |grad f| within 4 % of 1.
        assert float((f - (radius - 0.5)).abs().quantile(0.9)) < 0.05, radius
        norms = gradient.norm(dim=-1)
        assert abs(float(norms.mean()) - 1) < 0.1 and float((norms - 1).abs().median()) < 0.1, radius
        # ... and the gradient points outwards, along the radius.
        assert float((torch.nn.functional.normalize(gradient, dim=-1) * directions).sum(-1).mean()) > 0.95


def test_hash_encoding_gives_positions_the_gradient_of_its_interpolation():
    # Before the SDF field, positions got no gradient at all (the hand-written backward returns none).
    encoding = HashEncoding(levels=4, features_per_level=2, log2_table_size=10, min_resolution=4,
                            max_resolution=32, backend="auto").double()
    with torch.no_grad():
        encoding.table.normal_()
    points = torch.rand(64, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    weights = torch.randn(encoding.output_dim, dtype=torch.float64)
    ours = points.clone().requires_grad_(True)
    (encoding(ours) @ weights).sum().backward()
    reference = points.clone().requires_grad_(True)
    (reference_hash_encoding(encoding, reference) @ weights).sum().backward()
    assert ours.grad.abs().sum() > 0
    torch.testing.assert_close(ours.grad, reference.grad)


def test_tetrahedral_differences_give_the_gradient_of_an_analytic_sphere_sdf():
    points = torch.rand(4096, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0)) * 2 - 1
    points = points[points.norm(dim=-1) > 0.1]

    def sphere(p):
        return p.norm(dim=-1) - 0.5, p.norm(dim=-1, keepdim=True)

    f, gradient, features = tetrahedral_gradient(sphere, points, 1e-3)
    exact = points / points.norm(dim=-1, keepdim=True)
    # The error is the step times the Hessian (1 / |p| <= 10 here): at most 1e-2, mostly far less.
    assert float((gradient - exact).norm(dim=-1).max()) < 1e-2
    assert float((gradient - exact).norm(dim=-1).median()) < 2e-3
    torch.testing.assert_close(f, points.norm(dim=-1) - 0.5, atol=1e-5, rtol=0)
    torch.testing.assert_close(features[:, 0], points.norm(dim=-1), atol=1e-5, rtol=0)
    # No points (a batch whose rays all miss the surface's cells): empty results, not an error.
    f, gradient, features = tetrahedral_gradient(sphere, points[:0], 1e-3)
    assert f.shape == (0,) and gradient.shape == (0, 3) and features.shape == (0, 1)


def test_finite_difference_normals_match_autograd_normals_of_the_network():
    torch.manual_seed(0)
    model = NeuralSDF(gradient="autograd", **SMALL)
    with torch.no_grad():  # some hash-grid detail, as after training
        model.sdf.first.weight[:, 3:].normal_(0, 0.1)
        model.sdf.encoding.table.normal_(0, 0.05)
    points = _directions(2000) * 0.5
    _, exact, _ = model.sdf_and_gradient(points, create_graph=False)
    model.gradient, model.finite_difference_step = "finite-difference", 1e-4
    _, numerical, _ = model.sdf_and_gradient(points, create_graph=False)
    cosines = torch.nn.functional.cosine_similarity(numerical, exact, dim=-1)
    # Well inside the finest cells (1/64 of the box's half-side here) the two agree; the few
    # tetrahedra that straddle a cell's face see the trilinear grid's kink there.
    assert float(cosines.median()) > 0.9999 and float(cosines.quantile(0.05)) > 0.99, cosines.quantile(0.05)


@pytest.mark.parametrize("gradient", ["finite-difference", "autograd"])
def test_the_eikonal_term_reaches_the_hash_table(gradient):
    model = NeuralSDF(gradient=gradient, **SMALL)
    with torch.no_grad():  # as after some training: hash features in use
        model.sdf.first.weight[:, 3:].normal_(0, 0.1)
        model.sdf.encoding.table.normal_(0, 0.1)
    _, gradient, _ = model.sdf_and_gradient(torch.rand(512, 3) * 2 - 1, create_graph=True)
    ((gradient.norm(dim=-1) - 1) ** 2).mean().backward()
    assert model.sdf.encoding.table.grad.abs().sum() > 0
    assert model.sdf.first.weight.grad.abs().sum() > 0


def test_neus_alphas_composite_to_the_logistic_cdf_across_a_plane():
    # NeuS's unbiased opacity: along a ray entering the plane f = z head on, the transmittance
    # after any run of sections is Phi_s(f at its end) / Phi_s(f at its start), however they are cut.
    model = NeuralSDF(**SMALL)
    edges = torch.sort(torch.rand(40, generator=torch.Generator().manual_seed(1)) * 0.8 - 0.4).values
    deltas = edges[1:] - edges[:-1]
    middles = 0.5 * (edges[1:] + edges[:-1])
    f = -middles  # the ray runs down z through the plane z = 0: f = z = -t
    gradient = torch.tensor([[0.0, 0.0, 1.0]]).expand(len(f), 3)
    directions = torch.tensor([[0.0, 0.0, -1.0]]).expand(len(f), 3)
    alphas = model.alphas(f, gradient, directions, deltas).detach()
    s = float(model.sharpness.detach())
    expected = torch.sigmoid(torch.tensor(s * -float(edges[-1]))) / torch.sigmoid(torch.tensor(s * -float(edges[0])))
    assert float(torch.prod(1 - alphas)) == pytest.approx(float(expected), abs=1e-3)
    # Leaving a surface (the ray going up, out of the solid) absorbs nothing.
    assert float(model.alphas(f, gradient, -directions, deltas).detach().max()) == 0


def test_the_cosine_anneal_lets_every_section_absorb_at_first_and_ends_in_neus_alpha():
    # NeuS's cos_anneal_ratio: at step 0 a section absorbs whichever way the ray crosses the
    # surface (cos averaged over the half-sphere); from cos_anneal_steps on, only entering ones.
    model = NeuralSDF(cos_anneal_steps=100, **SMALL)
    f = torch.linspace(0.2, -0.2, 20)
    gradient = torch.tensor([[0.0, 0.0, 1.0]]).expand(20, 3)
    leaving = torch.tensor([[0.75 ** 0.5, 0.0, 0.5]]).expand(20, 3)  # 60 degrees off the gradient: out of the solid
    deltas = torch.full((20,), 0.02)
    model.before_step(0)
    assert float(model.alphas(f, gradient, leaving, deltas).detach().max()) > 0.05
    model.before_step(100)
    assert float(model.alphas(f, gradient, leaving, deltas).detach().max()) == 0
    assert NeuralSDF(**SMALL).cos_anneal_steps == 0  # off unless asked for


def test_a_ray_that_enters_the_box_inside_the_solid_meets_the_surface_at_the_wall():
    # The box's outside is free space (the exported mesh is closed there), so a ray whose first
    # section starts at negative distance crosses the surface at its start: opaque at once, as
    # the mesh would show it. NeuS's ratio Phi_s(end) / Phi_s(start) alone makes such a section
    # nearly transparent (both CDFs near 0), which rewarded levels pushed out past the box's walls.
    model = NeuralSDF(**SMALL)
    f = torch.tensor([-0.5, -0.52, -0.54])  # deep inside from the first sample on, falling along the ray
    gradient = torch.tensor([[0.0, 0.0, 1.0]]).expand(3, 3)
    directions = torch.tensor([[0.0, 0.0, -1.0]]).expand(3, 3)
    deltas = torch.full((3,), 0.02)
    first = torch.tensor([True, False, False])
    alphas = model.alphas(f, gradient, directions, deltas, first).detach()
    assert float(alphas[0]) > 0.99
    assert float(model.alphas(f, gradient, directions, deltas).detach()[0]) < 0.5  # NeuS's ratio alone
    # A first section in free space is NeuS's own.
    outside = f + 1.0
    assert torch.allclose(model.alphas(outside, gradient, directions, deltas, first),
                          model.alphas(outside, gradient, directions, deltas))


def test_the_sdf_networks_and_sharpness_learn_at_a_tenth_of_the_hash_tables_rate():
    # Adam moves the SDF network's last bias (a global offset of f) by about its rate a step: at the
    # table's 1e-2 the level set drifted past the cube's faces to the box's walls (measured).
    model = NeuralSDF(**SMALL)
    table, networks = model.parameter_groups(1e-2)
    assert table["params"] == [model.sdf.encoding.table] and table["lr"] == 1e-2
    assert networks["lr"] == pytest.approx(1e-3)
    assert any(p is model.variance for p in networks["params"]) and any(p is model.sdf.last.bias for p in networks["params"])
    assert len(networks["params"]) == len(list(model.parameters())) - 1


def test_the_sharpness_can_learn_at_a_rate_of_its_own():
    model = NeuralSDF(sharpness_lr_fraction=1.0, **SMALL)
    table, networks, sharpness = model.parameter_groups(1e-2)
    assert sharpness["params"] == [model.variance] and sharpness["lr"] == pytest.approx(1e-2)
    assert networks["lr"] == pytest.approx(1e-3) and all(p is not model.variance for p in networks["params"])
    assert len(table["params"]) + len(networks["params"]) + 1 == len(list(model.parameters()))


def test_an_sdf_run_from_before_the_two_rates_and_the_skipping_resumes_as_it_was_trained(tmp_path):
    options = {**CUBE, "cube_views": 4, "cube_size": 16}
    assert train(None, out=tmp_path / "new", steps=1, **options)["steps"] == 1
    assert json.loads((tmp_path / "new" / "config.json").read_text())["model_options"]["min_weight"] == MIN_WEIGHT
    first = train(None, out=tmp_path / "run", steps=1, **{**options, "model_options": {
        **options["model_options"], "network_lr_fraction": 1.0, "min_weight": 0.0}})  # as such a run trained
    config_path = tmp_path / "run" / "config.json"
    config = json.loads(config_path.read_text())
    del config["model_options"]["network_lr_fraction"]  # the options did not exist then
    del config["model_options"]["min_weight"]
    config_path.write_text(json.dumps(config))
    resumed = train(None, out=tmp_path / "run", steps=2, resume=True, **options)
    assert resumed["steps"] == 2 and first["steps"] == 1
    options_now = json.loads(config_path.read_text())["model_options"]
    assert options_now["network_lr_fraction"] == 1.0 and options_now["min_weight"] == 0.0  # as it was trained


def test_early_termination_drops_only_samples_that_cannot_change_a_pixel(monkeypatch):
    torch.manual_seed(0)
    # s = e^5: a sharp sphere of radius 0.75; early termination alone (no faint sections skipped)
    model = NeuralSDF(initial_variance=0.5, min_weight=0.0, **SMALL).eval()
    directions = _directions(256, seed=3)
    origins = -4.0 * directions + 0.3 * torch.randn(256, 3, generator=torch.Generator().manual_seed(4))
    rays = RayBundle(origins, directions, torch.zeros(256), torch.full((256,), 8.0))
    with torch.no_grad():
        marched = march_rays(rays, model.grid, model.step_size)
        kept_samples, _ = model.terminated(marched, rays)
        (kept,) = model(rays).passes
        monkeypatch.setattr(model, "terminated", lambda samples, rays: (samples, first_of_ray(samples.ray_indices)))
        (everything,) = model(rays).passes
    assert float((kept.color - everything.color).abs().max()) < 1e-3
    assert float((kept.opacity - everything.opacity).abs().max()) < 1e-3
    assert float(everything.opacity.max()) > 0.99  # rays that do meet the sphere
    # The full occupancy grid of an untrained field marches through the whole sphere: most of it goes.
    assert len(kept_samples) < 0.6 * len(marched), (len(kept_samples), len(marched))


def test_skipping_faint_sections_lets_a_step_afford_more_rays_for_the_same_picture():
    # The sphere of s = e^5 as above: its logistic tail in front of the surface is marched (the
    # occupancy band) but carries almost no weight; the full field (four evaluations and a backward
    # each) runs only where the weight is.
    rays_directions = _directions(256, seed=3)
    origins = -4.0 * rays_directions + 0.3 * torch.randn(256, 3, generator=torch.Generator().manual_seed(4))
    rays = RayBundle(origins, rays_directions, torch.zeros(256), torch.full((256,), 8.0))
    outputs = {}
    for min_weight in (0.0, 1e-3):
        torch.manual_seed(0)
        model = NeuralSDF(initial_variance=0.5, min_weight=min_weight, **SMALL).eval()
        with torch.no_grad():
            outputs[min_weight] = model(rays)
    (everything,), (skipped,) = outputs[0.0].passes, outputs[1e-3].passes
    assert outputs[1e-3].samples < 0.7 * outputs[0.0].samples, (outputs[1e-3].samples, outputs[0.0].samples)
    assert float((skipped.color - everything.color).abs().max()) < 0.02
    assert float((skipped.opacity - everything.opacity).abs().max()) < 0.02
    with pytest.raises(ValueError, match="min_weight"):
        NeuralSDF(min_weight=1.0, **SMALL)


def test_the_sdf_model_refuses_an_unbounded_scene():
    with pytest.raises(ValueError, match="bounded"):
        build_model("sdf", unbounded=True)


# -- training on the cube and the mesh of its zero level -----------------------------------------------

CUBE = dict(model="sdf", cube_views=24, cube_size=32, device="cpu", progress=False,
            model_options={**SMALL, "target_samples": 4096})
TRAIN_STEPS = 240


@pytest.fixture(scope="module")
def sdf_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sdf")
    start = train(None, out=folder / "start", steps=1, **CUBE)
    metrics = train(None, out=folder / "run", steps=TRAIN_STEPS, eval_every=TRAIN_STEPS // 3, **CUBE)
    return folder / "run", metrics, start


def test_sdf_learns_the_cube(sdf_run):
    # Measured: 24.5 dB held out after 240 steps, 12 dB after one (a grey sphere).
    out, metrics, start = sdf_run
    records = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert records[-1]["train_loss"] < 0.5 * records[0]["train_loss"]
    assert all(math.isfinite(r["train_auxiliary_loss"]) for r in records)  # the eikonal term, logged
    assert metrics["psnr"] > start["psnr"] + 6, (metrics["psnr"], start["psnr"])
    config = json.loads((out / "config.json").read_text())
    assert config["model"] == "sdf" and config["model_options"]["unbounded"] is False


def test_an_sdf_run_renders_colour_depth_and_opacity_like_the_other_fields(sdf_run):
    run = pointfield.load_run(sdf_run[0], device="cpu")
    cameras = run.scene.cameras[[0]]
    (view,) = run.render(cameras, outputs=("rgb", "depth", "opacity"))
    assert view["rgb"].shape == (32, 32, 3) and view["depth"].shape == view["opacity"].shape == (32, 32)
    # The cube in the middle of the picture, nothing at the corners.
    assert float(view["opacity"][16, 16]) > 0.95 and float(view["opacity"][0, 0]) < 0.05
    assert 3.0 < float(view["depth"][16, 16]) < 4.0  # the camera is 4 from the centre, the cube's faces 0.5


def test_the_exported_mesh_is_one_watertight_surface_near_the_cube(sdf_run, tmp_path):
    out = tmp_path / "cube.ply"
    summary = export_mesh(sdf_run[0], out, resolution=64, device="cpu", progress=False)
    assert summary["watertight"] and summary["openness"]["boundary"] == 0
    mesh = read(out)
    openness = mesh_openness(mesh)
    assert openness["boundary"] == 0 and openness["nonmanifold"] == 0
    # Coloured by the faces the views saw, not the grey of a colour ray that met nothing.
    colours = mesh.fields["colors"].astype(np.int64)
    assert (np.abs(colours - 128).max(axis=1) > 40).mean() > 0.9
    diagonal = math.sqrt(3)
    # bench_geometry's Chamfer: the mean of accuracy and completeness, over the cube's diagonal.
    scores = surface_scores(sample_mesh(mesh, 50_000), cube_surface(100_000), 0.01 * diagonal, unit=diagonal)
    # Measured 3.0 % of the diagonal at 32 x 32 pixels (half a pixel's footprint at the cube); the
    # untrained field's sphere of radius 0.3 scores about 15 %.
    assert scores["chamfer_relative"] < 0.045, scores


def test_nerf_export_meshes_an_sdf_run_from_the_command_line(sdf_run, tmp_path, capsys):
    out = tmp_path / "cube.ply"
    assert main(["nerf", "export", str(sdf_run[0]), "--mesh", str(out), "--resolution", "32", "--device", "cpu",
                 "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "SDF zero level" in printed and "closed (every edge shared by two faces)" in printed
    assert out.is_file()
    with pytest.raises(PointfieldError, match="threshold"):
        export_mesh(sdf_run[0], tmp_path / "other.ply", threshold=1.0, device="cpu", progress=False)
    assert not (tmp_path / "other.ply").exists()


def test_method_sdf_refuses_a_run_of_another_model(tmp_path):
    run = tmp_path / "tiny"
    train(None, model="tiny", out=run, steps=2, cube_views=6, cube_size=16, device="cpu", progress=False,
          model_options={"samples": 8})
    with pytest.raises(PointfieldError, match="--model sdf"):
        export_mesh(run, tmp_path / "mesh.ply", method="sdf", device="cpu", progress=False)

