"""Densification, the loss, and training / rendering / exporting runs (tiny scenes, few steps)."""

import json

import numpy as np
import pytest
import torch
from splat_strategy import model_and_optimizer, training_steps

from pointfield.cli import main
from pointfield.errors import PointfieldError
from pointfield.metrics import ssim
from pointfield.scenes import make_scene
from pointfield.splats.densification import DefaultStrategy
from pointfield.splats.gaussians import PARAMETER_NAMES
from pointfield.splats.loss import flatness, opacity_entropy, splat_loss
from pointfield.splats.ply import read_splats
from pointfield.splats.rasterizer import rasterization
from pointfield.splats.train import train


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory):
    return make_scene("cube", tmp_path_factory.mktemp("scenes") / "cube", views=6, size=24)


def test_loss_is_the_3dgs_mix_of_l1_and_the_metrics_ssim():
    generator = torch.Generator().manual_seed(0)
    a = torch.rand(20, 17, 3, generator=generator, dtype=torch.float64)
    b = (a + 0.1 * torch.rand(20, 17, 3, generator=generator, dtype=torch.float64)).clamp(0, 1)
    expected = 0.8 * float((a - b).abs().mean()) + 0.2 * (1 - float(ssim(a, b)))
    assert float(splat_loss(a, b)) == pytest.approx(expected, abs=1e-12)
    a.requires_grad_()
    splat_loss(a, b).backward()
    assert torch.isfinite(a.grad).all() and a.grad.abs().sum() > 0


def test_loss_is_zero_for_equal_images():
    image = torch.rand(16, 16, 3)
    assert float(splat_loss(image, image)) == pytest.approx(0, abs=1e-6)


def test_opacity_entropy_is_zero_for_decided_splats_and_log_two_at_one_half():
    assert float(opacity_entropy(torch.tensor([0.0, 1.0, 0.0]))) == pytest.approx(0, abs=1e-4)
    assert float(opacity_entropy(torch.tensor([0.5, 0.5]))) == pytest.approx(np.log(2), abs=1e-6)
    opacities = torch.tensor([0.3, 0.8], requires_grad=True)
    opacity_entropy(opacities).backward()
    assert opacities.grad[1] < 0 < opacities.grad[0]  # descent takes 0.3 towards 0, 0.8 towards 1


def test_flatness_is_the_mean_smallest_scale_in_scene_units():
    scales = torch.tensor([[0.2, 0.01, 0.3], [0.5, 0.4, 0.1]])
    assert float(flatness(scales, scene_scale=2.0)) == pytest.approx((0.01 + 0.1) / 2 / 2.0)


def geometry_of_a_short_run(scene, out, **weights):
    """Opacity entropy and the smallest scale over the scale of its splats after a short run."""
    train(scene, out=out, steps=80, eval_every=80, initial_splats=300, progress=False, **weights)
    gaussians = torch.load(out / "checkpoints" / "last.pt", weights_only=True)["model"]
    opacities = torch.sigmoid(gaussians["opacity_logits"])
    scales = torch.exp(gaussians["log_scales"]).sort(dim=1).values
    return float(opacity_entropy(opacities)), float((scales[:, 0] / scales[:, 1]).median())


def test_the_geometry_terms_make_splats_opaque_or_gone_and_flat(tiny_scene, tmp_path):
    # Weights far above the measured ones make 80 steps enough to see the terms act. Adam moves a
    # log-scale about its learning rate a step, so 40 steps could only just reach the 0.8 asked.
    off = geometry_of_a_short_run(tiny_scene, tmp_path / "off", opacity_entropy=0.0, flatness=0.0)
    on = geometry_of_a_short_run(tiny_scene, tmp_path / "on", opacity_entropy=1.0, flatness=50.0)
    assert on[0] < 0.8 * off[0], f"opacity entropy {on[0]:.3f} with the term, {off[0]:.3f} without"
    assert on[1] < 0.8 * off[1], f"smallest / middle scale {on[1]:.3f} with the term, {off[1]:.3f} without"


def test_densification_grows_and_keeps_the_optimizer_in_step():
    gaussians, optimizer = model_and_optimizer()
    strategy = DefaultStrategy(refine_start=1, refine_every=2, grad_threshold=1e-7, reset_every=1000)
    training_steps(gaussians, optimizer, strategy, 4)
    assert len(gaussians) > 100
    for name in PARAMETER_NAMES:
        parameter = getattr(gaussians, name)
        assert optimizer.state[parameter]["exp_avg"].shape == parameter.shape
        assert any(parameter is p for group in optimizer.param_groups for p in group["params"])


