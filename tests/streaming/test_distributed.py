"""The streaming verbs on a real two-worker dask.distributed cluster: the one-process bytes."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

import pointfield
from pointfield.clouds.cloud import PointCloud
from pointfield.streaming import convert_folder, crop, downsample, merge, stats, tile

CHUNK = 3_000


@pytest.mark.parametrize(("kind", "mode"), [("laz", "centroid"), ("ply", "centroid"), ("laz", "nearest")])
def test_voxel_downsample_on_two_workers_is_byte_identical_to_one_process(tmp_path, data, dask_client, kind, mode):
    here, there = tmp_path / f"here.{kind}", tmp_path / f"there.{kind}"
    downsample(data[kind], here, 0.7, mode=mode, points=CHUNK)
    result = downsample(data[kind], there, 0.7, mode=mode, points=CHUNK, client=dask_client)
    assert result["output_points"] > 0
    assert there.read_bytes() == here.read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([here.name, there.name])


def test_every_random_crop_merge_and_stats_on_two_workers_match_one_process(tmp_path, data, dask_client):
    for name, run in {
        "every.laz": lambda out, **kw: downsample(data["laz"], out, every=3, points=CHUNK, **kw),
        "random.ply": lambda out, **kw: downsample(data["ply"], out, random=999, points=CHUNK, **kw),
        "crop.laz": lambda out, **kw: crop(data["laz"], out, box=[0, 0, 500_050, 1e8], points=CHUNK, **kw),
        "merge.las": lambda out, **kw: merge([data["laz"], data["las"]], out, points=CHUNK, **kw),
    }.items():
        run(tmp_path / f"one-{name}")
        run(tmp_path / f"two-{name}", client=dask_client)
        assert (tmp_path / f"two-{name}").read_bytes() == (tmp_path / f"one-{name}").read_bytes(), name
    assert stats(data["laz"], points=CHUNK, client=dask_client) == stats(data["laz"], points=CHUNK)


def test_tiles_on_two_workers_are_the_one_process_tiles(tmp_path, data, dask_client):
    one = tile(data["laz"], tmp_path / "one", 30.0, buffer=1.5, points=CHUNK)
    two = tile(data["laz"], tmp_path / "two", 30.0, buffer=1.5, points=CHUNK, client=dask_client)
    assert two["tiles"] == one["tiles"]
    for entry in one["tiles"]:
        assert (tmp_path / "two" / entry["file"]).read_bytes() == (tmp_path / "one" / entry["file"]).read_bytes()
    assert json.loads((tmp_path / "two" / "tiles.json").read_text())["tiles"] == one["tiles"]


def test_a_folder_of_scans_converts_one_task_per_file_as_one_process_does(tmp_path, dask_client):
    scans = tmp_path / "scans"
    scans.mkdir()
    rng = np.random.default_rng(1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for number in range(6):
            cloud = PointCloud(rng.normal(0, 20, (4_000, 3)).astype(np.float32), {"intensity": rng.random(4_000, np.float32)})
            pointfield.write(scans / f"{number:06d}.bin", cloud)
    one = convert_folder(scans, tmp_path / "one", ".laz", points=CHUNK)
    two = convert_folder(scans, tmp_path / "two", ".laz", points=CHUNK, client=dask_client)
    assert one["converted"] == two["converted"] == 6
    for number in range(6):
        name = f"{number:06d}.laz"
        assert (tmp_path / "two" / name).read_bytes() == (tmp_path / "one" / name).read_bytes()


def test_a_bad_file_in_a_folder_is_named_after_the_others_are_done(tmp_path, data, dask_client):
    scans = tmp_path / "scans"
    scans.mkdir()
    (scans / "good.laz").write_bytes(data["laz"].read_bytes())
    (scans / "bad.laz").write_bytes(data["laz"].read_bytes()[: len(data["laz"].read_bytes()) * 6 // 10])
    with pytest.raises(pointfield.PointfieldError, match=r"1 of 2 files .*bad\.laz: LAZ data is cut short"):
        convert_folder(scans, tmp_path / "out", ".ply", points=CHUNK, client=dask_client)
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["good.ply"]


def test_a_bad_input_fails_the_dask_job_with_the_file_named_and_no_output(tmp_path, data, dask_client):
    cut = tmp_path / "cut.ply"
    cut.write_bytes(data["ply"].read_bytes()[:-1000])
    with pytest.raises(pointfield.FormatError, match="cut.ply"):
        downsample(cut, tmp_path / "out.ply", 0.7, client=dask_client)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cut.ply"]


def test_the_command_line_starts_its_own_local_cluster_with_workers(tmp_path, data, capsys):
    from pointfield.cli import main

    here, there = tmp_path / "here.laz", tmp_path / "there.laz"
    assert main(["cloud", "downsample", str(data["laz"]), str(here), "--voxel", "0.7", "--no-progress"]) == 0
    assert main(["cloud", "downsample", str(data["laz"]), str(there), "--voxel", "0.7", "--workers", "2", "--no-progress"]) == 0
    assert there.read_bytes() == here.read_bytes()
