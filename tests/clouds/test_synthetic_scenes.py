"""Synthetic labelled scenes: deterministic, every class present, and scanned with real occlusion."""

from __future__ import annotations

import json

import numpy as np
import pytest

import pointfield
from pointfield.clouds.synthetic_scenes import (
    ROOM_CLASSES,
    STREET_CLASSES,
    Box,
    SpinningLidar,
    make_scenes,
    scan,
    synthetic_scene,
)
from pointfield.errors import PointfieldError


@pytest.mark.parametrize("kind", ["room", "street"])
def test_the_same_seed_gives_the_same_cloud_bit_for_bit(kind):
    first, second = synthetic_scene(kind, 3, 0.1), synthetic_scene(kind, 3, 0.1)
    assert np.array_equal(first.cloud.points, second.cloud.points)
    for name in ("label", "colors", "normals", "intensity"):
        assert np.array_equal(first.cloud.fields[name], second.cloud.fields[name])
    assert not np.array_equal(synthetic_scene(kind, 4, 0.1).cloud.points[:100], first.cloud.points[:100])


@pytest.mark.parametrize(("kind", "classes"), [("room", ROOM_CLASSES), ("street", STREET_CLASSES)])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_every_class_is_seen_in_every_scene(kind, classes, seed):
    scene = synthetic_scene(kind, seed, 0.2)
    assert scene.classes == classes
    counts = np.bincount(scene.cloud.fields["label"], minlength=len(classes))
    assert len(counts) == len(classes) and (counts >= 20).all(), dict(zip(classes, counts))


def test_a_wall_between_the_sensor_and_a_box_hides_the_box():
    lidar = SpinningLidar((0.0, 0.0, 1.0), beams=16, steps=360, low=-10, high=10)
    target = Box(1, (200, 0, 0), 0.5, (4.0, -1.0, 0.0), (5.0, 1.0, 2.0))
    wall = Box(0, (255, 255, 255), 0.5, (2.0, -3.0, -1.0), (2.2, 3.0, 3.0))
    seen = scan([target], [lidar], ("wall", "box"), np.random.default_rng(0)).cloud
    hidden = scan([target, wall], [lidar], ("wall", "box"), np.random.default_rng(0)).cloud
    assert (seen.fields["label"] == 1).sum() > 50
    assert (hidden.fields["label"] == 1).sum() == 0
    # The returns stop at the wall's face, 2 m away (to the range noise), not at the box behind.
    in_front = hidden.points[hidden.fields["label"] == 0]
    assert np.abs(in_front[:, 0] - 2.0).max() < 0.1


def test_density_falls_with_range():
    lidar = SpinningLidar((0.0, 0.0, 1.0), beams=32, steps=720)
    near = Box(0, (255, 255, 255), 0.5, (3.0, -1.0, 0.0), (3.2, 1.0, 2.0))
    far = Box(1, (255, 255, 255), 0.5, (-12.0, -1.0, 0.0), (-11.8, 1.0, 2.0))
    cloud = scan([near, far], [lidar], ("near", "far"), np.random.default_rng(0)).cloud
    counts = np.bincount(cloud.fields["label"], minlength=2)
    assert counts[0] > 4 * counts[1] > 0  # the same 2 x 2 m face, 4 times nearer


def test_normals_face_the_sensor_and_intensity_is_reflectance_times_cosine():
    lidar = SpinningLidar((0.0, 0.0, 1.0), beams=8, steps=90, low=-5, high=5)
    face = Box(0, (255, 255, 255), 0.5, (3.0, -20.0, -5.0), (3.5, 20.0, 5.0))
    cloud = scan([face], [lidar], ("wall",), np.random.default_rng(0)).cloud
    assert np.allclose(cloud.fields["normals"], [-1, 0, 0])
    direction = cloud.points - np.array([0, 0, 1.0])
    cosine = direction[:, 0] / np.linalg.norm(direction, axis=1)
    assert np.allclose(cloud.fields["intensity"], 0.5 * cosine, atol=0.02)


def test_make_scenes_writes_train_and_test_clouds_with_one_class_table(tmp_path):
    written = make_scenes(tmp_path / "streets", "street", 3, seed=7, density=0.05)
    assert [p.parent.name for p in written] == ["train", "train", "test"]
    assert json.loads((tmp_path / "streets" / "classes.json").read_text()) == list(STREET_CLASSES)
    cloud = pointfield.read(written[0])
    assert np.array_equal(cloud.fields["label"], synthetic_scene("street", 7, 0.05).cloud.fields["label"])


def test_an_unknown_kind_is_refused():
    with pytest.raises(PointfieldError, match="unknown scene kind 'forest'"):
        synthetic_scene("forest")


def test_the_make_scenes_command_writes_a_folder_segment_train_takes(tmp_path, capsys):
    from pointfield.cli import main
    from pointfield.cli.segment_scenes import is_scene_data

    assert main(["segment", "make-scenes", str(tmp_path / "rooms"), "--count", "2", "--density", "0.02"]) == 0
    assert "2 room scans" in capsys.readouterr().out
    assert sorted(p.name for p in (tmp_path / "rooms").rglob("*.ply")) == ["room_0000.ply", "room_0001.ply"]
    assert is_scene_data([tmp_path / "rooms"])
