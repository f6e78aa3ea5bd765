"""Reading a binary file holds at most about twice its output arrays in memory.

Measured with tracemalloc, which sees numpy's and Python's allocations: a deterministic count of
bytes, not a timing.
"""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

import pointfield
from pointfield import PointCloud

ABOUT_TWICE = 2.3


@pytest.fixture(scope="module")
def coloured_cloud():
    rng = np.random.default_rng(3)
    n = 200_000
    return PointCloud(
        rng.normal(size=(n, 3)).astype(np.float32),
        {"colors": rng.integers(0, 256, (n, 3), dtype=np.uint8), "intensity": rng.random(n).astype(np.float32)},
    )


@pytest.mark.parametrize(
    ("name", "encoding"),
    [("cloud.ply", "binary_little_endian"), ("cloud.ply", "binary_big_endian"),
     ("cloud.pcd", "binary"), ("cloud.pcd", "binary_compressed"), ("cloud.npy", None),
     ("cloud.las", None)],
)
def test_binary_read_peak_memory_is_about_twice_the_output(coloured_cloud, tmp_path, name, encoding):
    path = tmp_path / name
    pointfield.write(path, coloured_cloud, encoding=encoding)
    tracemalloc.start()
    try:
        cloud = pointfield.read(path)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    output = cloud.points.nbytes + sum(v.nbytes for v in cloud.fields.values())
    assert peak <= ABOUT_TWICE * output, f"peak {peak:,} B for {output:,} B of output"
