"""Scene models rendered on the server from the browser's camera, as nerfstudio's viewer does.

A nerf run (tiny, nerf, ngp) has nothing a browser can draw by itself: the server renders it
through the one run interface, ``run.render(cameras, outputs)``
(:class:`~pointfield.scenes.run.SceneRun`), from each connected tab's camera
(:func:`camera_of`), and sends the picture as the page's background image -- with its depth,
so that other nodes on the page (camera frustums, a cloud beside it) are hidden behind
surfaces nearer than they are.

While the camera moves, frames are rendered with :data:`MOVING_SIZE` pixels along the longer
side, as fast as they render; once it has been still for :data:`STILL_AFTER` seconds, one frame
at the canvas's own size (at most ``full_size`` along the longer side) replaces them. A
dropdown chooses what is shown: colour, depth or opacity (:data:`SHOWN`).

The browser's camera is already in pointfield's convention: viser cameras are OpenCV-style
(x right, y down, looking down +z) camera-to-world poses ``wxyz``, ``position``, with a
vertical field of view -- so :func:`camera_of` is a pinhole camera with ``fx = fy`` and the
principal point at the image centre, moved from display to real coordinates.
"""

from __future__ import annotations

import math
import os
import threading
import time
import warnings
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import imageio.v3
import numpy as np
import torch
import viser
import viser.transforms as vtf

from pointfield.runs import load_run
from pointfield.scenes.cameras import Cameras
from pointfield.scenes.heldout import View, as_numpy, depth_bounds
from pointfield.scenes.run import SceneRun
from pointfield.scenes.scene import SceneError
from pointfield.splats.run import SplatRun
from pointfield.viewer.scenes import add_frustums, scene_framing
from pointfield.viewer.server import Viewer
from pointfield.viewer.splats import add_gaussians
from pointfield.viz.views import picture

MOVING_SIZE = 256
"""Pixels along the longer side of the frames rendered while the camera moves."""
DEFAULT_FULL_SIZE = 1024
"""At most this many pixels along the longer side of the frame rendered once the camera stops."""
STILL_AFTER = 0.2
"""Seconds without a camera update after which the camera counts as still."""
SHOWN = ("rgb", "depth", "opacity")
BAND_PIXELS = 65536
"""A frame larger than this is rendered in bands of rows (see :meth:`BrowserRenderer.draw`)."""
NO_SURFACE_DEPTH = 1000.0
"""Depth sent for pixels where nothing is hit, so that every other node draws in front."""

Render = Callable[[Cameras, Sequence[str]], list[View]]


def camera_of(camera: viser.CameraHandle, longest_side: int, origin: np.ndarray | None = None) -> Cameras:
    """The browser's view as one pinhole camera with ``longest_side`` pixels along the longer side.

    ``camera``: a tab's :class:`viser.CameraHandle` -- ``wxyz`` and ``position`` (camera to
    world, OpenCV axes: the convention of :mod:`pointfield.scenes.cameras`), ``fov`` (vertical,
    radians) and the canvas size. ``origin``: added to the position (display -> real
    coordinates, :meth:`~pointfield.viewer.server.Viewer.recentre`).
    """
    canvas_w, canvas_h = max(int(camera.image_width), 1), max(int(camera.image_height), 1)
    scale = longest_side / max(canvas_w, canvas_h)
    width, height = max(1, round(canvas_w * scale)), max(1, round(canvas_h * scale))
    focal = 0.5 * height / math.tan(0.5 * float(camera.fov))
    rotation = vtf.SO3(np.asarray(camera.wxyz, np.float64)).as_matrix()
    centre = np.asarray(camera.position, np.float64) + (0 if origin is None else origin)
    pose = np.concatenate([rotation, centre[:, None]], axis=1)
    return Cameras(pose, fx=focal, fy=focal, cx=width / 2, cy=height / 2, width=width, height=height)


def full_size_of(camera: viser.CameraHandle, full_size: int) -> int:
    """Pixels along the longer side of a still frame: the canvas's, at most ``full_size``."""
    return max(MOVING_SIZE, min(full_size, max(int(camera.image_width), int(camera.image_height))))


