"""The procedural labelled shapes and the SyntheticShapes dataset."""

from __future__ import annotations

import numpy as np
import pytest

from pointfield.clouds.shapes import (
    PART_NAMES,
    SHAPE_CLASSES,
    SHAPE_PARTS,
    SyntheticShapes,
    make_shape,
)


@pytest.mark.parametrize("name", SHAPE_CLASSES)
def test_every_shape_has_its_parts_and_unit_outward_normals(name):
    cloud = make_shape(name, 3000, np.random.default_rng(0), posed=False)
    assert cloud.points.dtype == np.float32 and len(cloud) == 3000
    parts = {PART_NAMES[i] for i in np.unique(cloud.fields["label"])}
    assert parts == set(SHAPE_PARTS[name])
    normals = cloud.fields["normals"]
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, rtol=1e-5)
    assert np.abs(cloud.points).max() < 1.5


@pytest.mark.parametrize("name", ["sphere", "cube", "cone", "pyramid", "cylinder", "hemisphere"])
def test_normals_of_convex_shapes_face_away_from_the_inside(name):
    cloud = make_shape(name, 2000, np.random.default_rng(1), posed=False)
    inside = cloud.points.mean(axis=0)
    assert ((cloud.points - inside) * cloud.fields["normals"]).sum(axis=1).min() > -1e-6


def test_there_are_ten_classes_and_seventeen_parts():
    assert len(SHAPE_CLASSES) == 10 and len(PART_NAMES) == 17


def test_dataset_items_are_deterministic_balanced_and_vary_in_size():
    dataset = SyntheticShapes("train", shapes_per_class=3, points=(100, 300), seed=4)
    assert len(dataset) == 30
    assert np.bincount(dataset.class_labels()).tolist() == [3] * 10
    first, label = dataset[0]
    again, _ = dataset[0]
    np.testing.assert_array_equal(first.points, again.points)
    assert label == 0 and 100 <= len(first) <= 300
    assert len({len(dataset[i][0]) for i in range(10)}) > 1


def test_train_and_test_splits_are_different_draws():
    train = SyntheticShapes("train", 2, points=64)
    test = SyntheticShapes("test", 2, points=64)
    assert not np.array_equal(train[0][0].points, test[0][0].points)


def test_posed_shapes_differ_from_one_draw_to_the_next():
    a = make_shape("table", 500, np.random.default_rng(0))
    b = make_shape("table", 500, np.random.default_rng(1))
    assert not np.allclose(a.points, b.points)
