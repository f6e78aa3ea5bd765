"""A real browser on the viewer's page: headless Chromium driven through playwright.

The tests, the benchmarks and the README's screenshots (:mod:`pointfield.viewer.screenshot`)
all look at the page this way. The browser is the system's Chromium (Debian's ``chromium``
package; ``make test`` installs it), never one playwright downloads. Without a GPU, WebGL runs
on SwiftShader, Chromium's software renderer (:data:`CHROMIUM_FLAGS`).

A picture "shows the object" when enough pixels of the 3D canvas differ from its background
(:func:`object_pixels`): an empty scene, or a page whose WebGL failed, has none.

playwright is in the ``dev`` extra: this module is imported by the tests, the benchmarks and the
screenshot script, never by ``pointfield view`` itself.
"""

from __future__ import annotations

import io
import shutil
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
from PIL import Image
from playwright.sync_api import Page, sync_playwright

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
CHROMIUM_FLAGS = (
    "--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist",
    "--disable-dev-shm-usage",
)
"""WebGL through SwiftShader, so that a machine without a GPU (or a display) draws the scene."""
VIEWPORT = (1024, 640)
HIDE_NOTIFICATIONS = ".mantine-Notifications-root, .mantine-Notification-root { display: none !important; }"
"""viser warns about software WebGL in a notification; pictures leave it out."""


def find_chromium() -> str | None:
    """The system Chromium's path, or None when there is none."""
    for name in CHROMIUM_NAMES:
        found = shutil.which(name)
        if found:
            return found
    return None


@contextmanager
def chromium(executable: str | None = None) -> Iterator[Any]:
    """A headless Chromium (playwright ``Browser``) for the duration of the block."""
    executable = executable or find_chromium()
    if executable is None:
        raise RuntimeError("no Chromium found: install Debian's chromium package (make test does)")
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=executable, args=list(CHROMIUM_FLAGS))
        try:
            yield browser
        finally:
            browser.close()


def open_page(browser: Any, url: str, viewport: tuple[int, int] = VIEWPORT) -> Page:
    """A new tab of ``browser`` on ``url`` (the viewer's page), notifications hidden."""
    page = browser.new_page(viewport={"width": viewport[0], "height": viewport[1]})
    page.goto(url)
    page.add_style_tag(content=HIDE_NOTIFICATIONS)
    return page


def canvas_box(page: Page) -> dict[str, float]:
    """Where the 3D canvas is on the page: the largest ``<canvas>`` (viser also draws an axes gizmo)."""
    boxes = [box for box in (c.bounding_box() for c in page.locator("canvas").all()) if box]
    if not boxes:
        raise RuntimeError("the page has no canvas (did the viewer's client load?)")
    return max(boxes, key=lambda box: box["width"] * box["height"])


def screenshot(page: Page, path: str | None = None, canvas_only: bool = False) -> np.ndarray:
    """The page (or only its 3D canvas) as an ``(H, W, 3)`` uint8 array; also written to ``path``."""
    clip = canvas_box(page) if canvas_only else None
    png = page.screenshot(path=path, clip=clip)
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))


def object_pixels(image: np.ndarray, tolerance: int = 24) -> int:
    """Pixels that differ from the image's background, its most common colour, by more than ``tolerance``."""
    flat = image.reshape(-1, 3).astype(np.int32)
    codes = (flat[:, 0] << 16) | (flat[:, 1] << 8) | flat[:, 2]
    values, counts = np.unique(codes, return_counts=True)
    mode = values[np.argmax(counts)]
    background = np.array([(mode >> 16) & 255, (mode >> 8) & 255, mode & 255])
    return int((np.abs(flat - background).max(axis=1) > tolerance).sum())


def wait_for(condition: Callable[[], Any], timeout: float, what: str, poll: float = 0.05) -> Any:
    """Poll ``condition()`` until it returns neither None nor False; TimeoutError naming ``what`` after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value is not None and value is not False:
            return value
        if time.monotonic() > deadline:
            raise TimeoutError(f"{what} did not happen within {timeout:.0f} s")
        time.sleep(poll)


def wait_for_picture(page: Page, min_pixels: int, timeout: float = 30.0,
                     region: tuple[float, float, float, float] | None = None) -> np.ndarray:
    """Screenshots of the canvas until at least ``min_pixels`` show something; returns the last one.

    ``region``: ``(left, top, right, bottom)`` fractions of the canvas to count in (the panel
    covers its top right; the axes gizmo its bottom left).
    """
    def picture() -> np.ndarray | None:
        image = screenshot(page, canvas_only=True)
        counted = crop(image, region) if region else image
        return image if object_pixels(counted) >= min_pixels else None

    return wait_for(picture, timeout, f"a picture with {min_pixels} object pixels", poll=0.1)


def crop(image: np.ndarray, region: tuple[float, float, float, float]) -> np.ndarray:
    """The part of ``image`` between fractions ``(left, top, right, bottom)`` of its size."""
    height, width = image.shape[:2]
    left, top, right, bottom = region
    return image[int(top * height): int(bottom * height), int(left * width): int(right * width)]


SCENE_REGION = (0.1, 0.1, 0.6, 0.9)
"""The part of the canvas left of viser's panel and above its axes gizmo."""
