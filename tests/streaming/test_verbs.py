"""crop, tile, merge, stats and convert, streamed: each equals its in-memory definition."""

from __future__ import annotations

import json

import numpy as np
import pytest

import pointfield
from pointfield.cli import main
from pointfield.clouds.cloud import PointCloud
from pointfield.streaming import convert_folder, crop, merge, stats, tile
from pointfield.streaming.cropping import crop_cloud
from pointfield.streaming.merging import merge_clouds
from pointfield.streaming.tiling import tile_cloud

CHUNK = 3_000


def test_crop_to_a_box_keeps_the_points_inside_it_bounds_included(tmp_path, data, written):
    cloud = pointfield.read(data["laz"])
    low = cloud.points.min(axis=0)
    box = [low[0] + 10, low[1] + 5, low[0] + 60, low[1] + 50]
    result = crop(data["laz"], tmp_path / "box.laz", box=box, points=CHUNK)
    expected = crop_cloud(cloud, box=box)
    assert 0 < result["output_points"] == len(expected) < len(cloud)
    assert (tmp_path / "box.laz").read_bytes() == written(tmp_path / "e.laz", expected)
    assert np.all((expected.points[:, 0] >= box[0]) & (expected.points[:, 0] <= box[2]))


def test_crop_to_a_polygon_file_text_or_geojson(tmp_path, data, written):
    cloud = pointfield.read(data["laz"])
    x0, y0, _ = cloud.points.min(axis=0)
    triangle = np.array([[x0 + 5, y0 + 5], [x0 + 100, y0 + 10], [x0 + 40, y0 + 75]])
    (tmp_path / "area.txt").write_text("\n".join(f"{x} {y}" for x, y in triangle))
    ring = [*triangle.tolist(), triangle[0].tolist()]
    (tmp_path / "area.geojson").write_text(json.dumps({"type": "Feature", "geometry": {"type": "Polygon", "coordinates": [ring]}}))
    expected = crop_cloud(cloud, polygon=triangle)
    assert 0 < len(expected) < len(cloud)
    for name in ("area.txt", "area.geojson"):
        crop(data["laz"], tmp_path / f"{name}.laz", polygon=tmp_path / name, points=CHUNK)
        assert (tmp_path / f"{name}.laz").read_bytes() == written(tmp_path / "e.laz", expected)


def test_tiles_with_a_buffer_are_the_in_memory_tiles(tmp_path, data, written):
    cloud = pointfield.read(data["ply"])
    result = tile(data["ply"], tmp_path / "tiles", 25.0, buffer=2.0, points=CHUNK)
    expected = tile_cloud(cloud, 25.0, buffer=2.0)
    assert [tuple(t["tile"]) for t in result["tiles"]] == list(expected)
    for entry in result["tiles"]:
        tile_file = tmp_path / "tiles" / entry["file"]
        assert tile_file.read_bytes() == written(tmp_path / "e.ply", expected[tuple(entry["tile"])])
    # A buffer copies border points into both neighbours.
    assert sum(t["points"] for t in result["tiles"]) > len(cloud) - cloud.nan_count
    manifest = json.loads((tmp_path / "tiles" / "tiles.json").read_text())
    assert manifest["tiles"] == result["tiles"]
    assert tile(data["ply"], tmp_path / "tiles", 25.0, buffer=2.0, points=CHUNK)["skipped"]


def test_merge_concatenates_in_order_keeping_the_fields_every_input_has(tmp_path, data, written, make_lidar):
    other = make_lidar(5_000, seed=3)
    del other.fields["gps_time"]
    second = tmp_path / "second.laz"
    written(second, other)
    with pytest.warns(UserWarning, match="gps_time"):
        result = merge([data["laz"], second], tmp_path / "merged.laz", points=CHUNK)
    clouds = [pointfield.read(data["laz"]), pointfield.read(second)]
    expected = merge_clouds(clouds)
    assert result["output_points"] == 45_000
    assert "gps_time" not in expected.fields
    assert (tmp_path / "merged.laz").read_bytes() == written(tmp_path / "e.laz", expected)


