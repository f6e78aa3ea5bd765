"""Where the page's camera starts: from the sensor that saw a cloud, upright; from a scene's own camera."""

from __future__ import annotations

import numpy as np
import pytest

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.formats.registry import read, write
from pointfield.clouds.sensor import sensor_view
from pointfield.scenes import read_scene
from pointfield.viewer.scenes import first_training_camera, scene_framing


def depth_frame(rows: int = 48, columns: int = 64, viewpoint=(0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)) -> PointCloud:
    """An organised frame as a depth camera gives it: OpenCV axes (x right, y down, z forward), a wall
    2 units ahead with a NaN hole, rows running top to bottom."""
    v, u = np.mgrid[0:rows, 0:columns].astype(np.float64)
    depth = np.full((rows, columns), 2.0)
    points = np.stack([(u - columns / 2) / 50 * depth, (v - rows / 2) / 50 * depth, depth], axis=-1).reshape(-1, 3)
    points[:40] = np.nan
    return PointCloud(points.astype(np.float32), {}, (rows, columns), {"viewpoint": viewpoint})


def test_an_organised_depth_frame_is_seen_from_its_sensor_with_image_up_up():
    view = sensor_view(depth_frame())
    assert view.eye == pytest.approx([0, 0, 0])
    forward = (view.target - view.eye) / np.linalg.norm(view.target - view.eye)
    assert forward @ [0, 0, 1] > 0.99  # looking into the frame, not from behind it
    assert view.up @ [0, -1, 0] > 0.99  # the first rows (small y) are at the top of the page
    assert abs(view.up @ forward) < 1e-9


def test_pcl_s_other_viewpoint_of_the_same_frame_gives_the_same_look():
    # PCL writes 0 0 0 0 1 0 0 as well as the identity for frames with these axes: the grid decides.
    default, flipped = sensor_view(depth_frame()), sensor_view(depth_frame(viewpoint=(0, 0, 0, 0, 1, 0, 0)))
    assert flipped.up == pytest.approx(default.up)
    assert flipped.target == pytest.approx(default.target)


def test_the_sensor_stands_where_the_viewpoint_puts_it(tmp_path):
    rng = np.random.default_rng(0)
    cloud = PointCloud(rng.uniform(-1, 1, (500, 3)).astype(np.float32), {},
                       metadata={"viewpoint": (5.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0)})
    write(tmp_path / "scan.pcd", cloud)
    view = sensor_view(read(tmp_path / "scan.pcd"))
    assert view.eye == pytest.approx([5, 0, 1])
    assert view.up @ [0, 0, 1] > 0.9  # an unorganised scan stays z-up


def test_a_cloud_that_says_nothing_of_its_sensor_has_no_sensor_view():
    rng = np.random.default_rng(0)
    assert sensor_view(PointCloud(rng.uniform(-1, 1, (100, 3)), {})) is None
    assert sensor_view(PointCloud(rng.uniform(-1, 1, (100, 3)), {}, metadata={"viewpoint": (0, 0, 0, 1, 0, 0, 0)})) is None
    all_nan = depth_frame()
    all_nan.points[:] = np.nan
    assert sensor_view(all_nan) is None


def test_a_kinect_scan_opens_from_the_kinect_upright(served, shared_data):
    path = shared_data / "pcd" / "pcl_table_scene_mug_organized.pcd"
    viewer, _ = served([path], max_points=20_000)
    camera = viewer.server.initial_camera
    position, look_at, up = (np.asarray(value, np.float64) for value in (camera.position, camera.look_at, camera.up))
    assert position == pytest.approx([0, 0, 0], abs=1e-6)  # where the sensor stood
    forward = (look_at - position) / np.linalg.norm(look_at - position)
    assert forward @ [0, 0, 1] > 0.9  # the table is in front (z forward) ...
    assert up @ [0, -1, 0] > 0.9  # ... and the right way up (image rows run down y)


def test_a_scene_opens_from_its_first_training_camera(scene_folder):
    scene = read_scene(scene_folder)
    index = first_training_camera(scene)
    assert index not in {int(i) for name in ("val", "test") for i in scene.splits.get(name, [])}
    target, eye, _ = scene_framing(scene, back=1.0, lift=0.0)
    camera = scene.cameras.centers.double().numpy()[index]
    forward = scene.cameras.rotations.double().numpy()[index][:, 2]
    assert eye == pytest.approx(camera)
    direction = (target - eye) / np.linalg.norm(target - eye)
    assert direction == pytest.approx(forward)
    # Stepped back for the frustums, the camera stays on the same axis and behind the first camera.
    _, back_eye, _ = scene_framing(scene, back=2.0, lift=0.0)
    assert np.cross(back_eye - camera, forward) == pytest.approx(np.zeros(3), abs=1e-9)
    assert (back_eye - camera) @ forward < 0
