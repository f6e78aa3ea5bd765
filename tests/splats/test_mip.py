"""Mip-Splatting's filters (``splat train --mip``): the 3D smoothing filter from the training
cameras, the 2D mip filter, and what they do to views closer than the training cameras."""

import json
import math

import pytest
import torch

import pointfield
from pointfield.metrics import mean_psnr
from pointfield.scenes import synthetic_truth
from pointfield.scenes.synthetic import synthetic_cameras
from pointfield.splats.gaussians import Gaussians
from pointfield.splats.mip import MIP_DILATION, SMOOTHING, baked, smoothed, smoothing_variance
from pointfield.splats.ply import read_splat_mode, read_splats
from pointfield.splats.run import export
from pointfield.splats.train import train


def _camera_at(distance, focal, size=100):
    """A camera on the -z axis at ``distance`` looking at the origin: viewmat (4, 4), K (3, 3)."""
    viewmat = torch.eye(4)
    viewmat[2, 3] = distance
    K = torch.tensor([[focal, 0, size / 2], [0, focal, size / 2], [0, 0, 1.0]])
    return viewmat, K


def test_the_filter_follows_the_finest_sampling_of_the_cameras_that_see_each_splat():
    near, far = _camera_at(2.0, 100.0), _camera_at(5.0, 400.0)
    viewmats, Ks = torch.stack([near[0], far[0]]), torch.stack([near[1], far[1]])
    # Splat 0 at the origin is seen by both: intervals 2/100 and 5/400, the finer 0.0125 wins.
    # Splat 1 is off the near camera's screen (u = 50 + 100 * 1.5 / 2 = 125 > 1.15 * 100) but in
    # the far one's (u = 50 + 400 * 1.5 / 5 = 170 > 115: off too): nobody sees it, so it takes
    # the largest interval of the others.
    means = torch.tensor([[0.0, 0.0, 0.0], [1.5, 0.0, 0.0], [0.0, 0.0, -3.0]])
    variance = smoothing_variance(means, viewmats, Ks, [100, 100], [100, 100])
    assert variance[0] == pytest.approx(SMOOTHING * 0.0125**2)
    # Splat 2 is behind the near camera (z = -1) and 2 units in front of the far one: 2/400.
    assert variance[2] == pytest.approx(SMOOTHING * (2 / 400) ** 2)
    assert variance[1] == pytest.approx(float(variance[[0, 2]].max()))


def test_the_filter_keeps_each_splats_integral_and_grows_small_splats_most():
    scales = torch.tensor([[0.001, 0.001, 0.001], [0.1, 0.1, 0.1]])
    opacities = torch.tensor([0.8, 0.8])
    variance = torch.full((2,), 0.01**2)
    filtered_scales, filtered_opacities = smoothed(scales, opacities, variance)
    # Opacity times the Gaussian's volume, o prod(s), is unchanged: the low-pass spreads a splat, adds nothing.
    assert torch.allclose(filtered_opacities * filtered_scales.prod(1), opacities * scales.prod(1))
    assert filtered_scales[0, 0] == pytest.approx(math.sqrt(0.001**2 + 0.01**2))
    assert filtered_opacities[1] == pytest.approx(0.8 * (0.1**2 / (0.1**2 + 0.01**2)) ** 1.5, rel=1e-5)
    assert smoothed(scales, opacities, None) == (scales, opacities)


CUBE = {"cube_views": 24, "cube_size": 48}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The cube trained from 4 units away, with and without the filters, in the same short schedule
    (without the opacity entropy term, on by default, so that the filters alone make the difference;
    the 3D filter at Mip-Splatting's strength 0.2).

    Measured (seed 0): from 2.6 units 21.06 dB without the filters, 22.28 with; from 4 units
    27.38 and 27.14 dB. Shorter runs (300 steps at 40 x 40) have splats too coarse yet for the
    filters to matter (19.68 and 19.74 dB from 2.6 units).
    """
    folder = tmp_path_factory.mktemp("mip")
    for mip in (False, True):
        train(None, out=folder / str(mip), steps=500, eval_every=500, initial_splats=2000, seed=0, device="cpu",
              progress=False, mip=mip, mip_smoothing=SMOOTHING, opacity_entropy=0.0, **CUBE)
    return folder


def _psnr_at(run_folder, distance):
    """Mean PSNR of 8 views of the cube from ``distance`` against its analytic truth."""
    run = pointfield.load_run(run_folder, "cpu")
    cameras = synthetic_cameras(8, CUBE["cube_size"], radius=distance)
    views = run.render(cameras, outputs=("rgb",))
    return mean_psnr([view["rgb"].numpy() for view in views], list(synthetic_truth(run.scene, cameras)))


def test_a_mip_run_records_its_filters(runs):
    config = json.loads((runs / "True" / "config.json").read_text())
    assert config["mip"] is True and config["antialiased"] is True
    assert config["screen_dilation"] == MIP_DILATION
    assert pointfield.load_run(runs / "True", "cpu").gaussians.smoothing is not None
    assert pointfield.load_run(runs / "False", "cpu").gaussians.smoothing is None


def test_views_closer_than_the_training_cameras_score_better_with_the_filters(runs):
    closer = {mip: _psnr_at(runs / str(mip), 0.65 * 4.0) for mip in (False, True)}
    assert closer[True] > closer[False] + 0.5, closer


def test_the_filters_change_little_at_the_training_distance(runs):
    same = {mip: _psnr_at(runs / str(mip), 4.0) for mip in (False, True)}
    assert abs(same[True] - same[False]) < 1.0, same


def test_the_export_bakes_the_3d_filter_in(runs, tmp_path):
    out = tmp_path / "mip.ply"
    export(runs / "True", out)
    run = pointfield.load_run(runs / "True", "cpu")
    written = read_splats(out)
    expected = baked(run.gaussians)
    assert torch.allclose(written.scales, expected.scales, rtol=1e-5)
    assert torch.allclose(written.opacities, expected.opacities, rtol=1e-4, atol=1e-6)
    assert bool((written.scales >= run.gaussians.scales.detach() - 1e-9).all())
    assert read_splat_mode(out) == {"antialiased": True, "screen_dilation": MIP_DILATION}


def test_baked_splats_render_like_the_filtered_ones():
    gaussians = Gaussians.random_in_box(50, [-1, -1, -1], [1, 1, 1], seed=3)
    gaussians.smoothing = torch.full((50,), 0.02**2)
    copy = baked(gaussians)
    assert copy.smoothing is None
    scales, opacities = smoothed(gaussians.scales, gaussians.opacities, gaussians.smoothing)
    assert torch.allclose(copy.scales, scales.detach()) and torch.allclose(copy.opacities, opacities.detach())
