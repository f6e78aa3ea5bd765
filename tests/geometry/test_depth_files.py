"""Depth maps from ``render``: float32 ``.npy`` in scene units, and 16-bit PNGs of ``depth / scale``."""

from __future__ import annotations

import json

import imageio.v3 as iio
import numpy as np
import pytest

from pointfield.cli import main


def render_depths(run, out, *outputs: str) -> None:
    assert main(["splat", "render", str(run), "--frames", "2", "--rasterizer", "pointfield", "--out", str(out),
                 "--outputs", *outputs]) == 0


def test_splat_render_writes_each_depth_output_as_npy_and_16_bit_png_with_one_scale(splat_run, tmp_path):
    out = tmp_path / "depths"
    render_depths(splat_run, out, "depth", "median_depth")
    scale_file = json.loads((out / "depth_scale.json").read_text())
    assert scale_file["units"] == "scene units per PNG step" and scale_file["zero"] == "no surface"
    scale = scale_file["scale"]
    largest = 0
    for name in ("depth", "median_depth"):
        for index in range(2):
            depth = np.load(out / f"{name}_{index:03d}.npy")
            steps = iio.imread(out / f"{name}16_{index:03d}.png")
            assert depth.dtype == np.float32 and depth.shape == (24, 24)
            assert steps.dtype == np.uint16 and steps.shape == depth.shape
            assert np.abs(steps * scale - depth).max() <= scale  # within one step
            np.testing.assert_array_equal(steps == 0, depth == 0)  # 0: no surface, and only there
            assert (out / f"{name}_{index:03d}.png").exists()  # the picture, as before
            largest = max(largest, int(steps.max()))
    assert largest == 65535  # the largest depth of the render takes the last step
    assert not list(out.glob("color_*")) and not list(out.glob("opacity_*"))  # only what was asked for
    assert not list(out.glob(".*"))  # no temporary files left behind


def test_median_depth_is_zero_where_expected_depth_shows_little_opacity(splat_run, tmp_path):
    out = tmp_path / "depths"
    render_depths(splat_run, out, "depth", "median_depth")
    expected, median = np.load(out / "depth_000.npy"), np.load(out / "median_depth_000.npy")
    assert (median > 0).any() and (median == 0).any()
    assert ((median > 0) <= (expected > 0)).all()  # a median depth needs something on the ray


def test_a_render_without_depth_outputs_writes_no_depth_maps(splat_run, tmp_path):
    out = tmp_path / "colour"
    render_depths(splat_run, out, "rgb")
    assert sorted(path.name for path in out.iterdir()) == ["color_000.png", "color_001.png"]


def test_a_video_has_one_panel_per_output_asked_for(splat_run, tmp_path):
    out = tmp_path / "render.gif"
    render_depths(splat_run, out, "rgb", "median_depth")
    frames = iio.imread(out, index=None)
    assert frames.shape[:3] == (2, 24, 48)


def test_an_unknown_output_is_refused_before_anything_is_written(splat_run, tmp_path, capsys):
    out = tmp_path / "nothing"
    assert main(["splat", "render", str(splat_run), "--out", str(out), "--outputs", "normals"]) == 1
    assert "unknown render outputs ['normals']" in capsys.readouterr().err
    assert not out.exists()


def test_nerf_render_passes_the_outputs_asked_for(monkeypatch, tmp_path):
    asked = {}

    def fake_render(run, **options):
        asked.update(options)
        return {"out": str(options["out"]), "frames": 1, "path": options["path"]}

    monkeypatch.setattr("pointfield.fields.run.render", fake_render)
    assert main(["nerf", "render", str(tmp_path), "--out", str(tmp_path / "d"), "--outputs", "median_depth"]) == 0
    assert asked["outputs"] == ["median_depth"]
    assert main(["nerf", "render", str(tmp_path), "--out", str(tmp_path / "d")]) == 0
    assert tuple(asked["outputs"]) == ("rgb", "depth", "opacity")


@pytest.mark.parametrize(("depths", "scale"), [([0.0, 2.0, 4.0], 4.0 / 65535), ([0.0], 1.0)])
def test_the_png_scale_maps_the_largest_depth_to_the_last_step(depths, scale):
    from pointfield.viz.views import depth_png, depth_png_scale

    view = {"depth": np.array([depths], dtype=np.float32)}
    assert depth_png_scale([view], ["depth"]) == pytest.approx(scale)
    steps = depth_png(view["depth"], depth_png_scale([view], ["depth"]))
    assert steps[0, 0] == 0 and steps.max() == (65535 if max(depths) > 0 else 0)
