"""The viewer without a browser: what each PATH is, the command's errors and ports, decimation,
recentring, the browser's camera, and the quick preview of a large LAZ file."""

from __future__ import annotations

import json
import math
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

import pointfield
from pointfield.cli import main
from pointfield.errors import PointfieldError
from pointfield.viewer.clouds import decimate, laz_preview
from pointfield.viewer.fields import camera_of
from pointfield.viewer.server import start_viewer, wxyz_of
from pointfield.viewer.sources import kind_of


def test_each_path_is_known_by_its_kind(cloud_file, splat_file, scene_folder, tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text(json.dumps({"task": "splat"}))
    assert [kind_of(p) for p in (cloud_file, splat_file, scene_folder, run)] == ["cloud", "splats", "scene", "run"]


def test_a_classifier_run_has_nothing_to_view(tmp_path):
    (tmp_path / "config.json").write_text(json.dumps({"task": "classify"}))
    with pytest.raises(PointfieldError, match="nothing to show in 3D"):
        kind_of(tmp_path)


def test_a_bad_path_is_the_one_line_error_of_every_command(capsys):
    assert main(["view", "no-such-scan.laz"]) == 1
    assert capsys.readouterr().err == "pointfield: error: no-such-scan.laz: no such file or directory\n"


def test_a_taken_port_gets_the_next_free_one_and_says_so():
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        viewer = start_viewer(port=port)
        try:
            assert viewer.port != port
            assert viewer.port_note == f"port {port} was taken; using {viewer.port}"
            assert viewer.url == f"http://127.0.0.1:{viewer.port}"
        finally:
            viewer.close()


def test_decimation_keeps_exactly_the_budget_in_file_order():
    kept = decimate(1_000_000, 100_000)
    assert len(kept) == 100_000
    assert np.all(np.diff(kept) > 0)
    assert decimate(1_000, 100_000) is None


def test_the_command_s_defaults_are_the_viewer_s():
    # cli/view.py repeats them so that `pointfield --help` does not import viser.
    from pointfield.cli import view as command
    from pointfield.viewer import clouds, server

    assert (command.DEFAULT_HOST, command.DEFAULT_PORT) == (server.DEFAULT_HOST, server.DEFAULT_PORT)
    assert command.DEFAULT_MAX_POINTS == clouds.DEFAULT_MAX_POINTS


def test_the_page_says_how_many_points_it_shows_and_reports_real_coordinates(served, cloud_file):
    viewer, [view] = served([cloud_file], max_points=5_000)
    assert "showing 5,000 of 20,000 points" in view.status.content
    assert "x 500,000" in view.status.content  # the bounds in the file's own coordinates
    assert viewer.origin.tolist() == [500_010.0, 4_200_010.0, 100.0]
    # A click's ray through a shown point reports that point in real coordinates.
    target = view.display[123].astype(np.float64)
    event = SimpleNamespace(ray_origin=target + [0, 0, 0.05], ray_direction=(0.0, 0.0, -1.0))
    view._picked(event)
    x, y, _ = view.shown.points[123]
    assert f"x {x:,.3f}, y {y:,.3f}" in view.clicked.content


def test_the_browser_camera_becomes_an_opencv_camera_looking_where_it_looks():
    # A viser camera at (0, -5, 0) looking at the origin with +z up: OpenCV axes x right, y down, z forward.
    rotation = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])  # columns: the camera's x, y, z in the world
    browser = SimpleNamespace(wxyz=wxyz_of(rotation), position=np.array([0.0, -5.0, 0.0]), fov=math.radians(60),
                              image_width=400, image_height=200)
    cameras = camera_of(browser, longest_side=256)
    assert (int(cameras.width[0]), int(cameras.height[0])) == (256, 128)
    pixels, depth = cameras.project(torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64))
    assert pixels[0, 0].tolist() == pytest.approx([128, 64])
    assert depth[0, 0].item() == pytest.approx(5.0)
    assert pixels[0, 1, 1].item() < 64  # world up is image up
    assert float(cameras.fy[0]) == pytest.approx(64 / math.tan(math.radians(30)))


def test_a_large_laz_file_is_previewed_from_the_first_points_of_each_chunk(shared_data):
    path = shared_data / "las" / "autzen_trim.laz"
    preview, total = laz_preview(path, 20_000)
    assert total == 110_000
    assert 20_000 <= len(preview.points) < 25_000
    assert preview.points[:, 0].min() > 636_000 and preview.points[:, 0].max() < 637_200
    full = pointfield.read(path)
    assert set(preview.fields) == set(full.fields)  # every field, as the reader gives them
    row_of = {tuple(point): row for row, point in enumerate(full.points.tolist())}
    rows = [row_of[tuple(point)] for point in preview.points.tolist()]
    for name, values in preview.fields.items():
        np.testing.assert_array_equal(values, full.fields[name][rows], err_msg=name)


