"""``pointfield view``: clouds, meshes, scenes, splats and runs in the browser, and training live.

=====================  =========================================================================
server.py              the page: a viser server on 127.0.0.1, the next free port, display origin
sources.py             what each PATH is (cloud, splats, scene, run) and :func:`view`
clouds.py              clouds and meshes: decimated past a budget, colour by any field, LAZ preview
scenes.py              camera frustums with thumbnails, sparse points, a camera's photo on click
splats.py              Gaussians drawn by the browser (viser's Gaussian-splat node)
fields.py              scene models rendered on the server from the browser's camera
training.py            ``nerf train --view`` / ``splat train --view``: the run live, pause / resume
browser.py             a headless Chromium that opens the page (tests, benchmarks, screenshots)
screenshot.py          ``python -m pointfield.viewer.screenshot``: the README's pictures
=====================  =========================================================================

Example::

    from pointfield.viewer import view
    view(["scan.laz", "runs/lego-ngp"])          # serves http://127.0.0.1:8080 until Ctrl-C
"""

from pointfield.viewer.sources import open_viewer, view

__all__ = ["open_viewer", "view"]
