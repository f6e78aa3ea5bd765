"""The memory budget: sizes as people write them, and how a budget is shared."""

from __future__ import annotations

import pytest

from pointfield.streaming.memory import CHUNK_COPIES, MIN_MEMORY, parse_memory, plan


@pytest.mark.parametrize(("text", "size"), [("2G", 2 << 30), ("512M", 512 << 20), ("1.5GB", 3 << 29), ("800MiB", 800 << 20), ("4096", 4096)])
def test_sizes_read_the_way_people_write_them(text, size):
    assert parse_memory(text) == size


def test_a_size_that_is_not_one_is_refused():
    with pytest.raises(ValueError, match="expected a size"):
        parse_memory("lots")


def test_a_larger_budget_buys_larger_chunks_and_more_state_never_past_the_budget():
    small, large = plan("512M", 100), plan("4G", 100)
    assert small.chunk_points < large.chunk_points and small.state_bytes < large.state_bytes
    for budget in (small, large):
        assert budget.chunk_points * 100 * CHUNK_COPIES + budget.state_bytes < budget.budget


def test_a_budget_too_small_for_the_interpreter_is_refused():
    with pytest.raises(ValueError, match="too small"):
        plan(MIN_MEMORY - 1, 100)
