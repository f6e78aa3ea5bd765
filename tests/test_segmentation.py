"""Classical segmentation: RANSAC planes with PCL's equation, DBSCAN clusters, cloth-simulation ground; the verbs write labels."""

from __future__ import annotations

import json

import numpy as np
import pytest

import pointfield
from pointfield.cli import main
from pointfield.segmentation import (
    clusters_beside_planes,
    dbscan,
    ground_classification,
    ground_mask,
    iou,
    segment_planes,
)


def box_scene(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A 4 x 4 floor (z = 0, 6000 points) with three boxes standing on it, sides and top as a scanner
    above sees them (label 1, 2, 3; floor 0), 2 cm clear of the floor so that distance separates them."""
    rng = np.random.default_rng(seed)
    floor = np.column_stack([rng.uniform(0, 4, (6000, 2)), rng.normal(0, 0.002, 6000)])
    parts, labels = [floor], [np.zeros(6000, int)]
    for label, (x, y, size) in enumerate([(0.8, 0.8, 0.5), (2.5, 1.0, 0.4), (1.5, 3.0, 0.3)], start=1):
        count = int(4000 * size)
        cube = rng.uniform(0, size, (count, 3))
        face = rng.integers(0, 3, count)
        side = np.where(face == 2, size, np.where(rng.random(count) < 0.5, 0.0, size))  # top, or a side wall
        cube[np.arange(count), face] = side
        cube[:, 2] = np.maximum(cube[:, 2], 0.02)
        parts.append(cube + (x, y, 0))
        labels.append(np.full(count, label))
    return np.concatenate(parts), np.concatenate(labels)


def test_pcl_plane_test_cloud_gives_pcl_equation(shared_data):
    cloud = pointfield.read(shared_data / "segmentation" / "pcl_sac_plane_test.pcd")
    planes, labels = segment_planes(cloud.points, count=1, distance=0.03)  # PCL's test threshold
    a, b, c, d = planes[0].equation
    assert np.allclose([a / d, b / d, c / d], [-0.8964, -0.5868, -1.208], atol=1e-2)
    assert (labels == 0).sum() == len(planes[0].inliers) > 2000  # PCL's test expects more than 2000


def test_planes_come_largest_first_with_unit_normals():
    points, truth = box_scene()
    planes, labels = segment_planes(points, count=3, distance=0.01)
    assert [len(p.inliers) for p in planes] == sorted((len(p.inliers) for p in planes), reverse=True)
    assert np.allclose(np.abs(planes[0].equation), [0, 0, 1, 0], atol=0.01)  # the floor
    assert iou(labels == 0, truth == 0) > 0.95
    assert all(np.isclose(np.linalg.norm(p.equation[:3]), 1.0) for p in planes)


def test_dbscan_separates_the_boxes_and_numbers_them_by_size():
    points, truth = box_scene()
    boxes = points[truth > 0]
    labels = dbscan(boxes, eps=0.05, min_points=5)
    assert labels.max() == 2 and (labels >= 0).all()
    for cluster, box in zip(range(3), (1, 2, 3)):  # the boxes are made largest first
        assert iou(labels == cluster, truth[truth > 0] == box) > 0.99


def test_dbscan_calls_isolated_points_noise():
    points = np.vstack([np.random.default_rng(0).normal(0, 0.01, (100, 3)), [[5.0, 5, 5], [np.nan, 0, 0]]])
    labels = dbscan(points, eps=0.05, min_points=5)
    assert labels[-1] == -1 and labels[-2] == -1 and (labels[:100] == 0).all()


def test_dbscan_in_small_blocks_matches_one_block_and_open3d():
    """Pairs found a few thousand at a time (bounded memory) join the same clusters as all at once,
    and as open3d's cluster_dbscan, up to the numbering and the border points open3d gives its first core neighbour."""
    o3d = pytest.importorskip("open3d")
    rng = np.random.default_rng(1)
    points = np.vstack([rng.normal(centre, 0.05, (800, 3)) for centre in rng.uniform(-1, 1, (6, 3))]
                       + [rng.uniform(-1.5, 1.5, (800, 3))])
    labels = dbscan(points, eps=0.06, min_points=8)
    assert np.array_equal(dbscan(points, eps=0.06, min_points=8, max_pairs=2000), labels)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    theirs = np.asarray(cloud.cluster_dbscan(0.06, 8))
    assert labels.max() == theirs.max() >= 5
    assert np.array_equal(labels < 0, theirs < 0)
    agree = [np.bincount(theirs[labels == c][theirs[labels == c] >= 0]).max() / (labels == c).sum()
             for c in range(labels.max() + 1)]
    assert min(agree) > 0.99


def test_planes_taken_out_first_leave_what_stands_on_them_apart():
    points, truth = box_scene()
    _, on_plane = segment_planes(points, count=1, distance=0.01)
    assert dbscan(points, eps=0.1, min_points=5).max() == 0  # the boxes stand 2 cm off the floor: joined to it
    labels = clusters_beside_planes(points, on_plane, eps=0.1, min_points=5)
    for cluster in range(4):  # the floor, then the boxes, largest first
        assert iou(labels == cluster, truth == cluster) > 0.95


def test_clusters_planes_needs_the_plane_field(tmp_path, capsys):
    source = tmp_path / "scene.ply"
    pointfield.write(source, pointfield.PointCloud(box_scene()[0].astype(np.float32)))
    assert main(["cloud", "clusters", str(source), str(tmp_path / "out.ply"), "--planes"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(source) in err[0] and "field 'plane'" in err[0]


def test_milk_table_and_each_object_are_their_own_clusters(shared_data):
    """PCL's milk cloud (a Kinect frame of a floor with a milk carton, a detergent and a bleach bottle on it, chair legs
    behind): planes out first, then DBSCAN; docs/images/milk-clusters.png is this result."""
    cloud = pointfield.read(shared_data / "segmentation" / "pcl_milk_cartoon_all_small_clorox.pcd")
    planes, on_plane = segment_planes(cloud.points, count=1, distance=0.02)
    labels = clusters_beside_planes(cloud.points, on_plane, eps=0.025, min_points=50)
    assert np.array_equal(labels == 0, on_plane == 0)  # the table is the largest cluster, objects not joined to it
    normal, offset = planes[0].equation[:3], planes[0].equation[3]
    heights = np.abs(cloud.points.astype(np.float64) @ normal + offset)
    for cluster in (1, 2, 3):  # the three objects: whole (10,000 points or more), 10 to 30 cm tall, on the table
        inside = labels == cluster
        assert inside.sum() > 9000 and np.ptp(cloud.points[inside], axis=0).max() < 0.3
        assert heights[inside].min() < 0.025 and 0.1 < heights[inside].max() < 0.3
    for cluster in range(4, labels.max() + 1):  # chair legs: smaller, and standing on it too (no piece of an object)
        assert (labels == cluster).sum() < 2000 and heights[labels == cluster].min() < 0.03


def test_cloth_simulation_finds_the_ground_under_boxes():
    points, truth = box_scene()
    mask = ground_mask(points, cloth_resolution=0.1, rigidness=3, class_threshold=0.01)  # box bottoms are 0.02 up
    assert iou(mask, truth == 0) > 0.95


def test_ground_classification_is_las_class_2_and_keeps_other_classes():
    out = ground_classification(np.array([True, False, False]), np.array([5, 2, 6], np.uint8))
    assert out.tolist() == [2, 1, 6] and out.dtype == np.uint8


def test_verbs_write_labels_as_fields(tmp_path, capsys):
    points, truth = box_scene()
    source = tmp_path / "scene.ply"
    pointfield.write(source, pointfield.PointCloud(points.astype(np.float32), {"intensity": truth.astype(np.uint16)}))
    assert main(["cloud", "planes", str(source), str(tmp_path / "planes.ply"), "--distance", "0.01", "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert len(printed["planes"]) == 1 and printed["planes"][0]["points"] > 5500
    planes = pointfield.read(tmp_path / "planes.ply")
    assert planes.fields["plane"].dtype == np.int32 and np.array_equal(planes.fields["intensity"], truth)
    assert main(["cloud", "clusters", str(tmp_path / "planes.ply"), str(tmp_path / "clusters.ply"), "--eps", "0.05"]) == 0
    assert "clusters" in capsys.readouterr().out
    assert {"plane", "cluster", "intensity"} <= pointfield.read(tmp_path / "clusters.ply").fields.keys()
    assert main(["cloud", "ground", str(source), str(tmp_path / "ground.las"), "--resolution", "0.1", "--threshold",
                 "0.01", "--rigidness", "3"]) == 0
    ground = pointfield.read(tmp_path / "ground.las")
    assert iou(ground.fields["classification"] == 2, truth == 0) > 0.95


@pytest.mark.parametrize("argv, fragment", [
    (["planes", "--count", "0"], "--count must be at least 1"),
    (["clusters", "--eps", "-1"], "--eps must be positive"),
])
def test_bad_options_are_one_line(tmp_path, capsys, argv, fragment):
    source = tmp_path / "scene.ply"
    pointfield.write(source, pointfield.PointCloud(box_scene()[0].astype(np.float32)))
    assert main(["cloud", argv[0], str(source), str(tmp_path / "out.ply"), *argv[1:]]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and fragment in err[0]


def test_ground_json_is_all_that_reaches_stdout(tmp_path, capfd):
    """CSF's C++ prints its progress ("[0] Configuring terrain...") on file descriptor 1; --json must stay parseable."""
    points, _ = box_scene()
    source = tmp_path / "scene.ply"
    pointfield.write(source, pointfield.PointCloud(points.astype(np.float32)))
    assert main(["cloud", "ground", str(source), str(tmp_path / "ground.las"), "--resolution", "0.1", "--threshold",
                 "0.01", "--rigidness", "3", "--json"]) == 0
    printed = json.loads(capfd.readouterr().out)
    assert printed["ground"] == (pointfield.read(tmp_path / "ground.las").fields["classification"] == 2).sum()
