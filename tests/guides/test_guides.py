"""The README's and the guides' commands run, in the order written, as a new user would run them.

The commands are read from the pages' ``sh`` / ``console`` code blocks (the test reads the docs,
not a copy of them) and run through :func:`pointfield.cli.main` in one working folder, page after
page in :data:`PAGES`' order, so that a run trained on one line is there for the export on the
next, and a later page can use what the README made. A command that fails, or a page whose
commands name an option or file the code no longer knows, fails the test: a guide cannot drift
from the code unnoticed.

What the test changes, and why:

- The placeholder names of the pages (``scan.pcd``, ``nerf_synthetic/lego``, ``city.laz``, ...)
  are made to exist in the working folder, as links to real files of ../shared/data or as small
  generated files: :data:`SHARED` and :func:`make_inputs` are the one table of them. The docs'
  own ``../shared/data/...`` paths resolve there too.
- Work that takes minutes at the pages' settings runs with short settings, appended to or
  replacing the page's own (:data:`SHORT`): training stops after a few steps / seconds
  (``--steps``, ``--max-time``, ``--epochs``) and holds out fewer views; exports use a coarse grid
  and few cameras; renders few frames. The command is still the page's, with its verb, inputs,
  outputs and every other option. torch.compile is switched off (eager kernels, the same results)
  so that no command waits on a compiler.
- A few commands cannot run here and are skipped with the reason (:data:`NOT_RUN`): ``make``
  (it is the set-up itself), ``view`` and ``--view`` (a server until Ctrl-C; tests/viewer drive
  it in a browser), ``scene from-video`` (no video clip in the test data).

Time: the training and rendering commands set it. In one process, one torch thread, on the shared
2-core machine at a load average of 7 to 9 (other jobs running): the README page 163 s (43 commands;
the slowest, `nerf render` of the cube's orbit, 24 s), docs/geometry.md 65 s, docs/photos.md 20 s,
the other pages 5 s together; 254 s for the whole file. (Before these short settings the README
page alone took 12 to 20 minutes and ran outside `make test`.)
"""

from __future__ import annotations

import glob
import json
import re
import shlex
import time
from pathlib import Path

import numpy as np
import pytest

import pointfield
from pointfield.cli import main
from pointfield.clouds.cloud import PointCloud

ROOT = Path(__file__).resolve().parents[2]
PAGES = ("README.md", "docs/loading.md", "docs/photos.md", "docs/geometry.md", "docs/streaming.md",
         "docs/route.md", "docs/cameras.md")

SHARED = {
    "scan.pcd": "pcd/pcl_colored_cloud_binary.pcd",
    "scan.laz": "las/simple.laz",
    "city.laz": "las/autzen_trim.laz",
    "000008.bin": "kitti/mmdet3d_demo/000008.bin",
    "chair_0001.off": "modelnet/ModelNet10/chair/train/chair_0001.off",
    "nerf_synthetic/lego": "nerf/lego_blender",
    "nerf/lego_blender": "nerf/lego_blender",
    "fox": "nerf/fox_instant_ngp",
    "colmap_project": "colmap/tiny_phone_scene",
    "modelnet/ModelNet10": "modelnet/ModelNet10",
    "my_photos": "colmap/tiny_phone_scene/fotos",
    "b.pcd": "pcd/pcl_bunny_ascii.pcd",
    "c.off": "modelnet/ModelNet10/chair/train/chair_0002.off",
    "bun0.pcd": "registration/pcl_bun0.pcd",
    "bun4.pcd": "registration/pcl_bun4.pcd",
    "table.pcd": "segmentation/pcl_milk_cartoon_all_small_clorox.pcd",
    "frames": "rgbd/livingroom1_micro",
    "camera.json": "rgbd/livingroom1_micro/camera_primesense.json",
}
"""Placeholder name of the pages -> the real file of ../shared/data it stands for."""

