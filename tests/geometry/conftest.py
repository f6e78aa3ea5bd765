"""One small trained splat run shared by the geometry tests (training it once keeps them fast).

And one small hash-grid field run of the cube, shared by the density meshes and the cloud that
the shape classifier is shown.
"""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def splat_run(tmp_path_factory):
    """Splats trained 30 steps on the 24-pixel synthetic cube: not a good model, but a real run."""
    from pointfield.splats.train import train

    out = tmp_path_factory.mktemp("runs") / "splats"
    train(None, out=out, steps=30, eval_every=30, eval_views=1, cube_views=8, cube_size=24, progress=False)
    return out


NGP_CUBE_BOX = [-1.0, -1.0, -1.0, 1.0, 1.0, 1.0]
"""The field's box: twice the cube's side, so that the cube's surface is learnt, not the box's walls."""


@pytest.fixture(scope="session")
def ngp_cube_run(tmp_path_factory):
    """The hash-grid field trained 200 steps on the synthetic cube (24 views of 48 px) in :data:`NGP_CUBE_BOX`.

    About 45 s on 2 CPU threads (65 s on one); held-out PSNR 18.4 to 19.8 dB over seeds 0 to 2: a
    rough field, but the cube's shape is in it. The small, eager hash grid and the thick start are
    those of tests/fields/test_ngp.py.
    """
    from pointfield.fields.train import train

    options = {"backend": "eager", "levels": 8, "log2_table_size": 14, "max_resolution": 128,
               "target_samples": 8192, "initial_optical_depth": 7.4}
    out = tmp_path_factory.mktemp("runs") / "ngp-cube"
    train(None, model="ngp", out=out, steps=200, eval_every=200, cube_views=24, cube_size=48, device="cpu",
          model_options=options, scene_box=NGP_CUBE_BOX, seed=0, progress=False)
    return out
