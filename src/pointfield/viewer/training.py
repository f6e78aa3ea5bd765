"""``nerf train --view`` and ``splat train --view``: a run watched live in the browser.

:class:`TrainingView` is a :class:`~pointfield.training.loop.Watcher`: inside
``with TrainingView(...)`` the training loop calls it after every optimizer step, in the
training thread (:func:`pointfield.training.loop.watched_by`). It shows, on the viewer's page:

- the model as it is now, rendered from the browser's camera through the one run interface
  (the run folder's :class:`~pointfield.scenes.run.SceneRun` around the live model), at
  :data:`~pointfield.viewer.fields.MOVING_SIZE` pixels -- colour, depth or opacity;
- the step, the training loss, the held-out PSNR of the last evaluation, steps per second;
- a pause / resume button: while paused, the loop waits (the clock leaves the pause out) and
  the view renders at full size whenever the camera stops.

Viewing must not slow training much. Frames are rendered in the training thread (so the model
is never read mid-step) only when a tab's camera moved or the model changed, and at most so often
that they take :data:`RENDER_SHARE` of the time: after a frame that took ``r`` seconds to render
and send, the next waits ``(r + BROWSER_SECONDS_PER_FRAME) / RENDER_SHARE`` seconds, counting what
a browser on the same machine spends drawing it (``r`` is the cheaper of that frame and the one
before: the first compiles kernels, :meth:`TrainingView.frame_interval`). While training runs,
frames go to a picture in the page's panel, not to the 3D view's background: a browser without a
GPU draws the 3D view in software, and a background frame costs it eight times the CPU of a panel
picture (:attr:`~pointfield.viewer.fields.BrowserRenderer.into_panel`). The page reports what
viewing cost so far.

A browser on the same machine draws the page on the same processors (all of it, without a GPU:
software WebGL). torch's OpenMP threads wait for each other at every operation, and when one of
them is preempted by the browser the rest wait with it: with bench_viewer.py's training set-up
(splats on the cube, 2 cores) and the browser drawing every frame into its 3D view, steps took
5x as long with the page's camera still and 50x with it moving; leaving the thread for the whole
run cost a hash-grid run a fifth of its speed by itself. The browser draws the 3D view
continuously while its camera moves; so while a tab on a page bound to the loopback address moves
its camera (and for :data:`BROWSER_BUSY_AFTER_MOVE` seconds after), training leaves it one
thread: torch's intra-op threads go down by one (never below one), and back up once the camera
is still. docs/viewer.md gives the figures (``python benchmarks/bench_viewer.py --only training``).
"""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path
from typing import Self

import torch
from torch import nn

from pointfield.runs import RUN_CLASSES
from pointfield.scenes.run import SceneRun
from pointfield.training.loop import TrainingState, watched_by
from pointfield.training.run import RunDirectory
from pointfield.viewer.fields import BrowserRenderer, depth_range_of
from pointfield.viewer.scenes import scene_framing
from pointfield.viewer.server import DEFAULT_HOST, DEFAULT_PORT, Viewer, start_viewer

RENDER_SHARE = 0.025
"""Most of the training time that frames for the browser may take (a fortieth: a picture about
every 5 s). Every message makes a browser without a GPU work on the same processors as training,
and the rates matter: in interleaved one-off runs (docs/viewer.md) a twentieth with the status
every 2 s cost splats +41 % and ngp +22 %, a fortieth with the status every 5 s +20 % and +3 %."""
BROWSER_SECONDS_PER_FRAME = 0.1
"""CPU seconds a browser without a GPU spends on one 256 x 256 panel picture, as measured by
``benchmarks/bench_browser_cost.py`` (0.10 at 55879af). Counted in each frame's cost (module doc)."""
BROWSER_BUSY_AFTER_MOVE = 1.0
"""Seconds after a tab's last camera move during which its browser counts as drawing."""
STATUS_EVERY = 5.0
"""Seconds between updates of the step, loss and PSNR on the page (each costs the browser a
layout: 0.02 to 0.04 CPU s, bench_browser_cost.py; see :data:`RENDER_SHARE` for why so seldom)."""
LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1")
"""A page bound to one of these is seen by a browser on this machine (see the module doc)."""


