"""One small trained splat run shared by the geometry tests (training it once keeps them fast)."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def splat_run(tmp_path_factory):
    """Splats trained 30 steps on the 24-pixel synthetic cube: not a good model, but a real run."""
    from pointfield.splats.train import train

    out = tmp_path_factory.mktemp("runs") / "splats"
    train(None, out=out, steps=30, eval_every=30, eval_views=1, cube_views=8, cube_size=24, progress=False)
    return out
