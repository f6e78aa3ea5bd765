"""``python -m pointfield.viewer.screenshot OUT.png PATH [PATH ...]``: a picture of the viewer's page.

The README's pictures are made this way, by the code the browser tests use: the page is served
(:func:`pointfield.viewer.open_viewer`), opened in headless Chromium
(:mod:`pointfield.viewer.browser`), and captured once its canvas shows the object and, for runs,
once the server has sent a full-resolution frame.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from pointfield.viewer.browser import (
    SCENE_REGION,
    chromium,
    open_page,
    screenshot,
    wait_for,
    wait_for_picture,
)
from pointfield.viewer.fields import RunView
from pointfield.viewer.sources import open_viewer


def take(paths: list[str], out: Path, *, size: tuple[int, int] = (1200, 720), settle: float = 2.0,
         max_points: int = 2_000_000) -> Path:
    """Serve ``paths``, open the page at ``size``, and write its screenshot to ``out``."""
    viewer, views = open_viewer(paths, port=0, max_points=max_points)
    try:
        with chromium() as browser:
            page = open_page(browser, viewer.url, viewport=size)
            wait_for_picture(page, 5000, timeout=120, region=SCENE_REGION)
            for view in views:
                if isinstance(view, RunView) and view.renderer.enabled:
                    wait_for(lambda r=view.renderer: any(not f.moving for f in r.frames()) or None, 300,
                             "a full-resolution frame")
            time.sleep(settle)
            out.parent.mkdir(parents=True, exist_ok=True)
            screenshot(page, str(out))
    finally:
        viewer.close()
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="the PNG to write")
    parser.add_argument("paths", nargs="+", help="what to show (as for pointfield view)")
    parser.add_argument("--width", type=int, default=1200)
    parser.add_argument("--height", type=int, default=720)
    args = parser.parse_args(argv)
    print(f"wrote {take(args.paths, args.out, size=(args.width, args.height))}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
