"""The voxel accumulator's sorting and index helpers, against the numpy calls they replace."""

from __future__ import annotations

import numpy as np
import pytest

from pointfield.streaming.voxels import merge_places, merged, stable_key_order


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
