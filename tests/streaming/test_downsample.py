"""Streaming downsample: the in-memory result, bit for bit, whatever the chunks and the memory."""

from __future__ import annotations

import struct

import numpy as np
import pytest

import pointfield
from pointfield.clouds.formats.las import chunks as las_chunks
from pointfield.clouds.ops import voxel_downsample
from pointfield.streaming import downsample, jobs, voxels
from pointfield.streaming.downsampling import random_sample
from pointfield.streaming.memory import MemoryPlan
from pointfield.streaming.voxels import voxel_nearest

CHUNK = 3_000


@pytest.mark.parametrize("kind", ["laz", "ply", "bin"])
def test_voxel_centroids_are_the_in_memory_ones_exactly(tmp_path, data, written, kind):
    out = tmp_path / f"out.{kind}"
    result = downsample(data[kind], out, 0.9, points=CHUNK)
    expected = voxel_downsample(pointfield.read(data[kind]), 0.9)
    assert result["output_points"] == len(expected)
    assert out.read_bytes() == written(tmp_path / f"expected.{kind}", expected)


def test_one_chunk_many_chunks_and_a_tiny_memory_budget_give_the_same_bytes(tmp_path, data, monkeypatch):
    downsample(data["laz"], tmp_path / "one.laz", 0.5, points=10**6)
    downsample(data["laz"], tmp_path / "many.laz", 0.5, points=1_000)
    # Any real budget holds this small cloud's voxels; shrink the state's share to 20 kB so
    # that voxel ranges are parked on disk and reduced one by one.
    monkeypatch.setattr(jobs, "plan", lambda budget, *args: MemoryPlan(256 << 20, 1_000, 20_000))
    parked = []
    park_one = voxels._park_one

    def counting_park_one(*args):
        parked.append(args)
        park_one(*args)

    monkeypatch.setattr(voxels, "_park_one", counting_park_one)
    downsample(data["laz"], tmp_path / "parked.laz", 0.5)
    assert parked, "the state was never parked: the test would prove nothing"
    # Parked state written to disk and read back in pieces of a few voxels.
    monkeypatch.setattr(voxels, "RECORDS_PIECE", 7)
    downsample(data["laz"], tmp_path / "pieces.laz", 0.5)
    one = (tmp_path / "one.laz").read_bytes()
    assert (tmp_path / "many.laz").read_bytes() == one
    assert (tmp_path / "parked.laz").read_bytes() == one
    assert (tmp_path / "pieces.laz").read_bytes() == one
    assert sorted(p.name for p in tmp_path.iterdir()) == ["many.laz", "one.laz", "parked.laz", "pieces.laz"]


def test_nearest_to_centre_keeps_real_points_as_the_in_memory_reference_does(tmp_path, data, written):
    out = tmp_path / "out.ply"
    downsample(data["ply"], out, 0.9, mode="nearest", points=CHUNK)
    cloud = pointfield.read(data["ply"])
    expected = voxel_nearest(cloud, 0.9)
    assert out.read_bytes() == written(tmp_path / "expected.ply", expected)
    finite = cloud.points[np.isfinite(cloud.points).all(axis=1)]
    kept = {tuple(p) for p in finite.tolist()}
    assert all(tuple(p) in kept for p in pointfield.read(out).points.tolist())


def test_every_and_random_keep_the_points_the_in_memory_rules_keep(tmp_path, data, written):
    cloud = pointfield.read(data["laz"])
    downsample(data["laz"], tmp_path / "every.laz", every=7, points=CHUNK)
    downsample(data["laz"], tmp_path / "random.laz", random=5_000, seed=4, points=CHUNK)
    assert (tmp_path / "every.laz").read_bytes() == written(tmp_path / "e.laz", cloud.select(slice(0, None, 7)))
    chosen = cloud.select(random_sample(len(cloud), 5_000, seed=4))
    assert (tmp_path / "random.laz").read_bytes() == written(tmp_path / "r.laz", chosen)


@pytest.mark.parametrize("shift", [-3.0, +0.7])
def test_a_stale_las_header_costs_a_pass_not_a_wrong_result(tmp_path, data, written, shift):
    # min x is at byte 187 of the LAS header: make it lower than the points (a loose header) or
    # higher (points outside the header's box): either way the grid must start at the points.
    stale = bytearray(data["laz"].read_bytes())
    (min_x,) = struct.unpack_from("<d", stale, 187)
    struct.pack_into("<d", stale, 187, min_x + shift)
    path = tmp_path / "stale.laz"
    path.write_bytes(bytes(stale))
    downsample(path, tmp_path / "out.laz", 0.9, points=CHUNK)
    downsample(data["laz"], tmp_path / "fresh.laz", 0.9, points=CHUNK)
    expected = voxel_downsample(pointfield.read(data["laz"]), 0.9)
    assert np.array_equal(pointfield.read(tmp_path / "out.laz").points, pointfield.read(tmp_path / "fresh.laz").points)
    assert (tmp_path / "fresh.laz").read_bytes() == written(tmp_path / "expected.laz", expected)


def test_a_killed_job_leaves_no_output_and_a_rerun_skips_a_finished_one(tmp_path, data, monkeypatch, capsys):
    out = tmp_path / "out.laz"
    real_write = las_chunks.LasChunkWriter._write
    calls = []

    def dying_write(self, cloud):
        calls.append(len(cloud))
        if len(calls) == 2:
            raise KeyboardInterrupt
        real_write(self, cloud)

    monkeypatch.setattr(las_chunks.LasChunkWriter, "_write", dying_write)
    with pytest.raises(KeyboardInterrupt):
        downsample(data["laz"], out, 0.2, points=CHUNK)
    assert list(tmp_path.iterdir()) == []
    monkeypatch.setattr(las_chunks.LasChunkWriter, "_write", real_write)

    assert not downsample(data["laz"], out, 0.2, points=CHUNK)["skipped"]
    finished = out.read_bytes()
    assert downsample(data["laz"], out, 0.2, points=CHUNK)["skipped"]
    assert "skipped" in capsys.readouterr().err
    assert out.read_bytes() == finished


def test_exactly_one_rule_is_required(tmp_path, data):
    with pytest.raises(pointfield.PointfieldError, match="exactly one"):
        downsample(data["laz"], tmp_path / "out.laz", 0.5, every=3)
