"""The read-ahead thread: order, errors, and stopping."""

from __future__ import annotations

import threading

import pytest

from pointfield.errors import FormatError
from pointfield.streaming.readahead import read_ahead


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
