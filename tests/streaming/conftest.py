"""Small generated clouds in every streamable format, and a real two-worker Dask cluster."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

import pointfield
from pointfield.clouds.cloud import PointCloud


def lidar_cloud(count: int = 40_000, seed: int = 0) -> PointCloud:
    """A lidar-like cloud: UTM-sized float64 points on a gently sloping strip, with intensity,
    classification, RGB and GPS time, in file (scan) order."""
    rng = np.random.default_rng(seed)
    x = 500_000 + np.sort(rng.random(count)) * 120.0
    y = 4_100_000 + rng.random(count) * 80.0
    z = 30 + 0.05 * x % 7 + rng.normal(0, 0.3, count)
    fields = {
        "intensity": rng.integers(0, 4000, count).astype(np.uint16),
        "classification": rng.choice([1, 2, 5, 6], count).astype(np.uint8),
        "colors": rng.integers(0, 65535, (count, 3)).astype(np.uint16),
        "gps_time": 1e5 + np.arange(count) * 1e-4,
    }
    return PointCloud(np.stack([x, y, z], axis=1), fields)


@pytest.fixture(scope="session")
def make_lidar():
    """:func:`lidar_cloud`, for tests that generate their own."""
    return lidar_cloud


@pytest.fixture(scope="session")
def written():
    """``written(path, cloud)``: write ``cloud`` with :func:`pointfield.write` (its notes
    silenced) and return the file's bytes, the ones a streamed output must equal."""

    def write(path: Path, cloud: PointCloud) -> bytes:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            pointfield.write(path, cloud)
        return path.read_bytes()

    return write


@pytest.fixture(scope="session")
def data(tmp_path_factory) -> dict[str, Path]:
    """The same kind of cloud as LAZ, LAS, binary PLY, binary PCD, KITTI .bin and NPY."""
    folder = tmp_path_factory.mktemp("streaming-data")
    cloud = lidar_cloud()
    files = {"laz": folder / "strip.laz", "las": folder / "strip.las"}
    pointfield.write(files["laz"], cloud)
    pointfield.write(files["las"], cloud)
    small = PointCloud(
        (cloud.points - cloud.points.min(axis=0)).astype(np.float32),
        {
            "intensity": cloud.fields["intensity"].astype(np.float32) / 4000,
            "normals": np.tile(np.float32([0, 0, 1]), (len(cloud), 1)),
            "label": cloud.fields["classification"].astype(np.int32),
        },
    )
    small.points[::501] = np.nan
    for name in ("ply", "pcd", "npy"):
        files[name] = folder / f"strip.{name}"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            pointfield.write(files[name], small)
    files["bin"] = folder / "strip.bin"
    pointfield.write(files["bin"], PointCloud(small.points, {"intensity": small.fields["intensity"]}))
    return files


@pytest.fixture(scope="module")
def dask_client():
    """A real dask.distributed LocalCluster of 2 worker processes, 1 thread each, per module."""
    import os

    from distributed import Client, LocalCluster

    saved = dict(os.environ)  # the nannies write dask's pre-spawn-environ into this process too
    with (
        LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster,
        Client(cluster) as client,
    ):
        os.environ.clear()
        os.environ.update(saved)
        yield client