def test_the_cap_stops_densification_with_a_message():
    messages = []
    gaussians, optimizer = model_and_optimizer()
    strategy = DefaultStrategy(refine_start=1, refine_every=2, grad_threshold=1e-7, max_splats=130,
                               reset_every=1000, log=messages.append)
    training_steps(gaussians, optimizer, strategy, 6)
    assert len(gaussians) == 130
    assert len(messages) == 1 and "splat cap of 130 reached" in messages[0] and "--max-splats" in messages[0]


def test_pruning_removes_transparent_splats_and_reset_lowers_opacity():
    gaussians, optimizer = model_and_optimizer(10)
    with torch.no_grad():
        gaussians.opacity_logits[:3] = -10.0
    strategy = DefaultStrategy(refine_start=0, refine_every=1, grad_threshold=1e9, reset_every=2)
    training_steps(gaussians, optimizer, strategy, 3)
    assert len(gaussians) == 7
    assert float(gaussians.opacities.detach().max()) <= 0.011


def test_sh_degree_rises_on_schedule():
    strategy = DefaultStrategy(sh_degree_interval=100)
    assert [strategy.sh_degree_at(s, 3) for s in (0, 99, 100, 250, 10_000)] == [0, 0, 1, 2, 3]


def test_train_writes_a_run_and_resumes_it(tiny_scene, tmp_path):
    out = tmp_path / "run"
    metrics = train(tiny_scene, out=out, steps=6, eval_every=3, initial_splats=300, progress=False)
    assert metrics["steps"] == 6 and np.isfinite(metrics["psnr"])
    records = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in records] == [3, 6]
    assert {"config.json", "metrics.json", "checkpoints", "heldout"} <= {p.name for p in out.iterdir()}
    resumed = train(tiny_scene, out=out, steps=9, resume=True, progress=False)
    assert resumed["steps"] == 9
    with pytest.raises(PointfieldError, match="already holds a run"):
        train(tiny_scene, out=out, steps=3, progress=False)


def test_new_runs_default_to_the_mip_filters_and_older_runs_keep_their_settings(tiny_scene, tmp_path):
    import pointfield
    from pointfield.scenes.heldout import training_and_heldout
    from pointfield.splats.mip import SMOOTHING, training_smoothing
    from pointfield.splats.train import DEFAULT_MIP_SMOOTHING

    out = tmp_path / "new"
    train(tiny_scene, out=out, steps=2, eval_every=2, initial_splats=100, progress=False)
    config = json.loads((out / "config.json").read_text())
    assert (config["mip"], config["antialiased"], config["screen_dilation"]) == (True, True, 0.1)
    assert config["mip_smoothing"] == DEFAULT_MIP_SMOOTHING and not config["opacity_entropy"]
    assert pointfield.load_run(out, "cpu").gaussians.smoothing is not None
    # A mip run made before the 3D filter's strength was recorded was trained with Mip-Splatting's 0.2.
    del config["mip_smoothing"]
    (out / "config.json").write_text(json.dumps(config))
    run = pointfield.load_run(out, "cpu")
    expected = training_smoothing(run.gaussians, run.scene.cameras[training_and_heldout(run.scene)[0]], SMOOTHING)
    assert float(expected.min()) > 0 and torch.equal(run.gaussians.smoothing, expected)
    # A run made before the defaults has none of their keys: resumed and loaded, it stays as trained.
    for key in ("mip", "antialiased", "screen_dilation"):
        del config[key]
    (out / "config.json").write_text(json.dumps(config))
    train(tiny_scene, out=out, steps=4, resume=True, progress=False)
    resumed = json.loads((out / "config.json").read_text())
    assert not resumed.get("mip") and not resumed.get("antialiased")
    run = pointfield.load_run(out, "cpu")
    assert run.gaussians.smoothing is None and run.config.get("screen_dilation", 0.3) == 0.3
    # From the command line, --no-mip trains classic 3DGS.
    assert main(["splat", "train", str(tiny_scene), "--out", str(tmp_path / "classic"), "--steps", "2",
                 "--initial-splats", "100", "--no-mip", "--no-progress"]) == 0
    classic = json.loads((tmp_path / "classic" / "config.json").read_text())
    assert (classic["mip"], classic["antialiased"], classic["screen_dilation"]) == (False, False, 0.3)


