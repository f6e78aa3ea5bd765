"""Opacity trained towards the images' alpha: the recompositing identity, the defaults, and that it learns."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pointfield.scenes import synthetic_scene
from pointfield.training.opacity import (
    DEFAULT_ALPHA_LOSS,
    alpha_loss_weight,
    recomposite,
    transparency_of,
    uses_random_background,
)

STEPS = 60
SMALL_NGP = {"backend": "eager", "levels": 8, "log2_table_size": 14, "max_resolution": 128,
             "target_samples": 8192, "initial_optical_depth": 7.4}
"""The small, eager hash grid and the thick start of tests/fields/test_ngp.py."""


def test_recomposite_moves_the_target_onto_the_new_background():
    generator = torch.Generator().manual_seed(0)
    rgb, alpha = torch.rand(50, 3, generator=generator), torch.rand(50, generator=generator)
    white, random = torch.ones(3), torch.rand(50, 3, generator=generator)
    on_white = rgb * alpha[:, None] + white * (1 - alpha[:, None])
    moved = recomposite(on_white, 1 - alpha, white, random)
    torch.testing.assert_close(moved, rgb * alpha[:, None] + random * (1 - alpha[:, None]))


def test_the_alpha_loss_applies_only_where_the_images_have_alpha():
    cube = synthetic_scene("cube", views=4, size=8)
    frames = np.arange(4)
    assert alpha_loss_weight(None, cube, frames) == DEFAULT_ALPHA_LOSS
    assert alpha_loss_weight(0.5, cube, frames) == 0.5 and alpha_loss_weight(0, cube, frames) == 0
    transparency = transparency_of(cube, frames)
    assert transparency.shape == (4 * 8 * 8,) and 0 < float(transparency.mean()) < 1

    class Photos:  # a scene whose images have no alpha
        def alpha(self, index):
            return None

    assert alpha_loss_weight(None, Photos(), frames) == 0 and transparency_of(Photos(), frames) is None
    assert alpha_loss_weight(None, cube, frames, default=0.0) == 0  # the fields' default
    assert uses_random_background(None, cube, frames) and not uses_random_background(False, cube, frames)
    assert not uses_random_background(None, Photos(), frames) and not uses_random_background(True, Photos(), frames)


@pytest.fixture(scope="module")
def white_cube(tmp_path_factory):
    """The synthetic cube painted white on its white background: colour says nothing, only alpha does."""
    import imageio.v3 as iio

    from pointfield.scenes.synthetic import make_scene

    data = make_scene("cube", tmp_path_factory.mktemp("scenes") / "cube", views=20, size=24)
    images = sorted(data.rglob("*.png"))
    assert images
    for path in images:
        rgba = iio.imread(path)
        rgba[..., :3] = 255
        iio.imwrite(path, rgba)
    return data


def test_the_alpha_loss_learns_the_opacity_that_colour_cannot_show(white_cube, tmp_path):
    """A white cube on white: the colour loss is blind to opacity, the alpha loss finds the cube (no random backgrounds).

    The hash-grid field starts thick (opaque everywhere in its box); colour alone leaves it so.
    Splats are checked on lego by ``make bench-geometry`` (opacity error 0.006 against 0.34).
    """
    from pointfield.fields.train import train

    errors = {}
    for weight in (0.0, DEFAULT_ALPHA_LOSS):
        metrics = train(str(white_cube), model="ngp", out=tmp_path / str(weight), steps=STEPS, eval_every=STEPS,
                        device="cpu", model_options=SMALL_NGP, scene_box=[-1, -1, -1, 1, 1, 1], alpha_loss=weight,
                        random_background=False,
                        seed=0, progress=False)
        errors[weight] = metrics["opacity_error"]
    assert errors[DEFAULT_ALPHA_LOSS] < 0.5 * errors[0.0], errors


def test_the_alpha_loss_leaves_the_reported_training_psnr_that_of_the_colour(white_cube, tmp_path):
    """One step from the same start: the colour error, hence train_psnr, is the same with or without the alpha term."""
    import json

    from pointfield.fields.train import train

    first_psnr = {}
    for weight in (0.0, 1.0):
        out = tmp_path / str(weight)
        train(str(white_cube), model="tiny", out=out, steps=1, eval_every=1, device="cpu", alpha_loss=weight,
              random_background=False, model_options={"samples": 8}, seed=0, progress=False)
        first_psnr[weight] = json.loads((out / "metrics.jsonl").read_text().splitlines()[0])["train_psnr"]
    assert first_psnr[1.0] == first_psnr[0.0]
