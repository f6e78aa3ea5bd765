"""The voxel accumulator: its sorting and index helpers against the numpy calls they replace, and its growth."""

from __future__ import annotations

import numpy as np
import pytest

from pointfield.clouds.cloud import PointCloud
from pointfield.streaming.voxels import (
    VoxelAccumulator,
    VoxelGrid,
    merge_places,
    merged,
    stable_key_order,
)


@pytest.mark.parametrize("span", [1, 50, 2**40, 2**61], ids=["one-key", "narrow", "wide", "too-wide-to-pack"])
def test_stable_key_order_is_numpys_stable_argsort(span):
    keys = np.random.default_rng(0).integers(0, span, 100_000, dtype=np.int64) + 7
    order, ordered = stable_key_order(keys)
    np.testing.assert_array_equal(order, np.argsort(keys, kind="stable"))
    np.testing.assert_array_equal(ordered, keys[order])
    empty_order, empty_keys = stable_key_order(np.zeros(0, np.int64))
    assert len(empty_order) == len(empty_keys) == 0


def test_merging_an_index_is_two_inserts():
    rng = np.random.default_rng(1)
    keys = np.sort(rng.choice(10**6, 3000, replace=False))
    taken = rng.random(3000) < 0.3
    old_keys, new_keys = keys[~taken], keys[taken]
    old_slots, new_slots = rng.permutation(len(old_keys)), np.arange(len(new_keys)) + 10**5
    places = merge_places(old_keys, new_keys)
    merged_keys, merged_slots = merged(old_keys, new_keys, *places), merged(old_slots, new_slots, *places)
    at = np.searchsorted(old_keys, new_keys)
    np.testing.assert_array_equal(merged_keys, np.insert(old_keys, at, new_keys))
    np.testing.assert_array_equal(merged_slots, np.insert(old_slots, at, new_slots))


def test_the_state_grows_ahead_of_need_only_up_to_its_share_of_the_budget():
    # Chunks of 10,000 new voxels each, never parked: unlimited, the arrays grow 1.5x at a time;
    # limited, they grow to the limit and past it only by what each chunk needs, so that the
    # state holds no more bytes than its share or its voxels, whichever is more.
    rng = np.random.default_rng(2)
    template = PointCloud(np.zeros((0, 3), np.float32), {"intensity": np.zeros(0, np.uint16)})
    grid = VoxelGrid.covering(np.zeros(3), np.full(3, 1000.0), 1.0)
    unlimited, limited = VoxelAccumulator(template), VoxelAccumulator(template, state_bytes=4_000_000)
    voxel_bytes = limited.record.itemsize + 16
    for chunk in range(8):
        points = np.column_stack([np.arange(10_000) + 0.5, np.full(10_000, chunk + 0.5), np.full(10_000, 0.5)])
        cloud = PointCloud(points.astype(np.float32), {"intensity": rng.integers(0, 100, 10_000).astype(np.uint16)})
        index = np.arange(10_000) + 10_000 * chunk
        for accumulator in (unlimited, limited):
            accumulator.add(grid, cloud, index)
        assert len(limited.state["key"]) <= max(len(limited), limited.growth_limit)
        assert limited.nbytes <= max(4_000_000, len(limited) * voxel_bytes)
    assert limited.growth_limit == 4_000_000 // voxel_bytes
    assert len(unlimited.state["key"]) > len(limited.state["key"]) == len(limited) == 80_000
