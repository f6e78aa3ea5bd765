"""What the browser viewer costs: first frame of a large scan, streaming frame rates, training with --view.

The claims (issue 15), all measured through headless Chromium (:mod:`pointfield.viewer.browser`):

1. ``pointfield view`` on a 10-million-point LAZ shows its first frame in the browser within 5 s:
   from starting the command to the first screenshot whose canvas shows the cloud (the browser
   already running, as a user's is; it opens the page the moment the command prints its URL).
   The decimated cloud that replaces the quick preview is timed too.
2. Server-side streaming while the camera moves, 256 x 256 frames on 2 CPU threads: splats at
   least 10 frames per second, the hash-grid field (ngp) at least 3; and a full-resolution frame
   once the camera stops.
3. Training with ``--view`` and one connected browser is at most 10 % slower per step than
   without: measured with the browser's camera still (watching training) and moving (orbiting
   all the time, the worst case). The browser runs on the same 2 cores, drawing with software
   WebGL; training sends its frames to a picture in the page's panel, and leaves the browser one
   of its threads while the camera moves (:mod:`pointfield.viewer.training`). Each model's timed
   runs come after one untimed watched run, whose first frame compiles the renderer's kernels
   (reported, once per process); the slowdown is given over whole runs (the verdict) and over
   each run's last four fifths of steps (what a step costs once the page has settled); runs
   beside a page that is open but not watching give the floor, what showing a viser page costs.

The LAZ file is generated here (laspy): an airborne-like scan -- scan lines swept across a
1 km x 1 km tile of smooth terrain, in acquisition order, with intensity, classification, GPS
time and colour -- written to ``bench-output/viewer/``. The runs of claim 2 are trained here on
lego at 100 x 100 unless given (``--ngp-run``, ``--splat-run``).

Run: ``make bench-viewer`` (or ``python benchmarks/bench_viewer.py``); the record goes to
``benchmarks/records/viewer.json``.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

import laspy
import numpy as np
import torch

from pointfield.viewer.browser import (
    SCENE_REGION,
    chromium,
    crop,
    object_pixels,
    open_page,
    screenshot,
    wait_for,
)

from harness import ROOT, Record, round_order

OUTPUT = ROOT / "bench-output" / "viewer"
LEGO = ROOT.parent / "shared" / "data" / "nerf" / "lego_blender"
FIRST_FRAME_TARGET = 5.0
FPS_TARGETS = {"splats": 10.0, "ngp": 3.0}
SLOWDOWN_TARGET = 0.10
OBJECT_PIXELS = 1500


# -- 1. first frame of a 10-million-point LAZ ----------------------------------------------------


def make_scan(path: Path, points: int, seed: int = 0) -> Path:
    """An airborne-like LAZ scan of ``points`` points (see the module doc); kept when it exists."""
    if path.is_file():
        with laspy.open(path) as reader:
            if reader.header.point_count == points:
                return path
    rng = np.random.default_rng(seed)
    per_line = 2000
    index = np.arange(points)
    line, position = np.divmod(index, per_line)
    sweep = np.where(line % 2 == 0, position, per_line - 1 - position) / per_line
    x = sweep * 1000 + rng.normal(0, 0.05, points)
    y = line * (1000 / (points // per_line)) + rng.normal(0, 0.05, points)
    z = 20 * np.sin(x / 100) + 10 * np.cos(y / 70) + rng.normal(0, 0.05, points)
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.offsets, header.scales = np.array([636000.0, 849000.0, 0.0]), np.array([0.01, 0.01, 0.01])
    scan = laspy.LasData(header)
    scan.x, scan.y, scan.z = 636000 + x, 849000 + y, 100 + z
    scan.intensity = (1000 + 500 * np.sin(x / 30) * np.cos(y / 40) + rng.normal(0, 20, points)).astype(np.uint16)
    scan.classification = np.where(z > 15, 5, 2).astype(np.uint8)
    scan.gps_time = index * 1e-5
    scan.red, scan.green = (x / 1000 * 65535).astype(np.uint16), (y / 1000 * 65535).astype(np.uint16)
    scan.blue = np.full(points, 30000, np.uint16)
    path.parent.mkdir(parents=True, exist_ok=True)
    scan.write(path)
    return path


def first_frame(browser, scan: Path) -> dict[str, float]:
    """Seconds from starting ``pointfield view`` to the first picture of the cloud, and to the full cloud."""
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    started = time.perf_counter()
    process = subprocess.Popen([sys.executable, "-m", "pointfield", "view", str(scan), "--port", "0"],
                               stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env)
    try:
        line = process.stdout.readline()
        url = line.split("open ", 1)[1].split(";")[0].split(" ")[0]
        printed = time.perf_counter() - started
        page = open_page(browser, url)

        def seen():
            return object_pixels(crop(screenshot(page, canvas_only=True), SCENE_REGION)) >= OBJECT_PIXELS or None

        wait_for(seen, 60, "the cloud in the browser", poll=0.02)
        first = time.perf_counter() - started
        wait_for(lambda: ("showing 2," in page.inner_text("body") and "preview" not in page.inner_text("body"))
                 or None, 120, "the decimated cloud", poll=0.1)
        full = time.perf_counter() - started
        page.close()
        return {"url_printed": printed, "first_frame": first, "full_cloud": full}
    finally:
        process.terminate()
        process.wait(30)


# -- 2. streaming while the camera moves ---------------------------------------------------------


def train_runs(ngp: Path | None, splats: Path | None, seconds: float) -> tuple[Path, Path]:
    """The runs streamed: given, or trained on lego at 100 x 100 for ``seconds`` each (kept for next time)."""
    from pointfield.fields.train import train as train_field
    from pointfield.splats.train import train as train_splats

    common = {"downscale": 8, "holdout_every": 10, "max_training_time": seconds, "progress": False}
    if ngp is None:
        ngp = OUTPUT / "lego-ngp"
        if not (ngp / "metrics.json").is_file():
            train_field(LEGO, model="ngp", out=ngp, resume=ngp.exists(), **common)
    if splats is None:
        splats = OUTPUT / "lego-splats"
        if not (splats / "metrics.json").is_file():
            train_splats(LEGO, out=splats, resume=splats.exists(), **common)
    return ngp, splats


def stream(browser, run: Path, server_render: bool, seconds: float) -> dict[str, float]:
    """Frames per second drawn while the camera orbits for ``seconds``, and the still frame after."""
    from pointfield.viewer import open_viewer

    viewer, [view] = open_viewer([run], port=0)
    try:
        renderer = view.renderer
        if server_render:  # a splat run starts with the browser drawing the Gaussians
            renderer.shown.value = "rgb"
        page = open_page(browser, viewer.url, viewport=(1024, 1024))
        client = wait_for(lambda: next(iter(viewer.server.get_clients().values()), None), 60, "the tab")
        wait_for(lambda: any(not f.moving for f in renderer.frames()) or None, 120, "a first full frame")
        centre = np.asarray(client.camera.look_at, np.float64)
        offset = np.asarray(client.camera.position, np.float64) - centre
        before = len(renderer.frames())
        tab = next(iter(renderer.tabs.values()))
        version = tab.version
        began = time.perf_counter()
        while time.perf_counter() - began < seconds:
            angle = 2 * np.pi * (time.perf_counter() - began) / 20  # a turn in 20 s
            rotation = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
            client.camera.position = tuple(centre + rotation @ offset)
            time.sleep(0.01)
        updates = tab.version - version  # camera updates that came back from the browser
        moving = [f for f in renderer.frames()[before:] if f.moving]
        stopped = time.perf_counter()
        wait_for(lambda: any(not f.moving for f in renderer.frames()[before:]) or None, 120, "the still frame")
        still = [f for f in renderer.frames()[before:] if not f.moving][-1]
        page.close()
        return {
            "fps": len(moving) / seconds, "frames": len(moving), "camera_updates_per_s": updates / seconds,
            "moving_ms": 1000 * statistics.median(f.seconds for f in moving) if moving else float("nan"),
            "moving_size": moving[0].size if moving else 0,
            "still_size": still.size, "still_s": still.seconds, "still_after_s": time.perf_counter() - stopped,
        }
    finally:
        viewer.close()


# -- 3. training with --view -----------------------------------------------------------------------


def shown(value: float, form: str) -> str:
    """``value`` formatted for a table with ``form`` (``"{:.2f}"``), or a dash where nothing was measured (NaN)."""
    return "-" if math.isnan(value) else form.format(value)


class StepClock:
    """A training watcher that notes when each step ended (:func:`pointfield.training.loop.watched_by`)."""

    def __init__(self) -> None:
        self.ended: list[float] = []

    def after_step(self, model, state, loss: float) -> float:
        self.ended.append(time.perf_counter())
        return 0.0

    def seconds_per_step(self, after: int) -> float:
        """Mean seconds per step over the steps after the first ``after``."""
        kept = self.ended[after:]
        return (kept[-1] - kept[0]) / max(len(kept) - 1, 1)


def train_beside_page(browser, out: Path, train: Callable[[Path], tuple[float, float]], camera: str,
                      watched: bool) -> tuple[tuple[float, float], dict[str, float] | None]:
    """``train(out)`` beside a fresh viser page in ``browser``: watched live (a
    :class:`~pointfield.viewer.training.TrainingView`) or only open, its camera ``"still"`` or
    orbiting all the time (``"moving"``). Returns what ``train`` returned and, when watched, what
    the view saw (:func:`what_the_view_saw`: read before the page closes, which takes its tab's
    frames with it)."""
    from pointfield.viewer.server import start_viewer
    from pointfield.viewer.training import TrainingView

    viewer = start_viewer(port=0)
    view = TrainingView(viewer, out) if watched else None
    page = open_page(browser, viewer.url)
    moving = threading.Event()

    def orbit() -> None:
        while moving.is_set():
            for client in viewer.server.get_clients().values():
                try:
                    x, y, z = client.camera.position
                    client.camera.position = (0.99 * x - 0.14 * y, 0.14 * x + 0.99 * y, z)
                except AssertionError:  # the tab has not reported its camera yet
                    pass
            time.sleep(0.1)

    try:
        wait_for(lambda: viewer.server.get_clients() or None, 60, "the tab")
        if camera == "moving":
            moving.set()
        mover = threading.Thread(target=orbit, daemon=True)
        mover.start()
        try:
            with view if view is not None else contextlib.nullcontext():
                result = train(out)
        finally:
            moving.clear()
            mover.join()
        return result, (what_the_view_saw(view) if view is not None else None)
    finally:
        page.close()
        viewer.close()


def what_the_view_saw(view) -> dict[str, float]:
    """A finished watched run's viewing cost, steps on one thread fewer, frames sent, and first
    frame's seconds (NaN when none was drawn)."""
    drawn = view.renderer.frames() if view.renderer is not None else []
    return {"viewing_share": view.viewing_share(), "steps_sharing": view.steps_sharing / max(view.steps, 1),
            "frames": view.frames_during_training, "first_frame_s": drawn[0].seconds if drawn else float("nan")}


