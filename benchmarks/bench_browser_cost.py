"""What a viewer page costs the browser drawing it, on this machine's CPU (issue 15's training claim).

``bench_viewer.py`` finds training with ``--view`` more than 10 % slower per step while a
browser on the same 2 cores draws the page, and attributes the rest of the slowdown (beyond the
viewer's own share) to the browser. This measures the browser's side directly: the CPU seconds
that headless Chromium's processes (:mod:`pointfield.viewer.browser`: software WebGL,
SwiftShader, at the tests' viewport) spend on one connected page, 10 s per phase:

- the page idle (viser's client redraws once a second);
- the page receiving a status text every 0.5 s, as a watched training run sends;
- the page receiving a 256 x 256 JPEG frame as the 3D view's background (what ``pointfield view``
  sends a nerf run's tab) every 1 s, then every 2 s; the browser's CPU per frame is what the
  frames add over the idle page;
- the same frame as a picture in the page's panel (what a watched training run sends) every 1 s.

The browser's processes are this process's descendants (playwright's driver starts Chromium), so
other browsers on the machine are not counted. Run: ``python benchmarks/bench_browser_cost.py``;
the record goes to ``benchmarks/records/browser-cost.json``.
"""

from __future__ import annotations

import sys
import time
from importlib.metadata import version

import numpy as np
import psutil

from pointfield.viewer.browser import VIEWPORT, chromium, open_page, wait_for
from pointfield.viewer.server import start_viewer

from harness import Record

PHASE_SECONDS = 10.0


def browser_cpu_seconds() -> float:
    """User + system CPU seconds of the Chromium processes under this one so far."""
    total = 0.0
    for process in psutil.Process().children(recursive=True):
        try:
            if "chrom" in process.name() or "headless" in process.name():
                times = process.cpu_times()
                total += times.user + times.system
        except psutil.Error:  # a renderer process that ended meanwhile
            pass
    return total


def phase(action, every: float) -> tuple[float, int]:
    """Browser CPU seconds over :data:`PHASE_SECONDS` while ``action(i)`` (None: nothing) runs every
    ``every`` s, and how many times it ran."""
    before, began, calls = browser_cpu_seconds(), time.perf_counter(), 0
    while time.perf_counter() - began < PHASE_SECONDS:
        if action is not None:
            action(calls)
            calls += 1
        time.sleep(every)
    return browser_cpu_seconds() - before, calls


def main() -> int:
    record = Record(
        "browser-cost", "What a viewer page costs the browser that draws it (software WebGL, same CPU)", issue="15",
        about=f"Headless Chromium (SwiftShader WebGL) at a {VIEWPORT[0]} x {VIEWPORT[1]} viewport on one "
              f"`pointfield view` page; CPU seconds of the browser's processes over {PHASE_SECONDS:.0f} s per "
              "phase: idle, a status text every 0.5 s, a 256 x 256 JPEG frame as the 3D view's background every 1 s "
              "and every 2 s, the same frame as a picture in the panel every 1 s.",
    )
    # A smooth picture, as renders are (noise would make every frame's JPEG larger than a render's).
    y, x = np.mgrid[0:256, 0:256] / 255.0
    frame = (np.stack([x, y, 0.5 * (x + y)], axis=-1) * 255).astype(np.uint8)
    with chromium() as browser:
        viewer = start_viewer(port=0)
        page = open_page(browser, viewer.url)
        try:
            wait_for(lambda: viewer.server.get_clients() or None, 60, "the tab")
            time.sleep(3.0)  # the page's first scene and layout, before anything is counted
            status = viewer.server.gui.add_markdown("step 0")

            def show_status(i: int) -> None:
                status.content = f"step {i}"

            def send_frame(i: int) -> None:
                viewer.server.scene.set_background_image(np.roll(frame, i, axis=1), format="jpeg", jpeg_quality=85)

            picture = viewer.server.gui.add_image(frame, label="live render", format="jpeg", jpeg_quality=85)

            def send_picture(i: int) -> None:
                picture.image = np.roll(frame, i, axis=1)

            time.sleep(1.0)  # the picture's first layout
            plan = [("idle page", None, 0.5), ("status text every 0.5 s", show_status, 0.5),
                    ("256 x 256 background frame every 1 s", send_frame, 1.0),
                    ("256 x 256 background frame every 2 s", send_frame, 2.0),
                    ("256 x 256 panel picture every 1 s", send_picture, 1.0)]
            phases = {name: (*phase(action, every), action in (send_frame, send_picture)) for name, action, every in plan}
        finally:
            page.close()
            viewer.close()
    idle = phases["idle page"][0]
    rows = []
    for name, (seconds, calls, frames) in phases.items():
        per_frame = (seconds - idle) / calls if frames and calls else None
        record.figures[name] = {"browser_cpu_seconds": seconds, "updates": calls, "share_of_a_core": seconds / PHASE_SECONDS,
                                "cpu_seconds_per_frame": per_frame}
        rows.append([name, f"{seconds:.2f}", f"{100 * seconds / PHASE_SECONDS:.0f} %", calls or "-",
                     "-" if per_frame is None else f"{per_frame:.2f}"])
    record.table(["page receives", f"browser CPU s in {PHASE_SECONDS:.0f} s", "of one core", "updates",
                  "CPU s per frame (over idle)"], rows, title="The browser's CPU while drawing one viewer page")
    record.note(f"viser's client ({version('viser')}) draws continuously for 250 ms after every scene message "
                "(RENDER_SETTLE_MS in its App.tsx), all of it in software here; status texts change only the "
                "panel, and so do pictures in it. Training on the same 2 cores loses what the browser takes: see "
                "bench_viewer.py.")
    return record.finish()


if __name__ == "__main__":
    sys.exit(main())
