"""Median depth as a render output: where a pixel's accumulated opacity passes one half, for fields and splats.

Both are distances along the pixel's ray in scene units, as expected depth is, and 0 where the
opacity never reaches one half.
"""

from __future__ import annotations

import math

import pytest
import torch

from pointfield.fields.field import FieldOutput, RadianceField
from pointfield.fields.rays import RaySamples, SceneExtent
from pointfield.fields.rendering import render_rays
from pointfield.fields.run import render_field
from pointfield.fields.sampling import stratified_samples
from pointfield.scenes import Cameras
from pointfield.splats.gaussians import Gaussians
from pointfield.splats.rasterizer import rasterization
from pointfield.splats.run import render_camera

SIZE = 17  # pixel 8's centre is on the optical axis
SLAB_BOX = SceneExtent(((-6.0, -6.0, 0.5), (6.0, 6.0, 6.5)))
"""Rays enter at z = 0.5 and leave at z = 6.5: a length of 6 / axis cosine."""


def camera_at_origin() -> Cameras:
    """One pinhole camera at the origin looking down +z (OpenCV axes), 17 x 17 pixels, 80 degrees wide."""
    pose = torch.eye(4, dtype=torch.float64)[None, :3]
    focal = 0.5 * SIZE / math.tan(math.radians(40))
    return Cameras(pose, fx=focal, fy=focal, cx=SIZE / 2, cy=SIZE / 2, width=SIZE, height=SIZE).to(dtype=torch.float32)


