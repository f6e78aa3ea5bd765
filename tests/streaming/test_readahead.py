"""The read-ahead thread and the accumulator's sorting and index helpers it made worth speeding up."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from pointfield.errors import FormatError
from pointfield.streaming.readahead import read_ahead
from pointfield.streaming.voxels import merge_places, merged, stable_key_order


def test_read_ahead_gives_every_item_in_order_from_another_thread():
    threads = []

    def numbers():
        for n in range(50):
            threads.append(threading.current_thread())
            yield n

    assert list(read_ahead(numbers(), depth=2)) == list(range(50))
    assert threading.current_thread() not in threads


def test_an_error_while_reading_is_raised_where_its_item_would_have_come():
    def broken():
        yield 1
        yield 2
        raise FormatError("scan.laz", "LAZ data is corrupt in points 3 to 4")

    items = read_ahead(broken())
    assert [next(items), next(items)] == [1, 2]
    with pytest.raises(FormatError, match="scan.laz: LAZ data is corrupt"):
        next(items)


def test_leaving_the_loop_stops_the_reader_and_closes_its_source():
    closed = threading.Event()
    produced = []

    def endless():
        try:
            n = 0
            while True:
                produced.append(n)
                yield n
                n += 1
        finally:
            closed.set()

    before = threading.active_count()
    for item in read_ahead(endless(), depth=1):
        if item == 3:
            break
    assert closed.wait(5)
    assert threading.active_count() == before
    assert len(produced) <= 3 + 1 + 2  # the items taken, the one queued, the one in hand


def test_read_ahead_refuses_a_depth_below_one():
    with pytest.raises(ValueError, match="depth must be at least 1"):
        next(read_ahead([1], depth=0))


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
