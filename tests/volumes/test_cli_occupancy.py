"""`pointfield cloud occupancy` and `occupancy-query`: maps from scans with poses or from a scene's depth, and
their one-line errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
from volumes.test_occupancy import ROOM, SCANS, room_scan

import pointfield
from pointfield.cli import main
from pointfield.volumes import read_voxels
from pointfield.volumes.occupancy import read_octomap

VOXEL = 0.1


def scan_files(tmp_path) -> tuple[list, object]:
    """The two simulated lidar sweeps of the room, each in its sensor's frame, and cloud align's poses of them."""
    files, entries = [], []
    for index, (origin, seed) in enumerate(SCANS):
        files.append(tmp_path / f"sweep{index}.ply")
        pointfield.write(files[-1], pointfield.PointCloud((room_scan(origin, seed=seed) - origin).astype(np.float32)))
        pose = np.eye(4)
        pose[:3, 3] = origin
        entries.append({"scan": str(files[-1]), "pose": pose.tolist(), "left_out": False})
    poses = tmp_path / "merged.poses.json"
    poses.write_text(json.dumps({"reference": 0, "voxel": 0.05, "scans": entries, "pairs": [], "notes": []}))
    return files, poses


def wall_cells() -> np.ndarray:
    return np.unique(np.floor(np.concatenate([room_scan(o, seed=s) for o, s in SCANS]) / VOXEL), axis=0)


def test_scans_moved_by_their_poses_map_walls_occupied_and_the_space_before_them_free(tmp_path, capsys):
    files, poses = scan_files(tmp_path)
    bt, npz = tmp_path / "room.bt", tmp_path / "room.npz"
    assert main(["cloud", "occupancy", *map(str, files), "--poses", str(poses), "--voxel", str(VOXEL),
                 "--out", str(bt), "--out", str(npz), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    occupancy = read_octomap(bt)
    state = occupancy.state((wall_cells() + 0.5) * VOXEL)
    assert (state != 0).all() and (state == 1).mean() > 0.99  # never free where a wall was measured
    # Between each sensor and the wall its ray met: free, but for the last cell (the wall's).
    origin, seed = SCANS[1]
    ends = room_scan(origin, rays=500, seed=7)
    before = origin + (ends - origin) * np.linspace(0.05, 0.9, 20)[:, None, None]
    before = before[np.linalg.norm(ends - before, axis=2) > 2 * VOXEL]
    assert (occupancy.state(before) == 0).mean() > 0.99
    assert (occupancy.state(np.array([[6.0, 2.0, 1.0]])) == -1).all()  # behind the wall: unknown
    assert summary["scans"] == 2 and summary["occupied"] == int((occupancy.log_odds > 0).sum())
    assert summary["free"] == len(occupancy.keys) - summary["occupied"] and summary["unknown"] > 0
    assert np.allclose(summary["bounds"], [[0, 0, 0], [4, 4, 3]])
    grid = read_voxels(npz)
    assert len(grid) == summary["occupied"] and (grid.fields["probability"] > 0.5).all()


def test_poses_alone_name_the_scans(tmp_path, capsys):
    _, poses = scan_files(tmp_path)
    assert main(["cloud", "occupancy", "--poses", str(poses), "--voxel", str(VOXEL),
                 "--out", str(tmp_path / "room.bt")]) == 0
    printed = capsys.readouterr().out
    assert "2 scans, 40,000 points, cells of 0.1:" in printed and "occupied" in printed and "unknown" in printed


def test_the_bt_reads_back_in_octomap(tmp_path):
    octomap = pytest.importorskip("pyoctomap")
    files, poses = scan_files(tmp_path)
    bt = tmp_path / "room.bt"
    assert main(["cloud", "occupancy", "--poses", str(poses), "--voxel", str(VOXEL), "--out", str(bt)]) == 0
    ours = read_octomap(bt)
    tree = octomap.OcTree(VOXEL)
    assert tree.readBinary(str(bt))
    centres = ours.to_grid("known").centres()
    theirs = np.array([-1 if (node := tree.search(c)) is None else int(tree.isNodeOccupied(node)) for c in centres])
    assert np.array_equal(ours.state(centres), theirs)


def test_a_scenes_depth_frames_seen_from_its_cameras_make_the_map(tmp_path, capsys):
    import torch

    from pointfield.scenes import Cameras
    from pointfield.scenes.cameras import look_at
    from pointfield.scenes.formats.registry import write_scene
    from pointfield.scenes.scene import Frame, Scene

    low, high = ROOM
    eyes = np.array([[2.0, 2.0, 1.5], [1.0, 1.0, 1.0], [3.0, 3.0, 2.0], [1.0, 3.0, 1.5]])
    cameras = Cameras(look_at(eyes, target=(2.5, 2.0, 1.0)), fx=30.0, fy=30.0,
                      cx=32.0, cy=24.0, width=64, height=48)
    frames = []
    for index in range(len(eyes)):
        rays = cameras.rays(index)
        origin, direction = rays.origins.numpy(), rays.directions.numpy()
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(direction > 0, (high - origin) / direction, (low - origin) / direction)
        t = np.nan_to_num(t, nan=np.inf, posinf=np.inf).min(axis=-1)
        depth = (t * rays.axis_cosine.numpy()).astype(np.float32)
        frames.append(Frame(f"frame{index}", image=np.zeros((48, 64, 3), np.uint8), depth=depth))
    scene = tmp_path / "scene"
    write_scene(Scene(cameras.to(dtype=torch.float32), frames), scene)
    out = tmp_path / "scene.bt"
    assert main(["cloud", "occupancy", "--scene", str(scene), "--stride", "1", "--voxel", str(VOXEL),
                 "--out", str(out)]) == 0
    assert "4 depth frames" in capsys.readouterr().out
    occupancy = read_octomap(out)
    seen = np.concatenate([cameras.unproject(i, torch.tensor([[32.0, 24.0], [10.5, 40.5]], dtype=torch.float64),
                                             torch.tensor([d.depth[24, 32], d.depth[40, 10]], dtype=torch.float64))
                           .numpy() for i, d in enumerate(frames)])
    assert (occupancy.state(seen) == 1).all()  # where the depth ended
    assert (occupancy.state((eyes + seen[::2]) / 2) == 0).all()  # halfway from each camera to its centre pixel's wall


def test_query_answers_free_occupied_unknown_and_the_distance_to_the_nearest_obstacle(tmp_path, capsys):
    _, poses = scan_files(tmp_path)
    bt = tmp_path / "room.bt"
    assert main(["cloud", "occupancy", "--poses", str(poses), "--voxel", str(VOXEL), "--out", str(bt)]) == 0
    capsys.readouterr()
    assert main(["cloud", "occupancy-query", str(bt), "--points", "2,2,1.5", "0.05,2,1.5",
                 "--points=-3,2,1", "--json"]) == 0
    answers = json.loads(capsys.readouterr().out)["points"]
    assert [a["state"] for a in answers] == ["free", "occupied", "unknown"]
    assert answers[0]["distance"] == pytest.approx(1.45, abs=VOXEL)  # the floor at z = 0.05
    assert answers[1]["distance"] < VOXEL
    assert main(["cloud", "occupancy-query", str(bt), "--points", "2,2,1.5"]) == 0
    assert capsys.readouterr().out.startswith("2,2,1.5: free, nearest obstacle 1.4")


def test_a_ray_past_max_range_frees_space_up_to_the_range_and_marks_no_hit(tmp_path):
    scan = tmp_path / "rays.ply"
    pointfield.write(scan, pointfield.PointCloud(np.array([[5.05, 0.05, 0.05], [0.05, 1.05, 0.05]], np.float32)))
    out = tmp_path / "rays.bt"
    assert main(["cloud", "occupancy", str(scan), "--voxel", str(VOXEL), "--max-range", "2", "--out", str(out)]) == 0
    state = read_octomap(out).state(np.array([[1.95, 0.05, 0.05], [2.25, 0.05, 0.05], [5.05, 0.05, 0.05],
                                              [0.05, 1.05, 0.05]]))
    assert state.tolist() == [0, -1, -1, 1]  # free to 2, unknown past it and at the far point; the near one a hit


def test_query_points_from_a_file(tmp_path, capsys):
    files, poses = scan_files(tmp_path)
    bt = tmp_path / "room.bt"
    assert main(["cloud", "occupancy", "--poses", str(poses), "--voxel", str(VOXEL), "--out", str(bt)]) == 0
    queries = tmp_path / "queries.xyz"
    np.savetxt(queries, [[2.0, 2.0, 1.5], [1.0, 1.0, 1.0], [9.0, 9.0, 9.0]])
    capsys.readouterr()
    assert main(["cloud", "occupancy-query", str(bt), "--points-file", str(queries), "--json"]) == 0
    assert [a["state"] for a in json.loads(capsys.readouterr().out)["points"]] == ["free", "free", "unknown"]


def one_line_error(capsys, argv: list[str], *expected: str) -> None:
    assert main(argv) == 1
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and error.startswith("pointfield: error: "), error
    for text in expected:
        assert text in error, error


def test_a_voxel_too_small_for_memory_names_the_voxel_that_fits_and_writes_nothing(tmp_path, capsys):
    _, poses = scan_files(tmp_path)
    out = tmp_path / "room.bt"
    one_line_error(capsys, ["cloud", "occupancy", "--poses", str(poses), "--voxel", "0.0005", "--memory", "300M",
                            "--out", str(out)], "a voxel of 0.0005 makes a map that may take", "GiB",
                   "more than the 300 MiB allowed: a voxel of 0.0", "or larger fits")
    assert not out.exists()


def test_the_voxel_the_message_names_is_the_smallest_that_fits(tmp_path):
    from pointfield.cli.cloud_occupancy import fitting_voxel
    from pointfield.volumes.occupancy import occupancy_bytes
    from pointfield.volumes.scans import read_poses, scans_from_files

    files, poses = scan_files(tmp_path)
    scans = scans_from_files(files, poses=[p for _, p in read_poses(poses)])
    fits = fitting_voxel(scans, 0.0005, None, 300 << 20)
    assert occupancy_bytes(scans, fits, None) <= 300 << 20 < occupancy_bytes(scans, fits * 0.9, None)


def test_scans_that_do_not_match_the_poses_are_refused(tmp_path, capsys):
    files, poses = scan_files(tmp_path)
    out = tmp_path / "room.bt"
    one_line_error(capsys, ["cloud", "occupancy", str(files[0]), "--poses", str(poses), "--voxel", "0.1",
                            "--out", str(out)], "holds 2 poses but 1 scans were given")
    one_line_error(capsys, ["cloud", "occupancy", str(files[1]), str(files[0]), "--poses", str(poses), "--voxel",
                            "0.1", "--out", str(out)], "pose 0 is sweep0.ply's but scan 0 is sweep1.ply")
    assert not out.exists()


def test_depth_frame_options_on_scans_are_refused_not_ignored(tmp_path, capsys):
    files, _ = scan_files(tmp_path)
    out = tmp_path / "room.bt"
    one_line_error(capsys, ["cloud", "occupancy", str(files[0]), "--stride", "2", "--voxel", "0.1", "--out", str(out)],
                   "--stride apply to --scene's depth frames, not to scans")
    assert not out.exists()


@pytest.mark.parametrize("text, expected", [
    ("{not json", "not a poses file: invalid JSON"),
    ('{"poses": []}', "expected cloud align's"),
    ('{"scans": [{"scan": "a.ply", "pose": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]]}]}', "must be 4 x 4"),
    ('{"scans": [{"scan": "a.ply", "pose": [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}]}',
     "not a rigid motion"),
])
def test_a_malformed_poses_file_is_one_line_naming_it(tmp_path, capsys, text, expected):
    poses = tmp_path / "bad.poses.json"
    poses.write_text(text)
    out = tmp_path / "room.bt"
    one_line_error(capsys, ["cloud", "occupancy", "--poses", str(poses), "--voxel", "0.1", "--out", str(out)],
                   f"{poses}: ", expected)
    assert not out.exists()


def test_a_truncated_bt_is_one_line(tmp_path, capsys):
    _, poses = scan_files(tmp_path)
    bt = tmp_path / "room.bt"
    assert main(["cloud", "occupancy", "--poses", str(poses), "--voxel", str(VOXEL), "--out", str(bt)]) == 0
    cut = tmp_path / "cut.bt"
    cut.write_bytes(bt.read_bytes()[:-100])
    capsys.readouterr()
    one_line_error(capsys, ["cloud", "occupancy-query", str(cut), "--points", "1,1,1"], f"{cut}: the tree is cut short at byte")
    header_only = tmp_path / "header.bt"
    header_only.write_bytes(bt.read_bytes()[:40])
    one_line_error(capsys, ["cloud", "occupancy-query", str(header_only), "--points", "1,1,1"], "no 'data' line")


def test_an_output_that_cannot_be_written_leaves_no_output_at_all(tmp_path, capsys):
    scan = tmp_path / "rays.ply"
    pointfield.write(scan, pointfield.PointCloud(np.array([[3.0, 0.05, 0.05], [0.05, 3.0, 0.05]], np.float32)))
    bt, vox = tmp_path / "rays.bt", tmp_path / "rays.vox"
    # 3 m at 1 cm is 300 cells, more than a MagicaVoxel model holds: the .bt, written before it, goes too.
    one_line_error(capsys, ["cloud", "occupancy", str(scan), "--voxel", "0.01", "--out", str(bt), "--out", str(vox)],
                   "MagicaVoxel")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rays.ply"]