class Slabs(RadianceField):
    """A hand-set field: a faint slab ``2 <= z <= 2.1`` of opacity ``faint`` (seen square on) in front of
    a wall filling ``z >= 4`` (when ``wall``), marched at 600 samples between ``near`` and ``far``."""

    def __init__(self, faint: float, wall: bool = True):
        super().__init__()
        self.faint_sigma = -math.log(1 - faint) / 0.1  # 1 - exp(-sigma 0.1) = faint
        self.wall = wall

    def field(self, positions: torch.Tensor, directions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        z = positions[..., 2]
        sigma = torch.where((z >= 2) & (z <= 2.1), self.faint_sigma, 0.0)
        if self.wall:
            sigma = torch.where(z >= 4, 1e4, sigma)
        return sigma, torch.ones_like(positions)

    def forward(self, rays, background=None, jitter=False, generator=None) -> FieldOutput:
        t = stratified_samples(rays.near, rays.far, 600, jitter=False)
        samples = RaySamples.from_points(t, rays.far)
        return FieldOutput([render_rays(self.field, rays, samples, background)], samples=len(samples))


def test_a_fields_median_depth_is_the_distance_along_the_ray_to_the_wall_behind_a_faint_slab():
    cameras = camera_at_origin()
    view = render_field(Slabs(faint=0.3), cameras, 0, SLAB_BOX, torch.zeros(3))
    distance_to_wall = 4.0 / cameras.rays(0).axis_cosine
    step = 6.0 / 600 / cameras.rays(0).axis_cosine
    assert view["median_depth"].shape == (SIZE, SIZE)
    # the first sample past the wall, at most a sample spacing beyond it
    assert bool((view["median_depth"] >= distance_to_wall - 1e-4).all())
    assert bool((view["median_depth"] <= distance_to_wall + step + 1e-4).all())
    # the expected depth is pulled in front of the wall by the faint slab
    assert float(view["depth"][8, 8]) < 3.6


def test_a_fields_median_depth_is_zero_where_opacity_stays_below_one_half():
    view = render_field(Slabs(faint=0.3, wall=False), camera_at_origin(), 0, SLAB_BOX, torch.zeros(3))
    assert float(view["opacity"].max()) < 0.5
    assert bool((view["depth"][8, 8] > 2) & (view["depth"][8, 8] < 2.1))
    assert bool((view["median_depth"] == 0).all())


def discs(depths: list[float], opacities: list[float]) -> Gaussians:
    """Flat Gaussian discs facing the camera on its optical axis, wide enough to cover its view."""
    count = len(depths)
    means = torch.tensor([[0.0, 0.0, z] for z in depths])
    return Gaussians(
        means=means,
        quats=torch.tensor([1.0, 0.0, 0.0, 0.0]).repeat(count, 1),
        log_scales=torch.log(torch.tensor([[10.0, 10.0, 0.01]])).repeat(count, 1),
        opacity_logits=torch.logit(torch.tensor(opacities)),
        sh_dc=torch.zeros(count, 1, 3),
        sh_rest=torch.zeros(count, 0, 3),
    )


@pytest.mark.parametrize(("front", "back", "median"), [
    (0.3, 0.9, 4.0),  # T: 0.7 after the front disc, 0.07 after the back one
    (0.6, 0.9, 2.0),  # T: 0.4 after the front disc already
    (0.5, 0.9, 2.0),  # T exactly 0.5 after the front disc: "drops to 0.5 or below"
    (0.2, 0.2, 0.0),  # T: 0.64 at the end, the opacity never reaches one half
])
def test_splats_median_depth_is_the_depth_of_the_splat_where_transmittance_passes_one_half(front, back, median):
    view = render_camera(discs([2.0, 4.0], [front, back]), camera_at_origin(), 0, torch.zeros(3))
    centre = view["median_depth"][8, 8]
    assert float(centre) == pytest.approx(median, abs=1e-3)
    assert float(view["opacity"][8, 8]) == pytest.approx(1 - (1 - front) * (1 - back), abs=1e-3)
    assert 2.0 < float(view["depth"][8, 8]) < 4.0  # the expected depth falls between the discs


def test_splats_median_depth_is_zero_where_opacity_stays_below_one_half():
    view = render_camera(discs([2.0, 4.0], [0.2, 0.2]), camera_at_origin(), 0, torch.zeros(3))
    assert float(view["opacity"].max()) < 0.5
    assert bool((view["median_depth"] == 0).all())


def test_splats_median_depth_is_the_distance_along_the_ray_like_expected_depth():
    cameras = camera_at_origin()
    view = render_camera(discs([3.0], [0.95]), cameras, 0, torch.zeros(3))
    rays = cameras.rays(0)
    covered = view["median_depth"] > 0
    assert float(rays.axis_cosine[covered].min()) < 0.8  # the test means something: rays far off the axis
    torch.testing.assert_close(view["median_depth"][covered], 3.0 / rays.axis_cosine[covered])


def test_splats_median_depth_is_not_rendered_unless_asked_for():
    view = render_camera(discs([3.0], [0.95]), camera_at_origin(), 0, torch.zeros(3), outputs=("rgb", "depth"))
    assert "median_depth" not in view


def random_splats(count: int, seed: int) -> list[torch.Tensor]:
    generator = torch.Generator().manual_seed(seed)
    means = torch.randn(count, 3, generator=generator, dtype=torch.float64) * 0.5 + torch.tensor([0, 0, 4.0],
                                                                                                 dtype=torch.float64)
    quats = torch.randn(count, 4, generator=generator, dtype=torch.float64)
    scales = torch.rand(count, 3, generator=generator, dtype=torch.float64) * 0.3 + 0.05
    opacities = torch.rand(count, generator=generator, dtype=torch.float64) * 0.6 + 0.3
    return [means, quats, scales, opacities]


@pytest.mark.parametrize("gradients", [False, True])
def test_rasterized_median_depth_matches_one_found_from_each_splats_weight(gradients):
    """Each splat's weight ``alpha_i T_i`` per pixel, rendered as a one-hot feature per splat, gives
    the accumulated alpha after every splat; the median is the first splat (by z) taking it to 0.5."""
    means, quats, scales, opacities = random_splats(24, seed=3)
    K = torch.tensor([[[30.0, 0, 16], [0, 30.0, 14], [0, 0, 1]]], dtype=torch.float64)
    viewmat = torch.eye(4, dtype=torch.float64)[None]
    one_hot = torch.eye(len(means), dtype=torch.float64)
    inputs = [means, quats, scales, opacities, one_hot]
    if gradients:
        inputs = [tensor.clone().requires_grad_() for tensor in inputs]
        weights, _, _, meta = rasterization(*inputs, viewmat, K, 32, 28, median_depth=True, splats_per_slice=5)
    else:
        with torch.no_grad():
            weights, _, _, meta = rasterization(*inputs, viewmat, K, 32, 28, median_depth=True, splats_per_slice=5)
    order = torch.argsort(means[:, 2])
    accumulated = torch.cumsum(weights[0].detach()[..., order], dim=-1)                      # (H, W, N)
    reached = accumulated >= 0.5
    first = reached.to(torch.int64).argmax(dim=-1)
    expected = torch.where(reached.any(dim=-1), means[order, 2][first], torch.zeros(()))
    assert bool((expected > 0).any()) and bool((expected == 0).any())
    torch.testing.assert_close(meta["median_depths"][0], expected)
    assert not meta["median_depths"].requires_grad


def test_the_rasterizer_renders_no_median_depth_unless_asked_for():
    means, quats, scales, opacities = random_splats(4, seed=0)
    K = torch.tensor([[[30.0, 0, 16], [0, 30.0, 14], [0, 0, 1]]], dtype=torch.float64)
    _, _, _, meta = rasterization(means, quats, scales, opacities, torch.ones(4, 3, dtype=torch.float64),
                                  torch.eye(4, dtype=torch.float64)[None], K, 32, 28)
    assert "median_depths" not in meta