def test_pointfield_view_prints_its_url_moves_off_a_taken_port_and_stops_on_ctrl_c(cloud_file, checkout_environment):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        command = [sys.executable, "-m", "pointfield", "view", str(cloud_file), "--port", str(port)]
        # SIGINT at its default: a child started while the test process ignores SIGINT (as some
        # earlier test's library leaves it) would inherit the ignoring, and Python then installs
        # no KeyboardInterrupt handler, so Ctrl-C could not be tested.
        process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                   env=checkout_environment, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # noqa: PLW1509 (only a signal reset)
        try:
            first = process.stdout.readline()
            assert first.startswith("pointfield view: open http://127.0.0.1:")
            assert f"(port {port} was taken; using" in first
            process.send_signal(signal.SIGINT)
            out, err = process.communicate(timeout=60)
        finally:
            process.kill()
    assert process.returncode == 0, err
    assert out.strip().endswith("pointfield view: stopped")


def test_a_cloud_is_coloured_by_any_of_its_fields(served, cloud_file):
    viewer, [view] = served([cloud_file])
    assert list(view.colour_by.options) == ["rgb", "height", "intensity"]
    assert view.colour_by.value == "rgb"
    node = viewer.server.scene.get_handle_by_name("/bumps/points")
    as_rgb = np.array(node.colors)
    view.colour_by.value = "intensity"
    assert not np.array_equal(np.array(node.colors), as_rgb)
    view.point_size.value = view.point_size.max
    assert node.point_size == view.point_size.max


def test_a_splat_run_s_gaussians_leave_the_page_while_the_server_renders_it(served, splat_run):
    # Hidden Gaussians would still be sorted by the browser on every camera move (3.8 fps streamed).
    viewer, [view] = served([splat_run])
    scene, node = viewer.server.scene, f"/{splat_run.name}/splats"
    assert scene.get_handle_by_name(node) is not None and not view.renderer.enabled
    view.renderer.shown.value = "rgb"
    assert scene.get_handle_by_name(node) is None and view.renderer.enabled
    view.renderer.shown.value = "gaussians (browser)"
    assert scene.get_handle_by_name(node) is not None and not view.renderer.enabled


def test_training_leaves_a_browser_on_this_machine_one_thread_while_its_camera_moves(tmp_path):
    # OpenMP threads preempted by a local browser stall each other: splat steps were 50x slower
    # while the browser drew a moving camera's view; with the camera still they need both threads.
    from pointfield.training.loop import TrainingState
    from pointfield.viewer.fields import BrowserRenderer, TabState
    from pointfield.viewer.training import BROWSER_BUSY_AFTER_MOVE, TrainingView

    viewer = start_viewer(port=0)
    try:
        view = TrainingView(viewer, tmp_path / "run")
        view._attaching = threading.Thread(target=lambda: None)  # no run to open: only the threads are watched
        view._attaching.start()
        renderer = BrowserRenderer(viewer, lambda cameras, outputs: [], (0.0, 1.0))
        renderer.enabled = False  # nothing drawn: the tab below has no browser behind it
        renderer.tabs[0] = TabState(client=None)
        threads_seen = []

        def train_watched() -> None:
            torch.set_num_threads(2)
            with view:
                view.after_step(None, TrainingState(), 0.1)
                threads_seen.append(torch.get_num_threads())  # no renderer yet
                view.renderer = renderer
                view.after_step(None, TrainingState(step=1), 0.1)
                threads_seen.append(torch.get_num_threads())  # the camera never moved
                renderer._moved(0)
                view.after_step(None, TrainingState(step=2), 0.1)
                threads_seen.append(torch.get_num_threads())  # it moves
                renderer.tabs[0].moved_at -= BROWSER_BUSY_AFTER_MOVE
                view.after_step(None, TrainingState(step=3), 0.1)
                threads_seen.append(torch.get_num_threads())  # still again
                renderer._moved(0)
                view.after_step(None, TrainingState(step=4), 0.1)
                threads_seen.append(torch.get_num_threads())
                renderer.tabs.clear()  # before training ends and the final model is drawn
            threads_seen.append(torch.get_num_threads())  # training ended while it moved

        training = threading.Thread(target=train_watched)
        training.start()
        training.join(30)
        assert threads_seen == [2, 2, 1, 2, 1, 2]
        assert (view.steps, view.steps_sharing) == (5, 2)
    finally:
        viewer.close()


