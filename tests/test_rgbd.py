"""`pointfield scene from-rgbd`: odometry recovers a known camera path, the outputs read back, bad input is one line."""

from __future__ import annotations

import json
import shutil

import imageio.v3 as iio
import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from pointfield.cli import main
from pointfield.geometry.tsdf import TSDFVolume, allocation_stride
from pointfield.registration.fragments import (
    _information_at,
    fragment_pose_graph,
    fragment_poses,
    nearest_pairs,
    split_fragments,
)
from pointfield.registration.odometry import Intrinsics, absolute_trajectory_error, backproject, rgbd_odometry
from pointfield.registration.scan import Scan
from pointfield.scenes import read_scene
from pointfield.scenes.cameras import Cameras
from pointfield.scenes.rgbd import (
    read_intrinsics,
    read_log_trajectory,
    read_rgbd_folder,
    reconstruct_rgbd,
)

CAMERA = Intrinsics(160, 120, 120.0, 120.0, 80.0, 60.0)
ROOM = (np.array([-2.0, -1.2, -1.5]), np.array([2.5, 1.3, 3.0]))
"""A room (seen from inside) and two boxes in it (seen from outside): corners that pin every direction."""
BOXES = [(np.array([-0.6, 0.3, 1.2]), np.array([0.2, 1.3, 1.8])), (np.array([0.8, -0.4, 2.0]), np.array([1.4, 0.5, 2.6]))]


def true_poses(count: int) -> np.ndarray:
    """Camera-to-world poses: a few centimetres and a degree or two a frame, turning and rising."""
    poses = []
    for i in range(count):
        pose = np.eye(4)
        pose[:3, :3] = Rotation.from_euler("yxz", [2.0 * i, 0.8 * i, 0.3 * i], degrees=True).as_matrix()
        pose[:3, 3] = [0.03 * i, -0.01 * i, 0.02 * i]
        poses.append(pose)
    return np.stack(poses)


