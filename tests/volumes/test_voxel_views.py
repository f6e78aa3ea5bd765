"""Voxel files in the viewer: recognised as clouds, shown as their voxel centres with their fields."""

from __future__ import annotations

import numpy as np

from pointfield.viewer.clouds import read_prepared
from pointfield.viewer.sources import kind_of
from pointfield.volumes import VoxelGrid, write_voxels


def test_a_voxel_file_is_viewed_as_the_cloud_of_its_voxel_centres(tmp_path):
    grid = VoxelGrid(np.array([[0, 0, 0], [2, 1, 0], [3, 3, 3]]), np.array([1.0, 2.0, 3.0]), 0.5,
                     {"counts": np.array([1, 5, 2])})
    for suffix in (".binvox", ".vox", ".npz"):
        path = tmp_path / f"grid{suffix}"
        write_voxels(path, grid)
        assert kind_of(path) == "cloud"
        prepared = read_prepared(path, 1000)
        assert not isinstance(prepared, str), prepared
        assert len(prepared.points) == 3
    assert np.allclose(np.sort(prepared.points[:, 0]), [1.25, 2.25, 2.75])  # the .npz keeps origin and size
    assert sorted(prepared.fields["counts"].tolist()) == [1, 2, 5]
