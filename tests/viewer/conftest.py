"""Small things to view, and a real browser to view them with.

The browser is the system's Chromium driven by playwright (:mod:`pointfield.viewer.browser`);
``make test`` installs Debian's ``chromium``. Where neither can be had, every browser test skips
with one reason that says so.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.formats.registry import write

BROWSER_SKIP = ("no headless browser: the viewer's browser tests need playwright (pip install -e '.[dev]') "
                "and Debian's chromium package (apt-get install chromium; `make test` installs both)")


def pytest_configure(config):
    config.addinivalue_line("markers", "browser: drives a headless Chromium on the viewer's page")


@pytest.fixture(scope="session")
def browser():
    """One headless Chromium for the whole session; skips every browser test when there is none."""
    try:
        from pointfield.viewer.browser import chromium, find_chromium
    except ImportError:
        pytest.skip(BROWSER_SKIP)
    if find_chromium() is None:
        pytest.skip(BROWSER_SKIP)
    with chromium() as opened:
        yield opened


@pytest.fixture
def page_of(browser):
    """``page_of(viewer)``: a new tab on ``viewer``'s page, closed after the test."""
    from pointfield.viewer.browser import open_page

    pages = []

    def open_one(viewer):
        page = open_page(browser, viewer.url, viewport=(800, 600))
        pages.append(page)
        return page

    yield open_one
    for page in pages:
        page.close()


@pytest.fixture(scope="session")
def cloud_file(tmp_path_factory):
    """A 20,000-point PLY (a bumpy square, 10 by 10 units, far from the origin) with colours and intensity."""
    rng = np.random.default_rng(0)
    xy = rng.uniform(0, 10, (20_000, 2))
    z = np.sin(xy[:, 0]) + np.cos(xy[:, 1])
    points = np.column_stack([xy + [500_000.0, 4_200_000.0], z + 100.0])
    colours = (np.column_stack([xy / 10, np.full(len(xy), 0.3)]) * 255).astype(np.uint8)
    cloud = PointCloud(points, {"colors": colours, "intensity": (z * 1000 + 3000).astype(np.uint16)})
    path = tmp_path_factory.mktemp("view") / "bumps.ply"
    write(path, cloud)
    return path


@pytest.fixture(scope="session")
def scene_folder(tmp_path_factory):
    """The synthetic cube as a Blender scene: 12 views of 32 pixels."""
    from pointfield.scenes import make_scene

    return make_scene("cube", tmp_path_factory.mktemp("view") / "cube", views=12, size=32)


@pytest.fixture(scope="session")
def splat_file(tmp_path_factory):
    """500 opaque splats in a unit box, as a standard splat .ply."""
    from pointfield.splats.gaussians import Gaussians
    from pointfield.splats.ply import write_splats

    gaussians = Gaussians.random_in_box(500, [-1, -1, -1], [1, 1, 1], seed=0)
    with torch.no_grad():
        gaussians.opacity_logits.fill_(3.0)
        gaussians.log_scales.fill_(np.log(0.08))
    path = tmp_path_factory.mktemp("view") / "box.ply"
    write_splats(path, gaussians)
    return path


@pytest.fixture(scope="session")
def ngp_run(tmp_path_factory):
    """A hash-grid field trained 20 steps on the synthetic cube (8 views of 24 px): a rough cube, in seconds."""
    from pointfield.fields.train import train

    options = {"backend": "eager", "levels": 4, "log2_table_size": 12, "max_resolution": 32,
               "target_samples": 4096, "initial_optical_depth": 7.4}
    out = tmp_path_factory.mktemp("runs") / "ngp"
    train(None, model="ngp", out=out, steps=20, eval_every=20, cube_views=8, cube_size=24, device="cpu",
          model_options=options, scene_box=[-1.0, -1.0, -1.0, 1.0, 1.0, 1.0], progress=False)
    return out


@pytest.fixture(scope="session")
def splat_run(tmp_path_factory):
    """Splats trained 10 steps on the synthetic cube (8 views of 24 px)."""
    from pointfield.splats.train import train

    out = tmp_path_factory.mktemp("runs") / "splats"
    train(None, out=out, steps=10, eval_every=10, eval_views=1, initial_splats=500, cube_views=8, cube_size=24,
          device="cpu", progress=False)
    return out


@pytest.fixture
def served():
    """``served(paths, **options)``: :func:`pointfield.viewer.open_viewer` on any free port, closed after the test."""
    from pointfield.viewer import open_viewer

    viewers = []

    def serve(paths, **options):
        viewer, views = open_viewer([str(p) for p in paths], port=0, **options)
        viewers.append(viewer)
        return viewer, views

    yield serve
    for viewer in viewers:
        viewer.close()