@dataclass
class Frame:
    """One frame drawn for a tab: pixels along its longer side, and seconds to render and send."""

    size: int
    seconds: float
    moving: bool


@dataclass
class TabState:
    """What one tab has asked for and been sent: versions count camera moves and setting changes."""

    client: viser.ClientHandle
    version: int = 0
    drawn_version: int = -1
    moved_at: float = 0.0
    full_drawn: bool = True
    frames: list[Frame] = field(default_factory=list)
    picture: viser.GuiImageHandle | None = None
    """The tab's picture in the panel, while frames go there (:attr:`BrowserRenderer.into_panel`)."""

    def due(self, now: float, still_after: float = STILL_AFTER) -> str | None:
        """``"moving"`` (a change not drawn yet: drawn small first, whatever comes next),
        ``"full"`` (still for ``still_after`` seconds and not drawn at full size yet) or None."""
        if self.version != self.drawn_version:
            return "moving"
        if now - self.moved_at >= still_after and not self.full_drawn:
            return "full"
        return None


class BrowserRenderer:
    """Draws a scene model into every connected tab from its own camera (see the module doc).

    ``render(cameras, outputs) -> [view]`` is any scene run's ``render``; ``near_far`` gives
    the depth range of depth pictures. :meth:`start` runs the drawing in a thread of its own;
    live training (:mod:`pointfield.viewer.training`) calls :meth:`draw_due` from its own
    thread instead, so that the model is never read while an optimizer step changes it.
    """

    def __init__(self, viewer: Viewer, render: Render, near_far: tuple[float, float], *,
                 full_size: int = DEFAULT_FULL_SIZE, moving_size: int = MOVING_SIZE, label: str = "show",
                 choices: Sequence[str] = SHOWN, into_panel: bool = False):
        self.viewer = viewer
        self.render = render
        self.near_far = near_far
        self.full_size = full_size
        self.moving_size = moving_size
        self.tabs: dict[int, TabState] = {}
        self.lock = threading.Lock()
        self.wake = threading.Event()
        self.enabled = True
        self.into_panel = into_panel
        """Frames go to a picture in each tab's panel instead of the 3D view's background
        (changed with :meth:`frames_to_panel`).

        A browser without a GPU draws the 3D view in software, for 250 ms after every
        background frame: 0.75 to 0.83 CPU seconds a frame at 1024 x 640, against 0.10
        for the same frame as a panel picture (``benchmarks/bench_browser_cost.py``). Live
        training (:mod:`pointfield.viewer.training`) sends its frames there."""
        self.shown = viewer.server.gui.add_dropdown(label, list(choices), initial_value=choices[0])
        self.shown.on_update(lambda _: self.invalidate())
        self._thread: threading.Thread | None = None
        self._stopped = threading.Event()
        viewer.on_client(self._connected)
        viewer.server.on_client_disconnect(self._disconnected)
        viewer.on_close.append(self.stop)

    # -- tabs -------------------------------------------------------------------------------------

    def _connected(self, client: viser.ClientHandle) -> None:
        with self.lock:
            self.tabs[client.client_id] = TabState(client)
        client.camera.on_update(lambda camera: self._moved(camera.client.client_id))

    def _disconnected(self, client: viser.ClientHandle) -> None:
        with self.lock:
            self.tabs.pop(client.client_id, None)

    def _moved(self, client_id: int) -> None:
        with self.lock:
            tab = self.tabs.get(client_id)
            if tab is not None:
                tab.version += 1
                tab.moved_at = time.monotonic()
                tab.full_drawn = False
        self.wake.set()

    def last_moved(self) -> float:
        """``time.monotonic()`` of the last camera move of any tab (0.0 when none moved yet)."""
        with self.lock:
            return max((tab.moved_at for tab in self.tabs.values()), default=0.0)

    def invalidate(self) -> None:
        """Redraw every tab at full size (the model or what is shown changed)."""
        with self.lock:
            for tab in self.tabs.values():
                tab.version += 1
                tab.full_drawn = False
        self.wake.set()

    # -- drawing ----------------------------------------------------------------------------------

    def draw_due(self, moving_only: bool = False) -> int:
        """Draw every frame that is due now (for each tab at most one); returns how many were drawn.

        ``moving_only``: leave full-size frames for later (training draws small frames only).
        """
        if not self.enabled:
            return 0
        drawn = 0
        with self.lock:
            tabs = list(self.tabs.values())
        for tab in tabs:
            with self.lock:
                kind = tab.due(time.monotonic())
                version = tab.version
            if kind is None or (moving_only and kind == "full") or not _has_camera(tab.client):
                continue
            moving = kind == "moving"
            size = self.moving_size if moving else full_size_of(tab.client.camera, self.full_size)
            started = time.perf_counter()
            finished = self.draw(tab, size, version)
            with self.lock:
                if finished:
                    tab.drawn_version = version
                    tab.full_drawn = not moving
                    tab.frames.append(Frame(size, time.perf_counter() - started, moving))
                    del tab.frames[:-1000]
            drawn += int(finished)
        return drawn

    @torch.no_grad()
    def draw(self, tab: TabState, size: int, version: int | None = None) -> bool:
        """Render ``tab``'s view with ``size`` pixels along the longer side and send it.

        A large frame is rendered in bands of rows of about :data:`BAND_PIXELS`; when the tab's
        camera moves meanwhile (its version is no longer ``version``) the frame is dropped and
        False returned, so that a slow full-size frame never holds up the moving ones.
        """
        cameras = camera_of(tab.client.camera, size, self.viewer.origin)
        width, height = int(cameras.width[0]), int(cameras.height[0])
        rows = max(1, BAND_PIXELS // width)
        bands = []
        for top in range(0, height, rows):
            if version is not None and tab.version != version:
                return False
            band = Cameras(cameras.camera_to_world, fx=cameras.fx, fy=cameras.fy, cx=cameras.cx,
                           cy=cameras.cy - top, width=width, height=min(rows, height - top))
            bands.append(as_numpy(self.render(band, ("rgb", "depth", "opacity"))[0]))
        view = {name: np.concatenate([band[name] for band in bands]) for name in bands[0]}
        image = picture(view, self.shown.value, *self.near_far)
        axis_cosine = cameras.rays(0).axis_cosine.double().numpy()
        z_depth = np.where(view["opacity"] > 0.5, view["depth"] * axis_cosine, NO_SURFACE_DEPTH)
        with _closed_tabs_ignored():
            if not self.into_panel:
                tab.client.scene.set_background_image(image, format="jpeg", jpeg_quality=85, depth=z_depth)
            elif tab.picture is None:
                tab.picture = tab.client.gui.add_image(image, label="live render", format="jpeg", jpeg_quality=85)
            else:
                tab.picture.image = image
            tab.client.flush()
        return True

    def clear(self) -> None:
        """Take the rendered frames off every tab: the background and the panel's pictures."""
        with self.lock:
            tabs = list(self.tabs.values())
        for tab in tabs:
            with _closed_tabs_ignored():
                tab.client.scene.set_background_image(None)
                if tab.picture is not None:
                    tab.picture.remove()
                    tab.picture = None

    def frames_to_panel(self, into_panel: bool) -> None:
        """Send frames to the panel's pictures (True) or the 3D view's background (False); on a
        change, the frames in the old place are taken off and every tab is drawn again."""
        if into_panel != self.into_panel:
            self.into_panel = into_panel
            self.clear()
            self.invalidate()

    def warm_up(self) -> None:
        """Render and encode one tiny frame now: kernel compilation and the image encoder's first
        use take seconds, which the page's first frame should not wait for."""
        camera = Cameras(np.eye(4)[:3], fx=8.0, fy=8.0, cx=4.0, cy=4.0, width=8, height=8)
        self.render(camera, ("rgb", "depth", "opacity"))
        imageio.v3.imwrite("<bytes>", np.zeros((8, 8, 3), np.uint8), extension=".jpeg")

    def start(self) -> BrowserRenderer:
        """Draw due frames in a thread of this renderer's own, until :meth:`stop`."""
        def loop() -> None:
            while not self._stopped.is_set():
                self.wake.wait(STILL_AFTER / 4)
                self.wake.clear()
                if not self._stopped.is_set():
                    self.draw_due()

        self._thread = threading.Thread(target=loop, name="pointfield-view-render", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stopped.set()
        self.wake.set()

    def frames(self) -> list[Frame]:
        """Every frame drawn so far, for every tab (the last 1,000 of each)."""
        with self.lock:
            return [frame for tab in self.tabs.values() for frame in tab.frames]


@contextmanager
def _closed_tabs_ignored() -> Iterator[None]:
    """A tab closed while its frame rendered: viser warns that the message goes nowhere, which is fine."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "Queued a .* on a closed connection")
        yield


def _has_camera(client: viser.ClientHandle) -> bool:
    """Whether the tab has reported its camera yet (viser asserts on reading it before)."""
    try:
        return client.camera.update_timestamp > 0 and client.camera.image_width > 0
    except AssertionError:
        return False


def depth_range_of(run: SceneRun) -> tuple[float, float]:
    """Near and far for depth pictures: the run's scene's :func:`depth_bounds`, else 0 to its extent."""
    try:
        return depth_bounds(run.scene)
    except SceneError:
        centres = run.scene.cameras.centers.double().numpy()
        return 0.0, float(np.linalg.norm(centres - centres.mean(0), axis=1).max() * 2 or 1.0)


@dataclass
class RunView:
    """A run on the page: the run and its renderer."""

    run: SceneRun
    renderer: BrowserRenderer


def show_run(viewer: Viewer, path: str | os.PathLike[str], name: str, *, device: str | None = None,
             full_size: int = DEFAULT_FULL_SIZE) -> RunView:
    """Add a nerf or splat run to the page: its training cameras and a server-rendered view of it.

    A splat run is also drawn by the browser itself as Gaussians (:mod:`pointfield.viewer.splats`);
    the *show* dropdown switches between those and the server's colour, depth and opacity.
    """
    run = load_run(Path(path), device)
    scene = run.scene
    with viewer.server.gui.add_folder(name):
        viewer.server.gui.add_markdown(f"{run.model_name} run, {run.task}  \n{Path(path).name}"
                                       + _scores_line(run))
        frustums = add_frustums(viewer, scene, f"/{name}/cameras", thumbnails=False, visible=False)
        shown = viewer.server.gui.add_checkbox("training cameras", initial_value=False)
        shown.on_update(lambda _: [setattr(frustum, "visible", shown.value) for frustum in frustums])
        if isinstance(run, SplatRun):
            node = f"/{name}/splats"
            splats = add_gaussians(viewer, run.gaussians, node)
            renderer = BrowserRenderer(viewer, run.render, depth_range_of(run), full_size=full_size,
                                       choices=("gaussians (browser)", *SHOWN))
            renderer.enabled = False

            def switch(_: Any) -> None:
                nonlocal splats
                in_browser = renderer.shown.value.startswith("gaussians")
                renderer.enabled = not in_browser
                if in_browser:
                    renderer.clear()
                    if splats is None:
                        splats = add_gaussians(viewer, run.gaussians, node)
                else:
                    # Removed, not hidden: the browser sorts hidden Gaussians on every camera move too.
                    if splats is not None:
                        splats.remove()
                        splats = None
                    renderer.invalidate()

            renderer.shown.on_update(switch)
        else:
            renderer = BrowserRenderer(viewer, run.render, depth_range_of(run), full_size=full_size)
        renderer.warm_up()
        view = RunView(run, renderer.start())
    viewer.first_look(*scene_framing(scene, back=1.0, lift=0.0))
    return view


def _scores_line(run: SceneRun) -> str:
    metrics = run.metrics
    if "psnr" not in metrics:
        return ""
    return f"  \nheld-out PSNR {metrics['psnr']:.2f} dB after {metrics.get('steps', '?')} steps"
