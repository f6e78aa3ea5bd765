"""Which box to reconstruct (issue 6): bounded objects, unbounded photos, boxes given by hand."""

import dataclasses
import math
import types

import numpy as np
import pytest
import torch

from pointfield.fields.scene_box import (
    NO_STEP_LIMIT,
    STEPS_PER_PIXEL,
    scene_bounds,
    steps_a_pixel_allows,
)
from pointfield.scenes import read_scene, synthetic_scene


@pytest.fixture(scope="module")
def cube_scene():
    return synthetic_scene("cube", views=12, size=16)


def test_a_synthetic_scene_with_alpha_is_bounded_by_its_aabb(cube_scene):
    box, unbounded = scene_bounds(cube_scene)
    assert unbounded is False
    assert np.allclose(box, [[-0.6, -0.6, -0.6], [0.6, 0.6, 0.6]])  # the cube with 10 % room
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


def test_a_new_ngp_run_takes_the_papers_hash_grid_on_cuda_only(cube_scene):
    from pointfield.fields.ngp import CUDA_OPTIONS, InstantNGP
    from pointfield.fields.train import default_ngp_options

    on_cpu = default_ngp_options(cube_scene, "auto", torch.device("cpu"))
    on_cuda = default_ngp_options(cube_scene, "auto", torch.device("cuda"))  # nothing is allocated
    assert set(on_cpu) == {"box", "unbounded", "max_resolution"}  # the model's own (CPU) grid
    assert on_cpu["max_resolution"] == 64  # twice the 16 px images' side, but at least 64 (scene_box.py)
    steps = steps_a_pixel_allows(cube_scene, on_cpu["box"])  # 16 px images: far fewer than the paper's 1,024
    assert on_cuda == {**on_cpu, **CUDA_OPTIONS, "steps_across_box": steps}
    model = InstantNGP(**{**on_cuda, "log2_table_size": 12})  # the paper's grid builds on any device
    assert model.step_size == pytest.approx(math.sqrt(3) * 1.2 / steps)
    assert model.grid.resolution == 128


def test_marching_steps_are_no_finer_than_a_quarter_of_a_pixel(cube_scene):
    box, _ = scene_bounds(cube_scene)
    footprint = 4.0 / float(cube_scene.cameras.fx[0])  # a pixel's width at the centre: the cameras are 4 from it
    steps = steps_a_pixel_allows(cube_scene, box)
    step = math.sqrt(3) * 1.2 / steps
    assert footprint / STEPS_PER_PIXEL <= step < footprint / STEPS_PER_PIXEL * (steps + 1) / steps


def test_cameras_at_the_boxs_centre_set_no_limit_on_the_steps(cube_scene):
    one_camera = types.SimpleNamespace(cameras=cube_scene.cameras[[0]])
    centre = cube_scene.cameras.camera_to_world[0, :3, 3].numpy()
    assert steps_a_pixel_allows(one_camera, [centre - 1, centre + 1]) == NO_STEP_LIMIT


def test_lego_keeps_the_papers_1024_steps_at_full_resolution_only(shared_data):
    from pointfield.fields.train import default_ngp_options

    lego = read_scene(shared_data / "nerf" / "lego_blender")
    full = default_ngp_options(lego, "auto", torch.device("cuda"))["steps_across_box"]
    eighth = default_ngp_options(lego.downscaled(8), "auto", torch.device("cuda"))["steps_across_box"]
    assert full == 1024  # a pixel at 800 x 800 spans fewer than four of them
    assert 256 < eighth < 1024  # at 100 x 100, four steps a pixel