def test_stats_in_one_pass_are_those_of_the_whole_cloud(data):
    info = stats(data["laz"], points=CHUNK)
    cloud = pointfield.read(data["laz"])
    assert info["points"] == len(cloud) and info["nonfinite_points"] == 0
    assert info["bounds"]["min"] == cloud.points.min(axis=0).tolist()
    values, counts = np.unique(cloud.fields["classification"], return_counts=True)
    assert info["classes"] == {str(v): int(c) for v, c in zip(values, counts)}
    assert info["field_ranges"]["intensity"] == {"min": float(cloud.fields["intensity"].min()),
                                                 "max": float(cloud.fields["intensity"].max())}
    assert info["field_ranges"]["colors"]["max"] == cloud.fields["colors"].max(axis=0).astype(float).tolist()
    with_nan = stats(data["ply"], points=CHUNK)
    assert with_nan["nonfinite_points"] == pointfield.read(data["ply"]).nan_count > 0


def test_the_command_line_runs_every_streaming_verb(tmp_path, data, capsys):
    common = ["--points", str(CHUNK), "--no-progress"]
    assert main(["cloud", "downsample", str(data["laz"]), str(tmp_path / "v.laz"), "--voxel", "1", *common]) == 0
    assert main(["cloud", "downsample", str(data["laz"]), str(tmp_path / "n.ply"), "--voxel", "1", "--nearest", *common]) == 0
    assert main(["cloud", "crop", str(data["laz"]), str(tmp_path / "c.laz"), "--box", "0", "0", "1e9", "1e9", *common]) == 0
    assert main(["cloud", "tile", str(data["laz"]), str(tmp_path / "t"), "--size", "50", *common]) == 0
    assert main(["cloud", "merge", str(data["laz"]), str(data["las"]), str(tmp_path / "m.las"), *common]) == 0
    assert main(["cloud", "convert", str(data["laz"]), str(tmp_path / "x.ply"), *common]) == 0
    assert main(["cloud", "info", str(data["laz"]), "--stats", "--json", *common]) == 0
    out = capsys.readouterr().out
    assert json.loads(out[out.index("{"):])["points"] == 40_000
    assert len(pointfield.read(tmp_path / "c.laz")) == 40_000
    assert len(pointfield.read(tmp_path / "m.las")) == 80_000
    assert main(["cloud", "downsample", str(data["laz"]), str(tmp_path / "v.laz"), "--voxel", "1", *common]) == 0
    assert "skipped" in capsys.readouterr().err


def test_the_command_line_names_the_file_of_a_bad_input(tmp_path, data, capsys):
    cut = tmp_path / "cut.ply"
    cut.write_bytes(data["ply"].read_bytes()[:-1000])
    assert main(["cloud", "downsample", str(cut), str(tmp_path / "out.ply"), "--voxel", "1", "--no-progress"]) == 1
    assert "cut.ply" in capsys.readouterr().err
    assert not (tmp_path / "out.ply").exists()


def test_a_folder_converts_file_by_file_and_a_rerun_skips_what_is_done(tmp_path, data, written):
    scans = tmp_path / "scans"
    (scans / "day2").mkdir(parents=True)
    rng = np.random.default_rng(0)
    for name in ("a.bin", "b.bin", "day2/c.bin"):
        written(scans / name, PointCloud(rng.random((500, 3), np.float32), {"intensity": rng.random(500, np.float32)}))
    first = convert_folder(scans, tmp_path / "out", ".ply")
    assert (first["converted"], first["skipped"]) == (3, 0)
    assert (tmp_path / "out" / "day2" / "c.ply").exists()
    again = convert_folder(scans, tmp_path / "out", ".ply")
    assert (again["converted"], again["skipped"]) == (0, 3)
