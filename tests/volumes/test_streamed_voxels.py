"""Voxelizing a file a chunk at a time gives the in-memory grid."""

from __future__ import annotations

import numpy as np
import pytest

import pointfield
from pointfield.errors import PointfieldError
from pointfield.streaming.memory import MemoryPlan
from pointfield.volumes import voxelize_cloud
from pointfield.volumes.streamed import voxelize_file


def small_chunks(points: int, state_bytes: int):
    """A stand-in for streaming.memory.plan: chunks of ``points`` and ``state_bytes`` for the sums."""
    return lambda memory, bytes_per_point: MemoryPlan(1 << 30, points, state_bytes)


@pytest.mark.parametrize(("name", "size"), [("las/simple.las", 25.0), ("pcd/pcl_milk_color_binary_compressed.pcd", 0.005)])
def test_chunks_give_the_in_memory_voxels_counts_and_labels(shared_data, monkeypatch, name, size):
    path = shared_data / name
    whole = voxelize_cloud(pointfield.read(path), size)
    # Chunks of 97 points: every voxel's sums are merged across many chunks.
    monkeypatch.setattr("pointfield.volumes.streamed.plan", small_chunks(97, 1 << 30))
    streamed = voxelize_file(path, size)
    assert len(pointfield.read(path)) > 10 * 97
    assert np.array_equal(streamed.coords, whole.coords)
    assert np.array_equal(streamed.origin, whole.origin) and streamed.shape == whole.shape
    assert np.array_equal(streamed.fields["counts"], whole.fields["counts"])
    for field, values in whole.fields.items():
        if np.issubdtype(values.dtype, np.floating):
            assert np.allclose(streamed.fields[field], values, rtol=1e-6, atol=1e-6)
        elif field == "colors":
            assert np.abs(streamed.fields[field].astype(int) - values).max() <= 1
        else:
            assert np.array_equal(streamed.fields[field], values), field


def test_voxels_beyond_the_memory_left_for_them_are_refused(shared_data, monkeypatch):
    monkeypatch.setattr("pointfield.volumes.streamed.plan", small_chunks(200, 10_000))
    with pytest.raises(PointfieldError, match=r"simple\.las: the occupied voxels of 0\.5 need more than .* a voxel of"):
        voxelize_file(shared_data / "las/simple.las", 0.5)
