"""A batch that cannot be made names the file it could not be made from: ``CloudCollate`` asked
for a feature field (``normals``) that one file lacks says which file, and what fields it has."""

from __future__ import annotations

import numpy as np
import pytest
from torch.utils.data import DataLoader

import pointfield
from pointfield.clouds import synthetic
from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.datasets import CloudCollate, CloudFolder
from pointfield.errors import PointfieldError


def test_a_missing_feature_field_names_the_file(tmp_path):
    folder = tmp_path / "my_clouds" / "ball"
    folder.mkdir(parents=True)
    with_normals = synthetic.sphere(count=64, seed=0)
    assert "normals" in with_normals.fields
    pointfield.write(folder / "0001.ply", with_normals)
    pointfield.write(folder / "0002.ply", PointCloud(with_normals.points, {"intensity": np.ones(64, np.float32)}))
    every = CloudFolder(tmp_path / "my_clouds")
    loader = DataLoader(every, batch_size=2, collate_fn=CloudCollate(features=("normals",)))
    with pytest.raises(PointfieldError, match=r"0002\.ply: has no 'normals' field to use as a feature \(its fields: intensity\)"):
        next(iter(loader))


def test_samples_say_where_they_came_from(tmp_path):
    folder = tmp_path / "my_clouds" / "ball"
    folder.mkdir(parents=True)
    pointfield.write(folder / "0001.xyz", synthetic.sphere(count=32, seed=0))
    cloud, _ = CloudFolder(tmp_path / "my_clouds")[0]
    assert cloud.metadata["source"] == str(folder / "0001.xyz")
