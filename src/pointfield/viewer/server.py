"""The viewer's page: a viser server bound to 127.0.0.1, its URL, the panel every source reports in.

:func:`start_viewer` binds ``host:port`` (the next free port when that one is taken, saying so)
and returns a :class:`Viewer`. Sources (:mod:`pointfield.viewer.sources`) add their scene nodes
and panel folders to it; :meth:`Viewer.serve` then waits until Ctrl-C and stops the server.

Coordinates: the page shows everything in *display* coordinates, ``real - origin``. The origin
is zero unless a source holds coordinates too large for the browser's float32 (LAS / UTM
scans, hundreds of kilometres from zero): the first such source picks a round origin near its
centre (:meth:`Viewer.recentre`) and every source after it is shifted by the same amount, so
that a scan and a mesh of the same place still line up. Whatever the page reports -- bounds,
a clicked point, where the camera looks -- is in real coordinates.
"""

from __future__ import annotations

import contextlib
import io
import threading
import time
from collections.abc import Callable

import numpy as np
import viser
import viser.transforms as vtf

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8080
RECENTRE_ABOVE = 1.0e4
"""A source with a coordinate beyond this (in its units) is shown relative to a round origin:
float32, which the browser draws with, keeps about 1 mm at 10 km but only 6 cm at 1,000 km."""


def url_of(host: str, port: int) -> str:
    """The page's address; an IPv6 host in brackets, the wildcard hosts as the loopback name."""
    shown = {"0.0.0.0": "localhost", "::": "localhost"}.get(host, host)
    return f"http://[{shown}]:{port}" if ":" in shown else f"http://{shown}:{port}"


def wxyz_of(rotation: np.ndarray) -> np.ndarray:
    """The unit quaternion ``(w, x, y, z)`` of a ``(3, 3)`` rotation matrix, as viser takes it."""
    return vtf.SO3.from_matrix(np.asarray(rotation, dtype=np.float64)).wxyz


