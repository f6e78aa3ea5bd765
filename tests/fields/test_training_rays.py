"""Fields train on rays jittered inside their pixels, and render through pixel centres, repeatably."""

from __future__ import annotations

import torch

from pointfield.fields.rays import RayBundle, SceneExtent
from pointfield.fields.training_rays import TrainingRays
from pointfield.scenes.synthetic import synthetic_scene

SCENE = synthetic_scene("cube", views=3, size=8)
EXTENT = SceneExtent(SCENE.aabb.tolist())


def pixels_hit(pixels: TrainingRays, bundle: RayBundle, indices: torch.Tensor) -> torch.Tensor:
    """``(B, 2)`` continuous pixel coordinates where each ray's point at unit distance projects in its camera."""
    points = (bundle.origins + bundle.directions).double()
    cameras = pixels.cameras
    which = pixels.camera_of[indices].long()
    projected = torch.stack([cameras[[int(c)]].project(p[None])[0][0, 0] for c, p in zip(which, points)])
    return projected


def test_training_rays_pass_through_random_points_inside_their_own_pixels():
    pixels = TrainingRays(SCENE, [0, 1, 2], EXTENT, torch.device("cpu"))
    indices = torch.arange(len(pixels))
    jittered = pixels.rays(indices, torch.Generator().manual_seed(0))
    hit = pixels_hit(pixels, jittered, indices)
    offsets = hit - pixels.pixel_of[indices].double()
    assert bool(((offsets > -1e-4) & (offsets < 1 + 1e-4)).all())  # inside the pixel they stand for
    assert float((offsets - 0.5).abs().max()) > 0.4  # spread over it, not at its centre
    assert float((offsets - 0.5).abs().mean()) > 0.15


def test_each_step_draws_other_offsets_and_the_same_step_the_same_ones():
    pixels = TrainingRays(SCENE, [0], EXTENT, torch.device("cpu"))
    indices = torch.arange(16)
    first = pixels.rays(indices, torch.Generator().manual_seed(1)).directions
    again = pixels.rays(indices, torch.Generator().manual_seed(1)).directions
    other = pixels.rays(indices, torch.Generator().manual_seed(2)).directions
    assert torch.equal(first, again) and not torch.allclose(first, other)


def test_without_a_generator_the_rays_are_the_renders_pixel_centre_rays():
    pixels = TrainingRays(SCENE, [1], EXTENT, torch.device("cpu"))
    centres = pixels.rays(torch.arange(len(pixels)))
    rendered = RayBundle.of_camera(SCENE.cameras, 1, EXTENT)
    assert torch.allclose(centres.directions, rendered.directions, atol=1e-6)
    assert torch.allclose(centres.near, rendered.near) and torch.allclose(centres.far, rendered.far)
    assert torch.equal(pixels.colors, torch.from_numpy(SCENE.image(1).reshape(-1, 3)))