def live_run(directory: RunDirectory, model: nn.Module, device: torch.device) -> SceneRun:
    """The run folder's scene run around ``model``, the module being trained (not its checkpoint)."""
    config = directory.read_config()
    for run_class in RUN_CLASSES:
        if config.get("task") in run_class.tasks and issubclass(run_class, SceneRun):
            return run_class(directory, config, model, device)
    raise ValueError(f"{directory.path}: a {config.get('task')!r} run has no view to render")


class TrainingView:
    """The page of a run being trained (see the module doc); a context manager around training."""

    def __init__(self, viewer: Viewer, out: str | os.PathLike[str], render_share: float = RENDER_SHARE):
        self.viewer = viewer
        self.directory = RunDirectory(out)
        self.render_share = render_share
        self.renderer: BrowserRenderer | None = None
        """Set (from a thread of its own) once the run's scene is open: see :meth:`after_step`."""
        self._attaching: threading.Thread | None = None
        self.resumed = threading.Event()
        self.resumed.set()
        self.holding = threading.Event()
        """Set while the training loop waits in a pause."""
        self.viewing_seconds = 0.0
        """Seconds the loop spent in this view, pauses excluded: what viewing cost training."""
        self.started = time.perf_counter()
        self.finished_at: float | None = None
        """``time.perf_counter()`` when :meth:`finish` ran (None while watching)."""
        self.next_render = 0.0
        self.next_status = 0.0
        self.frames_during_training = 0
        self._previous_frame_seconds = 0.0
        self._last: tuple[TrainingState, float] | None = None
        self.threads_before: int | None = None
        """torch's threads before one was left to a local browser; None while none is."""
        self.steps_sharing = 0
        """Steps taken with a thread left to the browser (its camera moving)."""
        self.steps = 0
        self._threads_owner: int | None = None
        gui = viewer.server.gui
        with gui.add_folder("training"):
            self.status = gui.add_markdown(f"waiting for {self.directory.path} to start ...")
            self.pause_button = gui.add_button("pause")
        self.pause_button.on_click(lambda _: self.toggle_pause())

    # -- the page's controls --------------------------------------------------------------------

    def toggle_pause(self) -> None:
        """Pause training after the current step, or resume it."""
        if self.resumed.is_set():
            self.resumed.clear()
            self.pause_button.label = "resume"
        else:
            self.resumed.set()
            self.pause_button.label = "pause"

    @property
    def paused(self) -> bool:
        return not self.resumed.is_set()

    # -- the watcher ----------------------------------------------------------------------------

    def after_step(self, model: nn.Module, state: TrainingState, loss: float) -> float:
        """Update the page; render when due and cheap enough; wait while paused (see the module doc)."""
        entered = time.perf_counter()
        self._last = (state, loss)
        self._share_threads(self._browser_drawing())
        self.steps += 1
        self.steps_sharing += self.threads_before is not None
        if self._attaching is None:
            # Opening the run's scene can take seconds (the synthetic cube is rendered): not here.
            self._attaching = threading.Thread(target=self._attach, args=(model,), daemon=True,
                                               name="pointfield-view-attach")
            self._attaching.start()
        if entered >= self.next_status:
            self._report(state, loss)
            self.next_status = entered + STATUS_EVERY
        renderer = self.renderer
        if renderer is not None and entered >= self.next_render:
            renderer.invalidate()  # the model changed with this step
            drawn = renderer.draw_due(moving_only=True)
            if drawn:
                self.frames_during_training += drawn
                self.next_render = time.perf_counter() + self.frame_interval(time.perf_counter() - entered, drawn)
        self.viewing_seconds += time.perf_counter() - entered
        if not self.paused:
            return 0.0
        return self._hold(state, loss)

    def frame_interval(self, took: float, drawn: int) -> float:
        """Seconds until the next frames, after ``drawn`` frames that took ``took`` seconds to render and send.

        ``(r + drawn * BROWSER_SECONDS_PER_FRAME) / render_share``, where ``r`` is the cheaper of
        ``took`` and the frames before (0 for the first): the first frame of a run compiles the
        renderer's kernels (seconds, once), and paced by that alone the page would wait a minute
        or more for its second picture (2 s of compiling at a fortieth of the time: 84 s).
        Remembers ``took`` for the next call.
        """
        paced_by = min(took, self._previous_frame_seconds)
        self._previous_frame_seconds = took
        return (paced_by + drawn * BROWSER_SECONDS_PER_FRAME) / self.render_share

    def _hold(self, state: TrainingState, loss: float) -> float:
        """Wait while paused, the model drawn into the 3D view meanwhile; returns the seconds waited."""
        paused_at = time.perf_counter()
        self._share_threads(False)
        self._report(state, loss)
        self.holding.set()
        while not self.resumed.wait(0.05):
            renderer = self.renderer  # set meanwhile when the pause came before the scene was open
            if renderer is not None:
                renderer.frames_to_panel(False)  # training waits: the browser may draw all it likes
                renderer.draw_due()
        if self.renderer is not None:
            self.renderer.frames_to_panel(True)
        self.holding.clear()
        self._report(state, loss)
        return time.perf_counter() - paused_at

    # -- the threads left to a browser on this machine ------------------------------------------

    def _browser_drawing(self) -> bool:
        """Whether a browser on this machine is drawing the 3D view: a tab moved its camera lately."""
        renderer = self.renderer
        return (renderer is not None and self.viewer.host in LOOPBACK_HOSTS
                and time.monotonic() - renderer.last_moved() < BROWSER_BUSY_AFTER_MOVE)

    @property
    def threads_watched(self) -> int | None:
        """torch's threads training uses while one is left to the browser; None while none is."""
        return None if self.threads_before is None else max(1, self.threads_before - 1)

    def _share_threads(self, leave_one: bool) -> None:
        """Leave the browser one torch thread, or take it back; in the training thread (the setting is per thread)."""
        if leave_one and self.threads_before is None:
            self.threads_before = torch.get_num_threads()
            self._threads_owner = threading.get_ident()
            torch.set_num_threads(self.threads_watched)
        elif not leave_one and self.threads_before is not None:
            if self._threads_owner == threading.get_ident():
                torch.set_num_threads(self.threads_before)
            self.threads_before = None

    def _attach(self, model: nn.Module) -> None:
        device = next(model.parameters()).device
        run = live_run(self.directory, model, device)
        renderer = BrowserRenderer(self.viewer, run.render, depth_range_of(run), into_panel=True)
        self.viewer.first_look(*scene_framing(run.scene, back=1.0, lift=0.0))
        self.renderer = renderer

    def _report(self, state: TrainingState, loss: float) -> None:
        heldout = next((record["psnr"] for record in reversed(state.history) if "psnr" in record), None)
        lines = [
            "**paused**" if self.paused else ("**finished**" if self.finished_at is not None else "**training**"),
            f"step {state.step:,}, loss {loss:.5f}",
            f"held-out PSNR {heldout:.2f} dB" if heldout is not None else "held-out PSNR: after the first evaluation",
            f"viewing cost {100 * self.viewing_share():.1f} % of the time ({self.frames_during_training} frames)",
        ]
        self.status.content = "  \n".join(lines)

    def viewing_share(self) -> float:
        """What viewing cost training: :attr:`viewing_seconds` as a share of the time from this
        view's start to :meth:`finish` (to now while watching)."""
        end = time.perf_counter() if self.finished_at is None else self.finished_at
        return self.viewing_seconds / max(end - self.started, 1e-9)

    # -- around training --------------------------------------------------------------------------

    def __enter__(self) -> Self:
        """Start watching: every training loop calls this view after each step until :meth:`finish`."""
        self._watching = watched_by(self)
        self._watching.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        self.finish()

    def finish(self) -> None:
        """Stop watching; the page goes on showing the final model (rendered on camera moves)."""
        self._watching.__exit__(None, None, None)
        self._share_threads(False)
        self.finished_at = time.perf_counter()
        self.resumed.set()
        self.pause_button.visible = False
        if self._attaching is not None:
            self._attaching.join()
        if self.renderer is not None:
            self.renderer.frames_to_panel(False)
            self.renderer.invalidate()
            self.renderer.start()  # the final model, rendered from its own thread from now on
        if self._last is not None:
            self._report(*self._last)

    def serve(self) -> None:
        """Keep the page up (the trained model, rendered on camera moves) until Ctrl-C."""
        self.viewer.serve()


def watch_training(out: str | os.PathLike[str], host: str = DEFAULT_HOST, port: int = DEFAULT_PORT) -> TrainingView:
    """Start the page for the run that will train into ``out`` and start watching (``nerf train --view``).

    Call :meth:`TrainingView.finish` after training, then :meth:`TrainingView.serve`.
    """
    viewer = start_viewer(host, port, label=f"pointfield: {Path(out).name}")
    return TrainingView(viewer, out).__enter__()