def test_commands_train_export_and_render(tiny_scene, tmp_path, capsys):
    run, ply, frames = tmp_path / "run", tmp_path / "s.ply", tmp_path / "frames"
    assert main(["splat", "train", str(tiny_scene), "--out", str(run), "--steps", "4",
                 "--initial-splats", "200", "--max-splats", "500", "--no-progress"]) == 0
    assert main(["splat", "export", str(run), "--out", str(ply)]) == 0
    assert len(read_splats(ply)) == json.loads((run / "metrics.json").read_text())["splats"]
    assert main(["splat", "render", str(run), "--path", "dataset", "--frames", "2", "--out", str(frames)]) == 0
    assert (frames / "color_001.png").is_file()
    assert main(["splat", "render", str(ply), "--scene", str(tiny_scene), "--path", "orbit",
                 "--frames", "2", "--out", str(tmp_path / "orbit.gif")]) == 0
    assert (tmp_path / "orbit.gif").stat().st_size > 0
    assert main(["splat", "render", str(ply), "--out", str(tmp_path / "x.gif")]) == 1
    assert "pass --scene" in capsys.readouterr().err
    if not torch.cuda.is_available():
        assert main(["splat", "render", str(run), "--rasterizer", "gsplat", "--out", str(tmp_path / "g.gif")]) == 1
        assert "cannot render with gsplat" in capsys.readouterr().err
        assert not (tmp_path / "g.gif").exists()


def test_an_antialiased_run_records_its_mode_and_dilation_and_renders_in_them(tiny_scene, tmp_path, capsys):
    import pointfield
    from pointfield.splats.mip import drawn
    from pointfield.splats.ply import read_splat_mode
    from pointfield.splats.rasterizer import rasterizer_mode
    from pointfield.splats.run import camera_matrices, render_camera
    from pointfield.splats.run import render as splat_render

    assert main(["splat", "train", str(tiny_scene), "--out", str(tmp_path / "run"), "--steps", "4",
                 "--initial-splats", "200", "--antialiased", "--screen-dilation", "0.1", "--no-progress"]) == 0
    run = pointfield.load_run(tmp_path / "run")
    assert run.config["antialiased"] is True and run.config["screen_dilation"] == 0.1
    opacity = run.render(run.scene.cameras[[0]], outputs=("opacity",))[0]["opacity"]
    g = run.gaussians
    scales, opacities = drawn(g)  # with the 3D filter of the default --mip
    viewmats, Ks = camera_matrices(run.scene.cameras[[0]], run.device)
    rendered = {(mode, dilation): rasterization(g.means, g.quats, scales, opacities, g.sh_coefficients, viewmats,
                                                Ks, 24, 24, sh_degree=g.active_sh_degree, antialiased=mode,
                                                screen_dilation=dilation)[2][0].detach()
                for mode, dilation in ((False, 0.3), (True, 0.3), (True, 0.1))}
    torch.testing.assert_close(opacity, rendered[True, 0.1].clamp(0, 1))
    for other in ((False, 0.3), (True, 0.3)):
        assert float((rendered[other] - rendered[True, 0.1]).abs().max()) > 1e-3, f"{other} should differ here"
    # Exported, the splats keep their mode (a header comment), and a render of the file draws in it.
    assert main(["splat", "export", str(tmp_path / "run"), "--out", str(tmp_path / "aa.ply")]) == 0
    assert read_splat_mode(tmp_path / "aa.ply") == {"antialiased": True, "screen_dilation": 0.1}
    rendered_file = splat_render(tmp_path / "aa.ply", scene=tiny_scene, path="dataset", frames=1,
                                 out=tmp_path / "aa-frames", outputs=("depth",))
    assert (rendered_file["antialiased"], rendered_file["screen_dilation"]) == (True, 0.1)
    # The file's depth (written as .npy, unquantised) is the run's own, and a classic draw's differs.
    file_depth = torch.from_numpy(np.load(tmp_path / "aa-frames" / "depth_000.npy"))
    run_depth = run.render(run.scene.cameras[[0]], outputs=("depth",))[0]["depth"]
    classic_depth = render_camera(g, run.scene.cameras[[0]], 0, torch.ones(3), "pointfield", ("depth",),
                                  antialiased=False, screen_dilation=0.3)["depth"]
    torch.testing.assert_close(file_depth, run_depth)
    assert float((file_depth - classic_depth).abs().max()) > 1e-3
    # A run made before the settings existed was classic, with 3DGS's 0.3 px^2.
    assert rasterizer_mode({"task": "splat"}) == {"antialiased": False, "screen_dilation": 0.3}
    assert main(["splat", "train", str(tiny_scene), "--out", str(tmp_path / "bad"), "--steps", "4",
                 "--screen-dilation", "0", "--no-progress"]) == 1
    assert "--screen-dilation must be a positive number of px^2, got 0.0" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def test_a_colmap_scene_initialises_from_its_sparse_points(shared_data):
    from pointfield.scenes import read_scene
    from pointfield.splats.train import initial_gaussians

    scene = read_scene(shared_data / "colmap/tiny_phone_scene", format="colmap")
    gaussians = initial_gaussians(scene, 1000, seed=0)
    assert len(gaussians) == len(scene.points.points) == 256
    np.testing.assert_allclose(gaussians.means.detach().numpy(), scene.points.points, rtol=1e-6)
    # --init random ignores the points (the start the SfM benchmark compares against)
    assert len(initial_gaussians(scene, 1000, seed=0, init="random")) == 1000