SHORT = {
    ("classify", "train"): {"--epochs": "1", "--points": "64", "--batch-size": "8"},
    ("segment", "train"): {"--epochs": "1", "--points": "64", "--batch-size": "8"},
    ("nerf", "train"): {"--steps": "30", "--max-time": "5", "--holdout-every": "50", "--eval-every": "30",
                        "--downscale": "32"},
    ("splat", "train"): {"--steps": "30", "--max-time": "5", "--holdout-every": "50", "--eval-every": "30",
                         "--downscale": "32"},
    ("nerf", "exercise"): {"--epochs": "1"},
    ("nerf", "render"): {"--frames": "2"},
    ("splat", "render"): {"--frames": "2"},
    # A model trained for seconds is faint: pixels count from a lower opacity than a trained model needs.
    ("nerf", "export"): {"--resolution": "32", "--points": "2000", "--faces": "2000", "--frames": "4",
                         "--min-opacity": "0.05"},
    ("splat", "export"): {"--resolution": "32", "--points": "2000", "--faces": "2000", "--frames": "4",
                          "--min-opacity": "0.05"},
    ("scene", "make"): {"--views": "8", "--size": "16"},
    ("scene", "convert"): {"--downscale": "8"},
    ("scene", "from-images"): {"--max-size": "400"},
    ("scene", "from-rgbd"): {"--frames": "10", "--voxel": "0.03"},
}
"""Verb -> options set for the test (replacing the page's value, else appended), except those of
:data:`ONLY_IF_GIVEN` and :data:`ONLY_WITHOUT_DATA`."""
ONLY_IF_GIVEN = {("nerf", "export"): {"--points", "--faces"}, ("splat", "export"): {"--points", "--faces"},
                 ("nerf", "train"): {"--downscale"}, ("splat", "train"): {"--downscale"}}
"""An export's ``--points`` and ``--faces`` (the size of what it writes) are only replaced where the page
gives them: a ``--mesh`` export takes no ``--points``. (A training's ``--points``, per cloud, is always set.)
A training's ``--downscale 8`` becomes 32 (lego's 25 x 25 pixels): a field trained for seconds renders
every sample of every ray, so each later render and export costs in proportion to the pixels."""
DENSITY = {"--threshold": "0.1"}
"""A field trained for seconds is thin: its density reaches a tenth, not instant-ngp's level (2.5 / the box side)."""
ONLY_WITHOUT_DATA = {("classify", "train"): {"--shapes-per-class": "4"}, ("segment", "train"): {"--shapes-per-class": "4"}}
"""Set only when the training has no DATA folder: the built-in synthetic shapes (100 per class by
default), made and trained on for ten minutes on one thread when this was not applied."""

NOT_RUN_PROGRAMS = {"make": "the set-up itself (creates .venv and runs the suite)",
                    "python": "a benchmark, the command a figure of the page was printed by (minutes long)"}
"""Shell lines of another program than pointfield that are not run, with the reason."""
NOT_RUN = {
    "view": "serves a page until Ctrl-C; tests/viewer drive it in headless Chromium",
    "--view": "serves a page until Ctrl-C; tests/viewer/test_training_hook.py covers it",
    "from-video": "needs a video clip, and the test data has none",
    "walk.mp4": "needs a video clip, and the test data has none",
}


def page_commands(page: str) -> list[str]:
    """Every command line of the page's shell blocks, in order: each line of an ``sh`` block, the
    ``$ `` lines of a ``console`` block (the others are the output it shows)."""
    text = (ROOT / page).read_text(encoding="utf-8")
    lines = []
    for kind, block in re.findall(r"```(sh|bash|shell|console)\n(.*?)```", text, flags=re.DOTALL):
        for line in block.splitlines():
            line = line.strip()
            if kind == "console":
                line = line[2:] if line.startswith("$ ") else ""
            lines.append(line)
    return [line for line in lines if line and not line.startswith("#")]


def skip_reason(argv: list[str]) -> str | None:
    """Why a page's line is not run, or None. ``make`` skips the line ``make demo``, not ``pointfield
    scene make``: words of :data:`NOT_RUN` are pointfield's, the programs of :data:`NOT_RUN_PROGRAMS` are others'."""
    program = next((word for word in argv if "=" not in word), "")  # after any VAR=value
    if program in NOT_RUN_PROGRAMS:
        return NOT_RUN_PROGRAMS[program]
    for word, reason in NOT_RUN.items():
        if word == argv[0] or (argv[0] == "pointfield" and word in argv[1:3]) or word in argv:
            return reason
    return None


def shortened(argv: list[str]) -> list[str]:
    """``argv`` (after ``pointfield``) with :data:`SHORT`'s settings for its verb."""
    verb = tuple(argv[:2])
    settings = dict(SHORT.get(verb, {}))
    positional = [a for a in argv[2:] if not a.startswith("-")]
    if verb in ONLY_WITHOUT_DATA and not any(Path(a).exists() and Path(a).is_dir() for a in positional):
        settings.update(ONLY_WITHOUT_DATA[verb])
    if "density" in argv:
        settings.update(DENSITY)
    argv = list(argv)
    for option, value in settings.items():
        if option in argv:
            argv[argv.index(option) + 1] = value
        elif option not in ONLY_IF_GIVEN.get(verb, ()):
            argv += [option, value]
    return argv


