"""The demo: the built-in clouds round-trip through every format; failures are caught; a scene is reconstructed."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from pointfield.cli import main
from pointfield.cli.demo import (
    SCENE_QUICK_SETTINGS,
    RoundTrip,
    compare,
    demo_clouds,
    reconstruct_scene,
    round_trip,
    run_demo,
)
from pointfield.clouds import synthetic
from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.formats import format_named, formats
from pointfield.errors import PointfieldError


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    lines: list[str] = []
    out_dir = tmp_path_factory.mktemp("demo")
    report = run_demo(out_dir, quick=True, progress=False, print_fn=lines.append)
    return report, "\n".join(lines), out_dir


def test_every_round_trip_passes(demo):
    report, printed, _ = demo
    failures = [f"{t.path.name}: {t.problems}" for t in report.round_trips if not t.ok]
    assert report.all_ok, failures


def test_every_cloud_goes_through_every_writable_format_and_encoding(demo):
    report, _, _ = demo
    done = {(t.cloud, t.format, t.encoding) for t in report.round_trips}
    expected = {
        (cloud, fmt.name, encoding)
        for cloud in demo_clouds(quick=True)
        for fmt in formats()
        if fmt.write is not None
        for encoding in fmt.encodings
    }
    assert done == expected


def test_the_table_has_a_row_per_file_and_a_summary(demo):
    report, printed, out_dir = demo
    for trip in report.round_trips:
        assert any(
            line.split()[:3] == [trip.cloud, trip.format, trip.encoding]
            for line in printed.splitlines()
        )
    assert f"{len(report.round_trips)} of {len(report.round_trips)} round trips ok" in printed
    assert str(out_dir) in printed


def test_lossless_formats_keep_every_field(demo):
    report, _, _ = demo
    for trip in report.round_trips:
        if trip.format in ("ply", "pcd", "npy", "npz") and not trip.skipped:
            assert trip.fields_kept == trip.fields_total, trip.path.name


def test_an_stl_round_trip_is_checked_triangle_by_triangle(tmp_path):
    # STL stores each triangle's corners: the mesh comes back with its vertices renumbered, and the
    # demo still checks every corner (and that the normals it cannot hold are named in a warning).
    trip = round_trip("icosphere", synthetic.icosphere(1), format_named("stl"), "binary", tmp_path / "ico.stl")
    assert trip.ok and not trip.skipped and "faces" in trip.extras_kept, trip.problems
    assert "normals dropped" in trip.notes


def test_renders_and_contact_sheet_are_written(demo):
    report, _, _ = demo
    assert len(report.renders) == len(demo_clouds(quick=True))
    for path in [*report.renders, report.contact_sheet]:
        with Image.open(path) as png:
            pixels = np.asarray(png.convert("RGB"))
        assert (pixels != 255).any(axis=2).mean() > 0.02, path.name


def test_cli_demo_exits_zero_and_writes_the_sheet(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path), "--quick"]) == 0
    assert "round trips ok" in capsys.readouterr().out
    assert (tmp_path / "clouds.png").is_file()


def test_the_scene_part_trains_both_models_and_exports_the_fields_geometry(demo):
    import imageio.v3 as iio

    from pointfield.clouds.formats import read

    report, printed, out_dir = demo
    scene = report.scene
    assert scene.runs == {"ngp": out_dir / "ngp-cube", "splats": out_dir / "splats-cube"}
    size = SCENE_QUICK_SETTINGS.size
    for model, run in scene.runs.items():
        metrics = scene.metrics[model]
        assert (run / "metrics.json").is_file()
        assert metrics["steps"] == getattr(SCENE_QUICK_SETTINGS, f"{model.rstrip('s')}_steps")
        assert f"held-out PSNR {metrics['psnr']:.2f} dB" in printed
        frames = iio.imread(scene.turntables[model], index=None)
        assert frames.shape[:3] == (SCENE_QUICK_SETTINGS.frames, size, 3 * size)  # colour | depth | opacity
        assert str(scene.turntables[model]) in printed
    assert len(read(scene.mesh).faces) > 0 and len(read(scene.cloud)) > 0
    for picture in scene.pictures:
        with Image.open(picture) as png:
            assert (np.asarray(png.convert("RGB")) != 255).any(axis=2).mean() > 0.01, picture.name


def test_the_demo_ends_with_what_to_look_at_and_the_next_commands(demo):
    _, printed, out_dir = demo
    ending = printed[printed.rindex("Look at:"):]
    assert str(out_dir / "clouds.png") in ending
    assert "Next:" in ending and "pointfield view" in ending and "pointfield nerf export" in ending


def test_a_second_demo_replaces_the_runs_of_the_first(demo, tmp_path):
    report, _, out_dir = demo
    (report.scene.runs["ngp"] / "left-by-the-first.txt").write_text("x")
    second = reconstruct_scene(out_dir, SCENE_QUICK_SETTINGS, progress=False, print_fn=lambda line: None)
    assert second.turntables["ngp"].is_file()
    assert not (second.runs["ngp"] / "left-by-the-first.txt").exists()


def test_the_scene_part_refuses_to_replace_a_folder_that_is_not_its_run(tmp_path):
    precious = tmp_path / "splats-cube" / "precious.txt"
    precious.parent.mkdir()
    precious.write_text("keep me")
    with pytest.raises(PointfieldError, match="something other than a run of the demo"):
        reconstruct_scene(tmp_path, SCENE_QUICK_SETTINGS, progress=False, print_fn=lambda line: None)
    assert precious.read_text() == "keep me"


def _trip() -> RoundTrip:
    return RoundTrip("c", "f", "e", path=None)  # type: ignore[arg-type]


def test_compare_flags_a_field_lost_without_a_warning():
    cloud = synthetic.sphere(50, seed=0)
    back = PointCloud(cloud.points.copy(), {"normals": cloud.fields["normals"]})
    trip = _trip()
    compare(cloud, back, "ply", warned="", trip=trip)
    assert not trip.ok and "colors" in trip.problems[0]
    trip = _trip()
    compare(cloud, back, "ply", warned="cannot hold 'colors'", trip=trip)
    assert trip.ok and trip.notes == ["colors dropped"]


def test_compare_flags_a_changed_dtype_except_in_formats_without_dtypes():
    cloud = synthetic.cube_surface(50, seed=0)
    back = PointCloud(
        cloud.points.astype(np.float64), {k: v.astype(np.float64) for k, v in cloud.fields.items()}
    )
    trip = _trip()
    compare(cloud, back, "ply", warned="", trip=trip)
    assert not trip.ok
    trip = _trip()
    compare(cloud, back, "text", warned="", trip=trip)
    assert trip.ok and trip.fields_kept == 2


def test_compare_allows_las_coordinates_within_half_their_scale():
    cloud = PointCloud(np.array([[1.0004, 2.0, 3.0]], np.float32))
    for moved, ok in [(0.0004, True), (0.0006, False)]:
        back = PointCloud(np.array([[1.0004 - moved, 2.0, 3.0]]), metadata={"scales": [0.001] * 3})
        trip = _trip()
        compare(cloud, back, "las", warned="", trip=trip)
        assert trip.ok is ok


def test_a_writer_that_raises_is_a_failed_row_not_a_crash(tmp_path, monkeypatch):
    import pointfield.cli.demo as demo_module

    def broken_write(*args, **kwargs):
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(demo_module, "write", broken_write)
    fmt = formats()[0]
    trip = demo_module.round_trip(
        "sphere", synthetic.sphere(20), fmt, fmt.encodings[0], tmp_path / "x"
    )
    assert not trip.ok and "disk on fire" in trip.problems[0]


def test_cli_demo_exits_non_zero_when_a_round_trip_loses_data(tmp_path, monkeypatch, capsys):
    import pointfield.cli.demo as demo_module

    real_read = demo_module.read

    def read_dropping_colors(*args, **kwargs):
        cloud = real_read(*args, **kwargs)
        cloud.fields.pop("colors", None)
        return cloud

    monkeypatch.setattr(demo_module, "read", read_dropping_colors)
    assert main(["demo", "--out", str(tmp_path), "--quick", "--clouds-only"]) == 1
    assert "FAILED: colors lost without a warning" in capsys.readouterr().out