def test_init_points_without_points_is_a_clear_error():
    from pointfield.errors import PointfieldError
    from pointfield.scenes import synthetic_scene
    from pointfield.splats.train import initial_gaussians

    with pytest.raises(PointfieldError, match="needs a scene with sparse points"):
        initial_gaussians(synthetic_scene("cube", views=3, size=8), 10, seed=0, init="points")


def test_a_scene_without_points_or_box_starts_at_random_around_its_cameras(tmp_path):
    from pointfield.scenes import synthetic_scene
    from pointfield.splats.train import initial_gaussians

    scene = synthetic_scene("cube", views=4, size=16)
    scene.aabb = None
    gaussians = initial_gaussians(scene, 50, seed=0)
    assert len(gaussians) == 50
    distances = np.linalg.norm(scene.cameras.centers.numpy(), axis=1).mean()
    assert gaussians.means.detach().abs().max() < distances / 2


def test_depth_distortion_is_the_double_sum_over_each_pixels_splats():
    from pointfield.splats.loss import depth_distortion

    generator = torch.Generator().manual_seed(0)
    weights = torch.rand(6, 5, 8, generator=generator, dtype=torch.float64) / 8   # (H, W, splats), sum <= 1
    z = 2 + 3 * torch.rand(6, 5, 8, generator=generator, dtype=torch.float64)
    brute = (weights[..., :, None] * weights[..., None, :] * (z[..., :, None] - z[..., None, :]) ** 2).sum((-1, -2))
    closed = depth_distortion((weights * z).sum(-1), (weights * z * z).sum(-1), weights.sum(-1), scene_scale=2.0)
    assert float(closed) == pytest.approx(float(brute.mean()) / 4, rel=1e-9)


def test_depth_distortion_of_rendered_layers_grows_with_their_gap():
    from pointfield.splats.loss import depth_distortion

    # Two half-transparent discs one behind the other, facing an identity camera.
    def distortion(gap):
        means = torch.tensor([[0.0, 0.0, 4.0], [0.0, 0.0, 4.0 + gap]], dtype=torch.float64)
        quats = torch.tensor([[1.0, 0, 0, 0]], dtype=torch.float64).repeat(2, 1)
        scales = torch.tensor([[0.5, 0.5, 1e-4]], dtype=torch.float64).repeat(2, 1)
        z = means[:, 2:]
        K = torch.tensor([[[40.0, 0, 20], [0, 40.0, 20], [0, 0, 1]]], dtype=torch.float64)
        colors, depths, alphas, _ = rasterization(means, quats, scales, torch.full((2,), 0.5, dtype=torch.float64),
                                                  z * z, torch.eye(4, dtype=torch.float64)[None], K, 40, 40)
        return float(depth_distortion(depths[0], colors[0, ..., 0], alphas[0], scene_scale=1.0))

    assert distortion(0.0) == pytest.approx(0, abs=1e-9)
    # Squared distances: twice the gap, four times the cost (less a little: the farther disc
    # covers fewer pixels).
    assert distortion(0.2) == pytest.approx(4 * distortion(0.1), rel=0.05)
    assert distortion(0.1) > 0


def test_a_negative_3d_filter_strength_is_refused_before_training(tmp_path):
    with pytest.raises(PointfieldError, match="--mip-smoothing must be a number >= 0"):
        train(None, out=tmp_path / "run", mip_smoothing=-0.1, steps=1, progress=False)
    assert not (tmp_path / "run").exists()