def expanded(argv: list[str]) -> list[str]:
    """Shell globs (``tiles/*.laz``) expanded, as the shell would; a ``--pattern`` is quoted on the
    pages (``'*.bin'``) and left to pointfield."""
    out = []
    for previous, arg in zip(["", *argv[:-1]], argv, strict=True):
        pattern = any(c in arg for c in "*?[") and not arg.startswith("-") and previous != "--pattern"
        out += (sorted(glob.glob(arg)) if pattern else []) or [arg]
    return out


def make_inputs(work: Path, shared_data: Path) -> None:
    """The placeholders of :data:`SHARED` as links, and the few inputs made for the test."""
    for name, real in SHARED.items():
        path = work / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.symlink_to(shared_data / real)
    rng = np.random.default_rng(0)
    sweep = np.concatenate([rng.normal(0, 20, (2000, 3)), rng.random((2000, 1)), rng.integers(0, 32, (2000, 1))], 1)
    sweep.astype(np.float32).tofile(work / "sweep.bin")  # nuScenes: x y z intensity ring
    (work / "scans").mkdir()
    for index in range(2):
        (work / "scans" / f"{index:06d}.bin").symlink_to(shared_data / SHARED["000008.bin"])
    city = pointfield.read(work / "city.laz")
    low, high = city.points[:, :2].min(axis=0), city.points[:, :2].max(axis=0)
    middle, quarter = (low + high) / 2, (high - low) / 4
    ring = [[middle[0] - quarter[0], middle[1] - quarter[1]], [middle[0] + quarter[0], middle[1] - quarter[1]],
            [middle[0], middle[1] + quarter[1]], [middle[0] - quarter[0], middle[1] - quarter[1]]]
    polygon = {"type": "Polygon", "coordinates": [[[float(x), float(y)] for x, y in ring]]}
    (work / "park.geojson").write_text(json.dumps(polygon), encoding="utf-8")
    pointfield.write(work / "a.ply", PointCloud(rng.normal(size=(200, 3)).astype(np.float32)))


@pytest.fixture(scope="module")
def base(tmp_path_factory, shared_data):
    """The folder the pages' folders sit in, beside ``shared`` (for ../shared/data) and ``runs``,
    which every page shares: the README trains the runs that the geometry and route guides use."""
    folder = tmp_path_factory.mktemp("guides")
    (folder / "shared").symlink_to(shared_data.parent)
    (folder / "runs").mkdir()
    return folder


@pytest.fixture()
def work(base, shared_data, request):
    """A fresh folder for the page, with the inputs it names: its own outputs never meet another
    page's (both the README and docs/geometry.md write lego-cloud.ply), its runs are the shared ones."""
    folder = base / Path(request.node.callspec.params["page"]).stem
    folder.mkdir()
    make_inputs(folder, shared_data)
    (folder / "runs").symlink_to(base / "runs")
    return folder


@pytest.fixture()
def eager(monkeypatch):
    """No torch.compile: every hot loop eager (the same results), no command waits on a compiler."""
    from pointfield import compiling

    monkeypatch.setattr(compiling, "_compiler_available_for", lambda device_type: False)


@pytest.mark.parametrize("page", PAGES)
def test_the_pages_commands_run_in_the_order_written(page, work, eager, monkeypatch, capsys, one_torch_thread):
    monkeypatch.chdir(work)
    ran, skipped, seconds, not_made = 0, [], [], []
    for line in page_commands(page):
        argv = shlex.split(line, comments=True)
        reason = skip_reason(argv)
        if reason is None and any(arg.startswith(folder) for arg in argv for folder in not_made):
            reason = "reads what a command not run here wrote"
        if reason is not None:
            skipped.append(f"{line.split('#')[0].strip()}: {reason}")
            if reason == NOT_RUN_PROGRAMS["python"] and "--out" in argv:  # a benchmark's folder: pictures come from it
                not_made.append(argv[argv.index("--out") + 1])
            continue
        assert argv[0] == "pointfield", f"{page}: a shell line that is not a pointfield command: {line}"
        args = expanded(shortened(argv[1:]))
        if "--out" in args:
            Path(args[args.index("--out") + 1]).parent.mkdir(parents=True, exist_ok=True)
        started = time.perf_counter()
        code = main(args)
        seconds.append((time.perf_counter() - started, line.split("#")[0].strip()))
        err = capsys.readouterr().err
        assert code == 0, f"{page}: `{line}` (run as `pointfield {shlex.join(args)}`) exited {code}: {err[-1500:]}"
        ran += 1
    if not ran and not skipped:
        pytest.skip(f"{page} has no shell commands")  # loading.md: Python only, run by test_docs_loading.py
    slowest = "; ".join(f"{t:.1f} s {line}" for t, line in sorted(seconds, reverse=True)[:5])
    print(f"{page}: {ran} commands run in {sum(t for t, _ in seconds):.0f} s (slowest: {slowest}); not run: {skipped}")