def test_the_point_size_follows_the_cloud_that_replaces_the_preview(tmp_path):
    from pointfield.clouds.cloud import PointCloud
    from pointfield.viewer.clouds import CloudView, prepare, typical_spacing

    points = np.random.default_rng(0).uniform(0, 100, (40_000, 3))
    viewer = start_viewer(port=0)
    try:
        view = CloudView(viewer, tmp_path / "scan.laz", "scan")
        view.show(prepare(PointCloud(points[:500]), 40_000, total=40_000, preview=True))
        assert view.point_size.value == pytest.approx(typical_spacing(points.min(0), points.max(0), 500), rel=0.5)
        view.show(prepare(PointCloud(points), 40_000))
        assert view.point_size.value == pytest.approx(typical_spacing(points.min(0), points.max(0), 40_000), rel=0.5)
    finally:
        viewer.close()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_the_reading_worker_dies_with_a_killed_viewer(checkout_environment):
    # A viewer killed while its worker sent back a large cloud left the worker blocked for ever.
    script = (
        "import os, time, multiprocessing\n"
        "from concurrent.futures import ProcessPoolExecutor\n"
        "from pointfield.viewer.clouds import start_worker\n"
        "pool = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context('fork'), initializer=start_worker,"
        " initargs=(os.getpid(),))\n"
        "print(pool.submit(os.getpid).result(), flush=True)\n"
        "pool.submit(time.sleep, 60)\n"
        "time.sleep(0.5)\n"
        "os._exit(0)\n"  # no clean shutdown: as when the viewer is killed
    )
    viewer = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=checkout_environment, timeout=60,
                            check=True)
    worker = int(viewer.stdout.split()[0])
    deadline = time.monotonic() + 10
    while Path(f"/proc/{worker}").exists() and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not Path(f"/proc/{worker}").exists()


def test_a_page_of_clouds_does_not_import_torch(checkout_environment):
    # torch takes a second or two to import: the first frame of a scan should not wait for it.
    code = ("import sys, pointfield.cli.view, pointfield.viewer.sources, pointfield.viewer.clouds; "
            "print(sorted(m for m in sys.modules if m == 'torch' or m.startswith('torch.')))")
    imported = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=checkout_environment,
                              check=True)
    assert imported.stdout.strip() == "[]"


def test_the_first_frame_of_a_watched_run_does_not_set_the_pace(tmp_path):
    # The first frame compiles the renderer's kernels (2 s on the benchmark's splats): paced by it,
    # the page went 40 s (at a twentieth of the time) without a second picture. Later frames are
    # paced by what they cost.
    from pointfield.viewer.training import BROWSER_SECONDS_PER_FRAME, TrainingView

    viewer = start_viewer(port=0)
    try:
        view = TrainingView(viewer, tmp_path / "run", render_share=0.05)
        first = view.frame_interval(2.0, 1)
        assert first == pytest.approx(BROWSER_SECONDS_PER_FRAME / 0.05)
        assert view.frame_interval(0.03, 1) == pytest.approx((0.03 + BROWSER_SECONDS_PER_FRAME) / 0.05)
        assert view.frame_interval(0.5, 1) == pytest.approx((0.03 + BROWSER_SECONDS_PER_FRAME) / 0.05)  # one slow frame
        assert view.frame_interval(0.5, 2) == pytest.approx((0.5 + 2 * BROWSER_SECONDS_PER_FRAME) / 0.05)  # slow frames
    finally:
        viewer.close()


def test_what_viewing_cost_is_a_share_of_the_watched_time_only(tmp_path):
    # The page's "viewing cost" and the benchmark's "time in the viewer" read the same share; once
    # training ends it stops counting, however long the page stays up.
    from pointfield.viewer.training import TrainingView

    viewer = start_viewer(port=0)
    try:
        view = TrainingView(viewer, tmp_path / "run")
        with view:
            time.sleep(0.05)
            view.viewing_seconds = 0.02
            assert 0 < view.viewing_share() < 0.4
        finished = view.viewing_share()
        time.sleep(0.05)
        assert view.viewing_share() == finished
        assert finished == pytest.approx(0.02 / (view.finished_at - view.started))
    finally:
        viewer.close()