class Viewer:
    """One page: the viser server, its address, a status line, and the display origin.

    ``server`` is the :class:`viser.ViserServer` (add nodes to ``server.scene``, controls to
    ``server.gui``); ``url`` the address to open; ``port_note`` says when the asked-for port
    was taken ("" otherwise).
    """

    def __init__(self, server: viser.ViserServer, host: str, asked_port: int):
        self.server = server
        self.host = host
        self.port = server.get_port()
        self.url = url_of(host, self.port)
        self.port_note = (f"port {asked_port} was taken; using {self.port}"
                          if asked_port not in (0, self.port) else "")
        self.origin = np.zeros(3)
        self.recentred = False
        self.framed = False
        """Whether a source has set where the camera starts (:meth:`first_look`)."""
        self._origin_note = server.gui.add_markdown("", order=0, visible=False)
        self._stop = threading.Event()
        self.on_close: list[Callable[[], None]] = []
        """Called when the page closes (before the server stops): renderers stop their threads."""
        self.extent = 0.0
        """The largest source's size (bounding-box diagonal, in its units): node sizes scale with it."""
        self.lit = False
        """Whether the environment map is on (:meth:`light_surfaces`)."""

    # -- coordinates ----------------------------------------------------------------------------

    def recentre(self, low: np.ndarray, high: np.ndarray) -> np.ndarray:
        """The display origin, chosen by the first source whose bounds ``low``/``high`` need one.

        A round point near the centre (to the nearest 10 units, say ``(636500, 849500, 100)``)
        when any coordinate is beyond :data:`RECENTRE_ABOVE`; zero otherwise. Once chosen it
        stays, for every later source.
        """
        low, high = np.asarray(low, np.float64), np.asarray(high, np.float64)
        if not self.recentred and np.all(np.isfinite(low)) and max(np.abs(low).max(), np.abs(high).max()) > RECENTRE_ABOVE:
            self.origin = np.round((low + high) / 2, -1)
            self.recentred = True
            x, y, z = self.origin
            self._origin_note.content = (
                f"**Coordinates** are shown relative to ({x:,.2f}, {y:,.2f}, {z:,.2f}); everything this "
                f"panel reports is in real coordinates."
            )
            self._origin_note.visible = True
        return self.origin

    def grow(self, low: np.ndarray, high: np.ndarray) -> None:
        """Note a source's bounds: the page's sizes (axes, frustums, point sizes) follow the largest."""
        diagonal = float(np.linalg.norm(np.asarray(high, np.float64) - np.asarray(low, np.float64)))
        if np.isfinite(diagonal):
            self.extent = max(self.extent, diagonal)

    def first_look(self, target: np.ndarray, eye: np.ndarray, up: np.ndarray | None = None) -> None:
        """Point every page's camera from ``eye`` at ``target`` (real coordinates), ``up`` up --
        unless an earlier source did: the first source shown frames the page.

        Pages opened later start there; pages already open (a browser can connect before a
        large file is read) are moved there too.
        """
        if self.framed:
            return
        self.framed = True
        position = np.asarray(eye, np.float64) - self.origin
        target = np.asarray(target, np.float64) - self.origin
        # The clipping planes follow the scene's size (viser's far plane is 1000 units by default).
        reach = 10 * max(self.extent, float(np.linalg.norm(position - target)), 1e-6)
        near, far = reach / 1e5, reach
        camera = self.server.initial_camera
        camera.near, camera.far = near, far
        if up is not None:
            up = np.asarray(up, np.float64)
            self.server.scene.set_up_direction(tuple(up))
            camera.up = tuple(up)
        camera.position = tuple(position)
        camera.look_at = tuple(target)
        for client in self.server.get_clients().values():
            with contextlib.suppress(AssertionError):  # no camera reported yet: it takes the initial one
                if up is not None:
                    client.camera.up_direction = tuple(up)
                client.camera.near, client.camera.far = near, far
                client.camera.position = tuple(position)
                client.camera.look_at = tuple(target)

    def light_surfaces(self) -> None:
        """Light the page for shaded surfaces (meshes) with viser's default environment map.

        The page starts without it (see :func:`start_viewer`): a mesh's faces turned from the
        default lights would otherwise be black.
        """
        if not self.lit:
            self.lit = True
            self.server.scene.configure_environment_map()

    # -- life -----------------------------------------------------------------------------------

    def on_client(self, callback: Callable[[viser.ClientHandle], None]) -> None:
        """Call ``callback(client)`` for every browser tab that connects, now and later."""
        self.server.on_client_connect(callback)

    def serve(self, until: Callable[[], bool] | None = None, poll: float = 0.2) -> None:
        """Keep serving until Ctrl-C (or ``until()`` turns true, or :meth:`close`); then stop the server.

        Ctrl-C is the way to stop, not an error: it returns normally.
        """
        try:
            while not self._stop.is_set() and not (until is not None and until()):
                time.sleep(poll)
        except KeyboardInterrupt:
            pass
        finally:
            self.close()

    def close(self) -> None:
        """Stop the server (idempotent)."""
        if not self._stop.is_set():
            self._stop.set()
            for callback in self.on_close:
                callback()
            with contextlib.redirect_stdout(io.StringIO()):  # viser prints "Server stopped"
                self.server.stop()


def start_viewer(host: str = DEFAULT_HOST, port: int = DEFAULT_PORT, label: str = "pointfield") -> Viewer:
    """Start a viser server on ``host:port`` (the next free port when it is taken; 0: any free port).

    viser prints a banner of its own; it is swallowed, so that the command prints one line with
    the URL (see :mod:`pointfield.cli.view`).
    """
    with contextlib.redirect_stdout(io.StringIO()):
        server = viser.ViserServer(host=host, port=port, label=label, verbose=False)
    server.gui.configure_theme(control_width="medium", show_share_button=False)
    # Only shaded surfaces need lighting: points, splats, frustums and server renders are flat.
    # Without a GPU, the browser spends seconds on the environment map and the shadow maps before
    # its first frame (with the torch-free start, bench_viewer.py's first frame of a 10 M-point LAZ
    # went from 11.1 s to 5.4 s), so the page starts without them and Viewer.light_surfaces adds
    # the map for meshes.
    server.scene.configure_default_lights(cast_shadow=False)
    server.scene.configure_environment_map(hdri=None)
    return Viewer(server, host, port)