def render_depth(pose: np.ndarray) -> np.ndarray:
    """Exact z-depth ``(H, W)`` of the room and boxes from one camera (rays through pixel centres)."""
    columns, rows = np.meshgrid(np.arange(CAMERA.width) + 0.5, np.arange(CAMERA.height) + 0.5)
    local = np.stack([(columns - CAMERA.cx) / CAMERA.fx, (rows - CAMERA.cy) / CAMERA.fy, np.ones_like(columns)], -1)
    directions = local @ pose[:3, :3].T  # z-depth = distance along the ray in units of these (local z = 1)
    origin = pose[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        wall = np.where(directions > 0, ROOM[1], ROOM[0])
        depth = np.nanmin(np.where(directions != 0, (wall - origin) / directions, np.inf), axis=-1)
        for low, high in BOXES:
            near = np.minimum((low - origin) / directions, (high - origin) / directions).max(axis=-1)
            far = np.maximum((low - origin) / directions, (high - origin) / directions).min(axis=-1)
            hit = (near <= far) & (near > 0)
            depth = np.where(hit, np.minimum(depth, near), depth)
    return depth


def write_sequence(folder, poses, colour_folder="image"):
    """A Redwood-layout sequence: 16-bit depth in millimetres, colour by height, open3d intrinsics JSON."""
    (folder / "depth").mkdir(parents=True)
    (folder / colour_folder).mkdir()
    for i, pose in enumerate(poses):
        depth = render_depth(pose)
        iio.imwrite(folder / "depth" / f"{i:05d}.png", np.round(depth * 1000).astype(np.uint16))
        shade = (np.clip(depth / 5.0, 0, 1) * 255).astype(np.uint8)
        iio.imwrite(folder / colour_folder / f"{i:05d}.jpg", np.stack([shade, 255 - shade, shade], -1))
    (folder / "camera.json").write_text(json.dumps({
        "width": CAMERA.width, "height": CAMERA.height,
        "intrinsic_matrix": [CAMERA.fx, 0, 0, 0, CAMERA.fy, 0, CAMERA.cx - 0.5, CAMERA.cy - 0.5, 1]}))
    return folder


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    poses = true_poses(8)
    return write_sequence(tmp_path_factory.mktemp("rgbd") / "room", poses), poses


def test_odometry_recovers_a_known_camera_path(sequence):
    _, truth = sequence
    odometry = rgbd_odometry((render_depth(p) for p in truth), CAMERA, voxel=0.05, stride=1)
    assert absolute_trajectory_error(odometry.poses, truth) < 0.005
    # Not only after alignment: the first pose is the world, so every pose itself is right.
    assert np.abs(odometry.poses[:, :3, 3] - truth[:, :3, 3]).max() < 0.01
    assert odometry.fitness.min() > 0.9


def test_from_rgbd_writes_mesh_trajectories_and_a_scene_that_reads_back(sequence, tmp_path, capsys):
    folder, truth = sequence
    out = tmp_path / "scene"
    assert main(["scene", "from-rgbd", str(folder), "--out", str(out), "--voxel", "0.04", "--odometry-voxel", "0.05",
                 "--device", "cpu"]) == 0
    assert "8 frames posed and fused" in capsys.readouterr().out
    logged = read_log_trajectory(out / "trajectory.log")
    assert absolute_trajectory_error(logged, truth) < 0.01
    tum = np.loadtxt(out / "trajectory.txt")
    assert tum.shape == (8, 8)
    np.testing.assert_allclose(tum[:, 1:4], logged[:, :3, 3], atol=1e-6)
    np.testing.assert_allclose(Rotation.from_quat(tum[:, 4:]).as_matrix(), logged[:, :3, :3], atol=1e-6)
    scene = read_scene(out)
    assert len(scene) == 8 and scene.points is not None
    np.testing.assert_allclose(scene.cameras.camera_to_world.numpy(), logged[:, :3, :], atol=1e-6)
    np.testing.assert_allclose(scene.depth(3), render_depth(truth[3]), atol=1e-3)
    # The mesh lies on the walls: every vertex within a voxel or so of the room's or a box's faces.
    mesh = read_scene(out).points.points
    faces = [np.abs(mesh - ROOM[0]).min(axis=1), np.abs(mesh - ROOM[1]).min(axis=1)]
    faces += [np.abs(mesh - corner).min(axis=1) for box in BOXES for corner in box]
    assert np.median(np.min(faces, axis=0)) < 0.02


def test_tum_layout_pairs_frames_by_timestamp(sequence, tmp_path):
    folder, _ = sequence
    tum = tmp_path / "tum"
    shutil.copytree(folder / "depth", tum / "depth")
    shutil.copytree(folder / "image", tum / "rgb")
    colour_lines = [f"{100 + 0.033 * i:.6f} rgb/{i:05d}.jpg" for i in range(8)]
    depth_lines = [f"{100 + 0.033 * i + 0.004:.6f} depth/{i:05d}.png" for i in reversed(range(8))]
    (tum / "rgb.txt").write_text("# colour\n" + "\n".join(colour_lines) + "\n")
    (tum / "depth.txt").write_text("# depth\n" + "\n".join(depth_lines) + "\n")
    frames = read_rgbd_folder(tum)
    assert frames.layout == "tum" and len(frames) == 8
    assert [p.stem for p in frames.depth] == [p.stem for p in frames.colour]
    np.testing.assert_allclose(frames.timestamps, 100 + 0.033 * np.arange(8), atol=1e-6)


def test_culling_blocks_out_of_view_changes_no_voxel(sequence, monkeypatch):
    _, truth = sequence
    cameras = Cameras(torch.as_tensor(truth), CAMERA.fx, CAMERA.fy, CAMERA.cx, CAMERA.cy, CAMERA.width, CAMERA.height)
    depths = [torch.from_numpy(render_depth(p).astype(np.float32)) for p in truth]
    colour = torch.zeros(CAMERA.height, CAMERA.width, 3)

    def fused():
        volume = TSDFVolume.create(ROOM[0] - 0.1, ROOM[1] + 0.1, 64)
        for index, depth in enumerate(depths):
            volume.allocate(depth, cameras, index)
        for index, depth in enumerate(depths):
            volume.integrate(depth, colour, cameras, index)
        return volume

    culled = fused()
    kept = len(culled.blocks_in_view(cameras[[0]].to(None, torch.float32), 10.0))
    assert kept < len(culled.tsdf) // 512  # the test means something: the first view does not see every block
    monkeypatch.setattr(TSDFVolume, "blocks_in_view", lambda self, camera, far: torch.arange(len(self.tsdf) // 512))
    every = fused()
    assert torch.equal(culled.tsdf, every.tsdf) and torch.equal(culled.weight, every.weight)


def test_open3d_intrinsics_json_becomes_pixel_centre_convention(tmp_path):
    path = tmp_path / "camera.json"
    path.write_text(json.dumps({"width": 640, "height": 480, "intrinsic_matrix": [525, 0, 0, 0, 525, 0, 319.5, 239.5, 1]}))
    assert read_intrinsics(path) == Intrinsics(640, 480, 525.0, 525.0, 320.0, 240.0)


def test_the_living_room_is_posed_within_2_cm_of_open3ds_reconstruction(shared_data, tmp_path):
    room = shared_data / "rgbd" / "livingroom1_micro"
    result = reconstruct_rgbd(room, tmp_path / "room", intrinsics=room / "camera_primesense.json", frames=12,
                              voxel=0.03, device="cpu")
    reference = read_log_trajectory(room / "open3d_trajectory.log")[:12]
    assert absolute_trajectory_error(result.poses, reference) < 0.02
    assert result.report["faces"] > 1000


def loop_poses(count: int) -> np.ndarray:
    """``count + 1`` camera-to-world poses round a 1 m circle facing the boxes, yawing +-30 degrees; the last is
    the first."""
    angles = 2 * np.pi * np.arange(count + 1) / count
    poses = np.repeat(np.eye(4)[None], count + 1, axis=0)
    poses[:, :3, :3] = Rotation.from_euler("yx", np.stack([30 * np.sin(angles), 5 * np.sin(2 * angles)], 1),
                                           degrees=True).as_matrix()
    poses[:, :3, 3] = np.stack([0.5 * np.sin(angles), 0.1 * np.sin(2 * angles), 0.5 * (1 - np.cos(angles)) - 1.0], 1)
    return poses


def end_to_start(poses: np.ndarray) -> float:
    """Metres between the first and the last camera of a trajectory that returns to where it began."""
    return float(np.linalg.norm(poses[-1, :3, 3] - poses[0, :3, 3]))


def test_loop_closure_removes_the_drift_of_a_camera_that_comes_back(tmp_path):
    truth = loop_poses(48)
    noise = np.random.default_rng(0)
    # 1 cm of depth noise: each step's error is small, but 48 of them add up.
    depths = [render_depth(p) + noise.normal(0, 0.01, (CAMERA.height, CAMERA.width)) for p in truth]
    odometry = rgbd_odometry(depths, CAMERA, voxel=0.05, stride=1)
    chained = fragment_poses(odometry.poses, odometry.points, 8, voxel=0.05, loop_closure=False,
                             global_registration=False)
    closed = fragment_poses(odometry.poses, odometry.points, 8, voxel=0.05, global_registration=False)
    assert end_to_start(odometry.poses) > 0.01  # the test means something: the odometry drifted
    assert closed.loops_kept >= 3 and any(p.source == 0 and p.target == 5 and p.kept for p in closed.pairs)
    assert end_to_start(closed.poses) < 0.5 * min(end_to_start(odometry.poses), end_to_start(chained.poses))
    # and the loop is closed without bending the rest: the whole path is nearer the truth than the odometry's
    assert absolute_trajectory_error(closed.poses, truth) < absolute_trajectory_error(odometry.poses, truth)


def test_a_fragments_own_pose_graph_closes_its_keyframe_loop_and_prunes_a_slid_registration():
    """20 frames round the circle, odometry biased 0.3 degree and 3 mm a frame (5.6 cm off at the end); keyframes
    every 5 frames register onto each other, one pair (10-15) slides 13 cm along a wall: open3d's make_fragments."""
    truth = loop_poses(20)
    points = [Scan(backproject(render_depth(p), CAMERA)).downsample(0.08).points for p in truth]
    bias = np.eye(4)
    bias[:3, :3], bias[:3, 3] = Rotation.from_euler("y", 0.3, degrees=True).as_matrix(), [0.003, 0.0, 0.003]
    drifted = [np.eye(4)]
    for before, after in zip(truth[:-1], truth[1:]):
        drifted.append(drifted[-1] @ np.linalg.inv(before) @ after @ bias)
    drifted = np.stack(drifted)
    poses, linked, kept, pruned = fragment_pose_graph(drifted, points, 0, len(truth), 0.08)
    assert end_to_start(drifted) > 0.05  # the test means something: the odometry is 5 cm off when it comes back
    assert linked == 9 and pruned == 1 and kept == 8
    assert end_to_start(poses) < end_to_start(drifted) / 10
    assert absolute_trajectory_error(poses, truth) < 0.8 * absolute_trajectory_error(drifted, truth)
    np.testing.assert_allclose(poses[0], drifted[0])  # the fragment's first camera stays where it was


def test_the_odometrys_information_gives_the_fragments_the_poses_they_measure_themselves():
    """Each step's information, measured in the odometry's own k-d trees, is what the fragments' pose graphs would
    measure (correspondences within the voxel), so handing it over changes no pose and saves a k-d tree per step."""
    truth = loop_poses(16)[:9]
    noise = np.random.default_rng(1)
    depths = [render_depth(p) + noise.normal(0, 0.01, (CAMERA.height, CAMERA.width)) for p in truth]
    odometry = rgbd_odometry(depths, CAMERA, voxel=0.05, stride=2, information=True)
    assert len(odometry.information) == len(truth) - 1 and all(i is not None for i in odometry.information)
    for k in (0, 5):
        motion = np.linalg.inv(odometry.poses[k]) @ odometry.poses[k + 1]
        measured = _information_at(odometry.points[k + 1], odometry.points[k], motion, 0.05)
        assert measured[3, 3] > 100  # the test means something: many correspondences
        np.testing.assert_allclose(odometry.information[k], measured, rtol=1e-9)
    measured, linked, _, _ = fragment_pose_graph(odometry.poses, odometry.points, 0, len(truth), 0.05, 4)
    handed, *_ = fragment_pose_graph(odometry.poses, odometry.points, 0, len(truth), 0.05, 4,
                                     information=odometry.information)
    assert linked > 0  # the pose graph has keyframe pairs to weigh against the steps
    np.testing.assert_allclose(handed, measured, atol=1e-9)

def test_loop_candidates_grow_as_n_times_the_cap_and_keep_each_fragments_nearest():
    """200 fragments whose boxes all meet (a long sequence in one room): 19,900 pairs, of which each keeps its 4 nearest."""
    centres = list(np.random.default_rng(0).uniform(0, 5, (200, 3)))
    every = [(i, j) for i in range(200) for j in range(i + 2, 200)]
    kept = nearest_pairs(centres, every, 4)
    assert len(kept) <= 4 * 200 < len(every) // 20
    for i in (0, 57, 199):
        distance = {j: np.linalg.norm(centres[i] - centres[j]) for j in range(200) if abs(i - j) > 1}
        nearest = sorted(distance, key=distance.get)[:4]
        assert all(tuple(sorted((i, j))) in kept for j in nearest)
    assert nearest_pairs(centres, every, None) == every


def test_fragments_split_as_open3d_and_a_short_tail_joins_the_last():
    assert split_fragments(60, 20) == [(0, 20), (20, 40), (40, 60)]
    assert split_fragments(119, 20)[-1] == (100, 119)
    assert split_fragments(65, 20) == [(0, 20), (20, 40), (40, 65)]


def test_fragments_keep_the_living_room_within_half_a_centimetre_of_open3d(shared_data, tmp_path):
    room = shared_data / "rgbd" / "livingroom1_micro"
    result = reconstruct_rgbd(room, tmp_path / "room", intrinsics=room / "camera_primesense.json", frames=30,
                              fragment_size=10, voxel=0.05, device="cpu", progress=False)
    fragments = result.report["fragments"]
    assert fragments["used"] and fragments["count"] == 3 and fragments["loops_kept"] == 1
    reference = read_log_trajectory(room / "open3d_trajectory.log")[:30]
    assert absolute_trajectory_error(result.poses, reference) < 0.005


def test_from_rgbd_fragments_and_loop_closure_through_the_cli(sequence, tmp_path, capsys):
    folder, truth = sequence
    argv = ["scene", "from-rgbd", str(folder), "--voxel", "0.04", "--odometry-voxel", "0.05", "--device", "cpu",
            "--fragment-size", "2"]
    assert main([*argv, "--out", str(tmp_path / "closed")]) == 0
    out = capsys.readouterr().out
    assert "fragments: 4 of 2 frames" in out and "loop closures: " in out
    report = json.loads((tmp_path / "closed" / "report.json").read_text())
    assert report["fragments"]["loops_kept"] >= 1
    assert absolute_trajectory_error(read_log_trajectory(tmp_path / "closed" / "trajectory.log"), truth) < 0.01
    assert main([*argv, "--no-loop-closure", "--out", str(tmp_path / "chained")]) == 0
    assert "loop closures not tried" in capsys.readouterr().out
    assert main([*argv[:-2], "--out", str(tmp_path / "plain")]) == 0
    assert "fragments: none (8 frames, not more than twice the fragment size 100)" in capsys.readouterr().out


def test_keyframe_every_sets_the_keyframe_pairs_of_each_fragments_pose_graph(sequence, tmp_path, capsys):
    folder, truth = sequence
    argv = ["scene", "from-rgbd", str(folder), "--voxel", "0.04", "--odometry-voxel", "0.05", "--device", "cpu",
            "--fragment-size", "3", "--no-loop-closure", "--no-progress"]
    assert main([*argv, "--keyframe-every", "2", "--out", str(tmp_path / "every2")]) == 0
    assert "fragments: 3 of 3 frames, each with its own pose graph (keyframes every 2 frames, 2 keyframe pairs" \
        in capsys.readouterr().out  # frames 0 and 2 of the two fragments of 3 (open3d's 5 would give none)
    report = json.loads((tmp_path / "every2" / "report.json").read_text())["fragments"]
    assert report["keyframe_every"] == 2 and report["keyframe_pairs"][0] == 2
    assert absolute_trajectory_error(read_log_trajectory(tmp_path / "every2" / "trajectory.log"), truth) < 0.01
    assert main([*argv, "--keyframe-every", "0", "--out", str(tmp_path / "none")]) == 0
    assert "the odometry kept within each (--keyframe-every 0)" in capsys.readouterr().out
    _one_line_error(capsys, [*argv, "--keyframe-every", "-1", "--out", tmp_path / "o"], "--keyframe-every")

def _one_line_error(capsys, argv, *fragments):
    assert main([str(a) for a in argv]) == 1
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("pointfield: error:"), captured.err
    for fragment in fragments:
        assert str(fragment) in lines[0], lines[0]


def test_a_missing_folder_is_one_line(capsys, tmp_path):
    _one_line_error(capsys, ["scene", "from-rgbd", tmp_path / "nowhere", "--out", tmp_path / "o"], "nowhere", "no such folder")


def test_unpaired_frames_are_one_line(capsys, sequence, tmp_path):
    folder, _ = sequence
    broken = tmp_path / "broken"
    shutil.copytree(folder, broken)
    (broken / "image" / "00007.jpg").rename(broken / "image" / "extra.jpg")
    (broken / "image" / "00006.jpg").unlink()
    _one_line_error(capsys, ["scene", "from-rgbd", broken, "--out", tmp_path / "o"], "unpaired frames", "8 depth", "7 colour")


def test_depth_of_another_size_than_the_colour_is_one_line(capsys, sequence, tmp_path):
    folder, _ = sequence
    broken = tmp_path / "broken"
    shutil.copytree(folder, broken)
    iio.imwrite(broken / "depth" / "00002.png", np.zeros((60, 80), np.uint16))
    _one_line_error(capsys, ["scene", "from-rgbd", broken, "--out", tmp_path / "o"], "00002.png", "80x60", "160x120")


@pytest.mark.parametrize("text, fragment", [
    ("{not json", "not a JSON file"),
    ('{"width": 640, "height": 480}', "intrinsic_matrix"),
    ('{"width": 640, "height": 480, "intrinsic_matrix": [1, 2, 3]}', "9 numbers"),
    ('{"width": 640, "height": 480, "intrinsic_matrix": [0, 0, 0, 0, 525, 0, 319.5, 239.5, 1]}', "pinhole"),
    ('{"width": -1, "height": 480, "intrinsic_matrix": [525, 0, 0, 0, 525, 0, 319.5, 239.5, 1]}', "positive integers"),
])
def test_bad_intrinsics_are_one_line(capsys, sequence, tmp_path, text, fragment):
    folder, _ = sequence
    camera = tmp_path / "bad.json"
    camera.write_text(text)
    _one_line_error(capsys, ["scene", "from-rgbd", folder, "--intrinsics", camera, "--out", tmp_path / "o"],
                    "bad.json", fragment)


def test_bad_options_are_one_line(capsys, sequence, tmp_path):
    folder, _ = sequence
    _one_line_error(capsys, ["scene", "from-rgbd", folder, "--out", tmp_path / "o", "--voxel", "0"], "--voxel")
    _one_line_error(capsys, ["scene", "from-rgbd", folder, "--out", tmp_path / "o", "--frames", "0"], "--frames")
    _one_line_error(capsys, ["scene", "from-rgbd", folder, "--out", tmp_path / "o", "--fusion-threads", "-1"],
                    "--fusion-threads")
    _one_line_error(capsys, ["scene", "from-rgbd", folder, "--out", tmp_path / "o", "--fragment-size", "-1"],
                    "--fragment-size")


def test_allocating_from_every_few_pixels_keeps_every_block_the_surface_passes_through(sequence):
    _, truth = sequence
    cameras = Cameras(torch.as_tensor(truth), CAMERA.fx, CAMERA.fy, CAMERA.cx, CAMERA.cy, CAMERA.width, CAMERA.height)
    depth = torch.from_numpy(render_depth(truth[0]).astype(np.float32))
    volume = TSDFVolume.create(ROOM[0] - 0.1, ROOM[1] + 0.1, 200)
    stride = allocation_stride(volume.voxel, CAMERA.fx, float(depth.max()))
    assert stride > 1  # the test means something: fewer rays than pixels
    every_pixel = set(volume.allocate(depth, cameras, 0).tolist())
    sparse = set(TSDFVolume.create(ROOM[0] - 0.1, ROOM[1] + 0.1, 200).allocate(depth, cameras, 0, stride).tolist())
    surface = TSDFVolume.create(ROOM[0] - 0.1, ROOM[1] + 0.1, 200)
    surface.truncation = 1e-9  # the band shrunk to the surface: the blocks the surface itself passes through
    assert set(surface.allocate(depth, cameras, 0).tolist()) <= sparse <= every_pixel
    assert len(sparse) >= 0.9 * len(every_pixel)