def training_cost(browser, kind: str, steps: int, rounds: int, camera: str, warm_up: bool) -> dict[str, float]:
    """Seconds per training step with and without a watched page (``camera`` "still" or "moving"), interleaved.

    With the camera still, runs beside a page that is open but not watching (nothing sent to it)
    give the floor: what the browser costs by merely showing a viser page. ``warm_up``: one watched
    run first, untimed, whose first frame compiles the renderer's kernels for rendering without
    gradients at the frame's size (seconds, once per process); its first frame is reported.
    """
    from pointfield.fields.train import train as train_field
    from pointfield.splats.train import train as train_splats
    from pointfield.training.loop import watched_by

    def train(out: Path) -> tuple[float, float]:
        """Seconds per step over the whole run, and over its steps after the first fifth (steady state)."""
        clock = StepClock()
        with watched_by(clock):
            if kind == "splats":
                metrics = train_splats(None, out=out, steps=steps, eval_every=steps, eval_views=1, cube_views=40,
                                       cube_size=64, initial_splats=5000, progress=False)
            else:
                metrics = train_field(None, model="ngp", out=out, steps=steps, eval_every=steps, cube_views=40,
                                      cube_size=64, progress=False)
        return metrics["training_seconds"] / metrics["steps"], clock.seconds_per_step(after=steps // 5)

    variants = ("without", "with", "page") if camera == "still" else ("without", "with")
    per_step: dict[str, list[float]] = {variant: [] for variant in variants}
    steady: dict[str, list[float]] = {variant: [] for variant in variants}
    seen: list[dict[str, float]] = []
    compiling_frame = float("nan")
    with tempfile.TemporaryDirectory() as folder:
        def run(variant: str, label: str):
            out = Path(folder) / f"{kind}-{label}-{variant}"
            if variant == "without":
                return train(out), None
            return train_beside_page(browser, out, train, camera, watched=variant == "with")

        if warm_up:
            _, warm = run("with", "warm-up")
            compiling_frame = warm["first_frame_s"]
        for round_ in range(rounds):
            for variant in round_order(variants, round_):
                (whole, settled), watched = run(variant, str(round_))
                per_step[variant].append(whole)
                steady[variant].append(settled)
                if watched is not None:
                    seen.append(watched)
    ms = {variant: 1000 * statistics.median(per_step[variant]) for variant in variants}
    steady_ms = {variant: 1000 * statistics.median(steady[variant]) for variant in variants}
    page_only = {"page_ms": ms["page"], "page_slowdown": ms["page"] / ms["without"] - 1,
                 "steady_page_slowdown": steady_ms["page"] / steady_ms["without"] - 1} if "page" in ms else {}
    return {"without_ms": ms["without"], "with_ms": ms["with"], "slowdown": ms["with"] / ms["without"] - 1,
            "steady_without_ms": steady_ms["without"], "steady_with_ms": steady_ms["with"],
            "steady_slowdown": steady_ms["with"] / steady_ms["without"] - 1, **page_only,
            **{name: statistics.median(run[name] for run in seen) for name in seen[0]},
            "warm_up_first_frame_s": compiling_frame, "runs": rounds, "camera": camera,
            "threads": torch.get_num_threads()}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=10_000_000, help="points of the generated LAZ scan")
    parser.add_argument("--repeats", type=int, default=3, help="first-frame measurements (median)")
    parser.add_argument("--stream-seconds", type=float, default=10.0, help="seconds of camera motion per model")
    parser.add_argument("--ngp-run", type=Path, help="hash-grid run to stream (default: train one on lego)")
    parser.add_argument("--splat-run", type=Path, help="splat run to stream (default: train one on lego)")
    parser.add_argument("--train-seconds", type=float, default=180.0, help="training time of each lego run made here")
    parser.add_argument("--steps", type=int, default=150, help="training steps per run of claim 3")
    parser.add_argument("--rounds", type=int, default=2, help="interleaved runs with and without the page")
    parser.add_argument("--only", choices=("first-frame", "stream", "training"), help="measure one claim")
    args = parser.parse_args()
    torch.set_num_threads(2)

    record = Record(
        "viewer", "The browser viewer: first frame, streaming, training with --view", issue="15",
        about=f"Everything through headless Chromium (SwiftShader WebGL, no GPU) on this "
              f"machine's CPU; torch on 2 threads. First frame: `pointfield view` on a generated {args.points:,}-point "
              "LAZ scan, from starting the command to the first screenshot whose canvas shows the cloud (the "
              "quick preview), and to the decimated 2-million-point cloud replacing it; median of "
              f"{args.repeats}. Streaming: the browser's camera orbits for {args.stream_seconds:.0f} s while the "
              "server renders 256 x 256 frames of lego (100 x 100 training views) into a 1024 x 1024 page, then "
              "stops, and the server renders one frame the canvas's size. Training: per-step training time "
              "(metrics' training_seconds / steps) of splats and ngp on the synthetic cube, with and without "
              "a watched page (and, camera still, beside a page open but not watching), interleaved, after one "
              "untimed watched run; the page's camera still, then orbiting all the time.",
    )
    with chromium() as browser:
        if args.only in (None, "first-frame"):
            scan = make_scan(OUTPUT / f"scan-{args.points // 1_000_000}M.laz", args.points)
            runs = [first_frame(browser, scan) for _ in range(args.repeats)]
            first = statistics.median(r["first_frame"] for r in runs)
            full = statistics.median(r["full_cloud"] for r in runs)
            record.figures["first_frame"] = {"runs": runs, "median_first_frame": first, "median_full_cloud": full}
            record.table(["file", "points", "URL printed s", "first frame s", "decimated cloud s"],
                         [[scan.name, f"{args.points:,}", f"{statistics.median(r['url_printed'] for r in runs):.2f}",
                           f"{first:.2f}", f"{full:.2f}"]], title="first frame in the browser")
            record.verdict(f"first frame of a {args.points:,}-point LAZ within {FIRST_FRAME_TARGET:.0f} s",
                           first <= FIRST_FRAME_TARGET, f"{first:.2f} s")
        if args.only in (None, "stream"):
            ngp, splats = train_runs(args.ngp_run, args.splat_run, args.train_seconds)
            rows = []
            for name, run in (("splats", splats), ("ngp", ngp)):
                result = stream(browser, run, server_render=name == "splats", seconds=args.stream_seconds)
                record.figures[f"stream_{name}"] = result
                rows.append([name, f"{result['moving_size']}", f"{result['camera_updates_per_s']:.1f}",
                             f"{result['fps']:.1f}", f"{result['moving_ms']:.0f}", f"{1000 / result['moving_ms']:.1f}",
                             f"{result['still_size']}", f"{result['still_s']:.2f}"])
                record.verdict(f"{name} stream at least {FPS_TARGETS[name]:.0f} fps at 256 x 256 while moving",
                               result["fps"] >= FPS_TARGETS[name], f"{result['fps']:.1f} fps")
            record.table(["model", "moving px", "camera updates/s", "fps while moving", "median ms per frame",
                          "fps the renders allow", "still px", "still frame s"], rows,
                         title="server-side streaming, 2 threads")
            record.note("fps while moving counts the frames sent while the camera orbited; it cannot exceed the "
                        "camera updates the browser sent back. 'fps the renders allow' is 1000 / the median "
                        "milliseconds to render, encode and send one moving frame.")
        if args.only in (None, "training"):
            rows = []
            for kind in ("splats", "ngp"):
                for camera in ("still", "moving"):
                    cost = training_cost(browser, kind, args.steps, args.rounds, camera, warm_up=camera == "still")
                    record.figures[f"training_{kind}_{camera}"] = cost
                    rows.append([kind, camera, f"{cost['without_ms']:.1f}", f"{cost['with_ms']:.1f}",
                                 f"{100 * cost['slowdown']:+.1f} %", f"{100 * cost['steady_slowdown']:+.1f} %",
                                 shown(100 * cost.get("page_slowdown", math.nan), "{:+.1f} %"),
                                 shown(100 * cost.get("steady_page_slowdown", math.nan), "{:+.1f} %"),
                                 f"{100 * cost['viewing_share']:.1f} %", shown(cost["warm_up_first_frame_s"], "{:.2f}"),
                                 f"{cost['first_frame_s']:.2f}",
                                 f"{cost['frames']:.0f}", f"{100 * cost['steps_sharing']:.0f} %"])
                    record.verdict(f"{kind} training with --view, camera {camera}, at most "
                                   f"{100 * SLOWDOWN_TARGET:.0f} % slower per step",
                                   cost["slowdown"] <= SLOWDOWN_TARGET, f"{100 * cost['slowdown']:+.1f} %")
            record.table(["model", "browser camera", "ms per step without", "with --view", "slowdown",
                          "slowdown after the first fifth", "page open, not watching",
                          "page open, after the first fifth", "time in the viewer", "compiling first frame s",
                          "first frame s", "frames sent",
                          "steps on one thread fewer"], rows,
                         title="training with one connected browser on the same 2 cores")
            record.note("The browser draws with software WebGL on the same two cores. While training runs, frames "
                        "go to a picture in the page's panel; while the page's camera moves, training leaves the "
                        "browser one of its torch threads ('steps on one thread fewer'). 'time in the viewer' is "
                        "what the training thread spent rendering and sending frames (medians over the runs); the "
                        "rest of the slowdown is the browser's. 'slowdown' compares whole runs (training_seconds / "
                        "steps) and is what the verdict reads; 'after the first fifth' compares the mean time per "
                        "step over each run's last four fifths of steps, leaving out what a run pays once: the "
                        "page's start-up in the browser and the camera's first move. Before the timed runs of each "
                        "model, one watched run, untimed, compiles the renderer's kernels for rendering without "
                        "gradients in its first frame ('compiling first frame s', once per process); 'first frame s' "
                        "is the timed runs' first frame. 'page open, not watching' (camera still) are runs beside a viser "
                        "page that nothing is sent to: what showing the page costs by itself, the floor under "
                        "'slowdown'.")
    return record.finish()


if __name__ == "__main__":
    sys.exit(main())
