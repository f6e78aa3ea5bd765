"""A trained field holds up from cameras it never saw: nearer and farther than its training cameras.

The hash-grid field is trained briefly (200 steps, the small eager grid of
tests/geometry/conftest.py) on a ``scene make`` cube of 24 views of 32 x 32 seen from 4 units,
then views from 0.7x and 1.3x that distance are scored against the scene's analytic truth from
the same cameras (``synthetic_truth``) beside its held-out PSNR at the training distance.
Before rays were bounded by the scene box, the nearer views were clipped to the training
cameras' depth bounds and showed nothing of the cube's near half.
"""

from __future__ import annotations

import pytest

from pointfield.fields.train import train
from pointfield.metrics import mean_psnr
from pointfield.runs import load_run
from pointfield.scenes import make_scene, synthetic_truth
from pointfield.scenes.synthetic import synthetic_cameras

SIZE = 32
OPTIONS = {"backend": "eager", "levels": 8, "log2_table_size": 14, "max_resolution": 128,
           "target_samples": 8192, "initial_optical_depth": 7.4}

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def cube_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("any-camera")
    scene = make_scene("cube", root / "cube", views=24, size=SIZE)
    metrics = train(scene, model="ngp", out=root / "run", steps=200, eval_every=200, device="cpu", seed=0,
                    model_options=OPTIONS, progress=False)
    return load_run(root / "run", device="cpu"), metrics["psnr"]


@pytest.mark.parametrize("factor", [0.7, 1.3])
def test_views_nearer_and_farther_than_training_score_within_2_db_of_the_heldout_psnr(cube_run, factor):
    run, heldout = cube_run
    cameras = synthetic_cameras(6, SIZE, radius=factor * 4.0)
    renders = [view["rgb"].numpy() for view in run.render(cameras, outputs=("rgb",))]
    score = mean_psnr(renders, list(synthetic_truth(run.scene, cameras)))
    # Measured, seed 0 (one seed: each run took 20 minutes on the shared 2 cores): held out 20.2 dB,
    # 0.7x 19.0 dB (-1.2), 1.3x 25.1 dB (+4.9). The bar is 2 dB.
    assert score > heldout - 2.0, (score, heldout)
