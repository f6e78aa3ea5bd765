"""Opacity trained towards the images' alpha: random backgrounds in expectation, the defaults, and that it learns."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pointfield.fields.rays import SceneExtent
from pointfield.fields.training_rays import TrainingRays
from pointfield.scenes import synthetic_scene
from pointfield.training.opacity import (
    BACKGROUND_MEAN,
    BACKGROUND_VARIANCE,
    DEFAULT_ALPHA_LOSS,
    alpha_loss_weight,
    random_background_loss,
    recomposite,
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


def test_the_random_background_loss_is_the_mean_over_drawn_backgrounds():
    """Colour error over grey plus the loss = the error averaged over many uniform random backgrounds,
    each composited behind both the render and the image, as Instant-NGP draws them."""
    generator = torch.Generator().manual_seed(0)
    rays = 64
    rgb, alpha = torch.rand(rays, 3, generator=generator), torch.rand(rays, generator=generator)
    rendered_rgb, opacity = torch.rand(rays, 3, generator=generator), torch.rand(rays, generator=generator)

    def over(colour, coverage, background):
        return colour * coverage[..., None] + background * (1 - coverage[..., None])

    backgrounds = torch.rand(200_000, 1, 3, generator=generator, dtype=torch.float64)
    sampled = torch.mean((over(rendered_rgb.double(), opacity.double(), backgrounds)
                          - over(rgb.double(), alpha.double(), backgrounds)) ** 2)
    grey = torch.full((3,), BACKGROUND_MEAN)
    expected = (torch.mean((over(rendered_rgb, opacity, grey) - over(rgb, alpha, grey)) ** 2)
                + random_background_loss(opacity, alpha))
    assert (BACKGROUND_MEAN, BACKGROUND_VARIANCE) == pytest.approx((1 / 2, 1 / 12))
    assert float(expected) == pytest.approx(float(sampled), rel=2e-3)
    # Opacity is pinned: a transparent render of an opaque pixel costs, whatever its colour.
    assert float(random_background_loss(torch.zeros(rays), torch.ones(rays))) == pytest.approx(1 / 12)


def test_the_alpha_loss_applies_only_where_the_images_have_alpha():
    cube = synthetic_scene("cube", views=4, size=8)
    frames = np.arange(4)
    assert alpha_loss_weight(None, cube, frames) == DEFAULT_ALPHA_LOSS
    assert alpha_loss_weight(0.5, cube, frames) == 0.5 and alpha_loss_weight(0, cube, frames) == 0
    transparency = TrainingRays(cube, frames, SceneExtent(cube.aabb), torch.device("cpu")).transparency
    assert transparency.shape == (4 * 8 * 8,) and 0 < float(transparency.mean()) < 1
    assert torch.equal(transparency[: 8 * 8], torch.from_numpy(1 - cube.alpha(0).reshape(-1)))

    class Photos:  # a scene whose images have no alpha
        def alpha(self, index):
            return None

    assert alpha_loss_weight(None, Photos(), frames) == 0
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


OPACITY_SETTINGS = {"colour only": {"alpha_loss": 0.0, "random_background": False},
                    "alpha loss": {"alpha_loss": DEFAULT_ALPHA_LOSS, "random_background": False},
                    "random backgrounds": {"alpha_loss": 0.0, "random_background": True}}


def _white_cube_opacity_error(white_cube, out, setting: str) -> float:
    from pointfield.fields.train import train

    metrics = train(str(white_cube), model="ngp", out=out, steps=STEPS, eval_every=STEPS, device="cpu",
                    model_options=SMALL_NGP, scene_box=[-1, -1, -1, 1, 1, 1], seed=0, progress=False,
                    **OPACITY_SETTINGS[setting])
    return metrics["opacity_error"]


@pytest.fixture(scope="module")
def colour_only_opacity_error(white_cube, tmp_path_factory):
    return _white_cube_opacity_error(white_cube, tmp_path_factory.mktemp("colour-only"), "colour only")


@pytest.mark.parametrize("cure", ["alpha loss", "random backgrounds"])
def test_opacity_training_learns_the_opacity_that_colour_cannot_show(white_cube, colour_only_opacity_error,
                                                                     tmp_path, cure):
    """A white cube on white: the colour loss is blind to opacity; the alpha loss or random backgrounds find the cube.

    The hash-grid field starts thick (opaque everywhere in its box); colour alone leaves it so.
    Splats are checked on lego by ``make bench-geometry`` (opacity error 0.006 against 0.34).
    """
    error = _white_cube_opacity_error(white_cube, tmp_path, cure)
    assert error < 0.5 * colour_only_opacity_error, (error, colour_only_opacity_error)


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
