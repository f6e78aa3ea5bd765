"""pointfield.align and `cloud align`: many scans into one frame, loop closures reducing drift, scans that overlap
nothing left out with a warning, merged clouds of any size, and registration held to --memory."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from scan_rings import pose_errors, ring_scans
from scipy.spatial.transform import Rotation

import pointfield
from pointfield.cli import main
from pointfield.clouds.cloud import PointCloud
from pointfield.errors import PointfieldError
from pointfield.registration import PoseGraph, PoseGraphEdge, align, aligned, optimize_pose_graph, streamed
from pointfield.registration.result import information_matrix
from pointfield.streaming import memory


def shift(x: float, angle: float = 0.0) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = rotation_z(angle)
    out[0, 3] = x
    return out


def rotation_z(degrees: float) -> np.ndarray:
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


# -- the pose graph ------------------------------------------------------------------------------


def test_pose_graph_shares_a_loop_closures_disagreement_by_the_edges_information():
    """A chain of two unit steps and a loop closure that says 1.9: the optimum of the weighted squares."""
    info = 100 * np.eye(6)
    edges = [PoseGraphEdge(1, 0, shift(1.0), info), PoseGraphEdge(2, 1, shift(1.0), info),
             PoseGraphEdge(2, 0, shift(1.9), 4 * info, uncertain=True)]
    found = optimize_pose_graph(PoseGraph(np.stack([shift(0), shift(1), shift(2)]), edges),
                                preference_loop_closure=100.0)
    w = found.weights[2] * 4  # the loop closure's weight; the chain's two edges act as one of weight 1/2
    assert found.poses[2][0, 3] == pytest.approx((0.5 * 2.0 + w * 1.9) / (0.5 + w), abs=1e-6)
    assert found.poses[1][0, 3] == pytest.approx(found.poses[2][0, 3] / 2, abs=1e-6)
    np.testing.assert_allclose(found.poses[0], np.eye(4))  # the reference does not move


def test_pose_graph_prunes_a_loop_closure_that_contradicts_the_odometry():
    info = 100 * np.eye(6)
    chain = [PoseGraphEdge(i + 1, i, shift(1.0, 10.0), info) for i in range(3)]
    start = np.stack([np.eye(4), shift(1.0, 10.0), shift(1.0, 10.0) @ shift(1.0, 10.0),
                      shift(1.0, 10.0) @ shift(1.0, 10.0) @ shift(1.0, 10.0)])
    false_closure = PoseGraphEdge(3, 0, shift(0.2, 90.0), info, uncertain=True)
    found = optimize_pose_graph(PoseGraph(start, [*chain, false_closure]))
    assert found.pruned == [3] and found.weights[3] == 0.0
    np.testing.assert_allclose(found.poses, start, atol=1e-8)


def drifting_loop(count: int = 24, bias_degrees: float = 0.4, bias: float = 0.004):
    """``(truth, odometry, edges)``: a camera round a 1 m circle, back where it began (node ``count`` is node 0),
    whose odometry turns ``bias_degrees`` and slides ``bias`` metres too far every step; edges weighed as
    400 correspondences on a room's walls."""
    def pose(yaw: float, xyz) -> np.ndarray:
        out = np.eye(4)
        out[:3, :3], out[:3, 3] = rotation_z(yaw), xyz
        return out

    angles = 360.0 * np.arange(count + 1) / count
    truth = np.stack([pose(a, [np.cos(np.radians(a)), np.sin(np.radians(a)), 0.0]) for a in angles])
    walls = np.random.default_rng(0).uniform(-1.5, 1.5, (400, 3))
    walls[:200, 0], walls[200:, 2] = 1.5, -0.5
    info = information_matrix(walls, np.stack([np.arange(400)] * 2, 1))
    steps = [np.linalg.inv(truth[i]) @ truth[i + 1] @ pose(bias_degrees, [bias, bias, 0.0]) for i in range(count)]
    odometry = [np.eye(4)]
    for step in steps:
        odometry.append(odometry[-1] @ step)
    return truth, np.stack(odometry), [PoseGraphEdge(i + 1, i, step, info) for i, step in enumerate(steps)], info


def test_pose_graph_closes_a_loop_that_drifted_many_voxels_and_prunes_a_false_one():
    """The odometry drifts 8 voxels (of 2 cm) round the loop: far beyond the loop closure's tolerance
    (sqrt(5) voxels) measured on the chain, yet a true loop; the false one (a look-alike place, 40 degrees and
    60 cm off) contradicts the chain and the true loop."""
    truth, odometry, chain, info = drifting_loop()
    right = PoseGraphEdge(24, 0, np.linalg.inv(truth[0]) @ truth[24], info, uncertain=True)
    wrong_motion = shift(0.5, 40.0) @ np.linalg.inv(truth[0]) @ truth[12]
    wrong_motion[1, 3] -= 0.3
    wrong = PoseGraphEdge(12, 0, wrong_motion, info, uncertain=True)
    drift = np.linalg.norm(odometry[24, :3, 3] - odometry[0, :3, 3])
    assert drift > 8 * 0.02  # the test means something: far past sqrt(5) voxels
    found = optimize_pose_graph(PoseGraph(odometry, [*chain, right, wrong]), 0.02, preference_loop_closure=5.0)
    assert found.pruned == [25] and found.weights[24] > 0.5
    closed = np.linalg.norm(found.poses[24, :3, 3] - found.poses[0, :3, 3])
    assert closed < drift / 20
    # and the whole loop, not only its ends, comes nearer the truth (in node 0's frame, as the poses are)
    centres = (np.linalg.inv(truth[0]) @ truth)[:, :3, 3]
    assert np.abs(found.poses[:, :3, 3] - centres).max() < 0.5 * np.abs(odometry[:, :3, 3] - centres).max()


def test_pose_graph_prunes_a_false_loop_the_chain_could_bend_to():
    """Seed 1's ring with the chain of highest fitness: its loop closure 0-1 is 26 degrees off. Followed from weight 1
    (the graduated start) the chain bends to within the tolerance of it, but that costs more than pruning it: the
    lower cost of the two starts wins, and the poses are the chain's."""
    scans, truth = ring_scans(seed=1)
    result = align(scans, method="gicp", voxel=0.02)
    edges = [PoseGraphEdge(p.source, p.target, p.transformation, p.information, uncertain=p.kind == "loop closure")
             for p in result.pairs if p.kind]
    start = np.stack(result.initial_poses)
    found = optimize_pose_graph(PoseGraph(start, edges), 0.02, preference_loop_closure=5.0)
    assert [(edges[k].source, edges[k].target) for k in found.pruned] == [(0, 1)]
    assert all(pose_errors(found.poses[i], truth[i])[0] < 0.3 for i in range(4))


def test_pose_graph_refuses_an_edge_to_a_missing_node():
    with pytest.raises(PointfieldError, match="does not join"):
        optimize_pose_graph(PoseGraph(np.stack([np.eye(4)] * 2), [PoseGraphEdge(0, 5, np.eye(4), np.eye(6))]))


# -- align ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 2])
def test_align_recovers_the_poses_and_the_loop_closure_beats_chaining(seed):
    scans, truth = ring_scans(seed=seed)
    result = align(scans, method="gicp", voxel=0.02)
    kinds = {(p.source, p.target): p.kind for p in result.pairs if p.linked}
    assert kinds == {(0, 1): "odometry", (1, 2): "odometry", (2, 3): "odometry", (0, 3): "loop closure"}
    optimised = [pose_errors(result.poses[i], truth[i]) for i in range(4)]
    chained = [pose_errors(result.initial_poses[i], truth[i]) for i in range(4)]
    assert all(degrees < 0.2 and distance < 0.002 for degrees, distance in optimised), optimised
    # The chain drifts to its far end; the loop closure shares the drift out.
    assert max(d for d, _ in optimised) < 0.6 * max(d for d, _ in chained), (optimised, chained)
    assert np.mean([d for d, _ in optimised]) < np.mean([d for d, _ in chained])


def test_a_wrong_odometry_edge_is_outvoted_by_the_pairs_that_agree():
    """Seed 1: scans 0 and 1 register 26 degrees off with fitness 0.29; the other three pairs of the ring agree."""
    scans, truth = ring_scans(seed=1)
    result = align(scans, method="gicp", voxel=0.02)
    wrong = next(p for p in result.pairs if (p.source, p.target) == (0, 1))
    assert wrong.kind == "loop closure" and wrong.weight == 0.0
    assert all(pose_errors(result.poses[i], truth[i])[0] < 0.3 for i in range(4))
    assert any("highest fitness" in note for note in result.notes)


def test_a_scan_that_overlaps_none_is_left_out_with_a_warning():
    scans, truth = ring_scans(count=4, seed=0)
    elsewhere = PointCloud(np.random.default_rng(5).normal(size=(2000, 3)).astype(np.float32) + [5.0, 0, 0])
    with pytest.warns(UserWarning, match=r"scan 4: overlaps none of the aligned scans .*left out"):
        result = pointfield.align([*scans, elsewhere], method="gicp", voxel=0.02)
    assert result.left_out == [4] and result.poses[4] is None
    # From identity, ICP cannot reach a scan 4 units off: those pairs are not even tried.
    assert all(p.error.startswith("not tried") for p in result.pairs if 4 in (p.source, p.target))
    assert pose_errors(result.poses[3], truth[3])[0] < 0.2


def test_no_two_scans_overlapping_is_an_error_not_a_guess():
    rng = np.random.default_rng(0)
    far = [PointCloud(rng.normal(size=(500, 3)) + [10.0 * i, 0, 0]) for i in range(3)]
    with warnings.catch_warnings(), pytest.raises(PointfieldError, match="do not seem to overlap"):
        warnings.simplefilter("ignore")
        align(far, method="icp", voxel=0.1)


def test_survey_coordinates_keep_their_precision():
    """Scans 500 km from the origin (UTM-sized): the same poses as near it."""
    scans, truth = ring_scans(seed=2)
    offset = np.array([500_000.0, 4_000_000.0, 100.0])
    far = [PointCloud(s.points.astype(np.float64) + offset, dict(s.fields)) for s in scans]
    result = align(far, method="gicp", voxel=0.02)
    to_far = np.eye(4)
    to_far[:3, 3] = offset
    for i in range(4):  # poses in far coordinates are S P S^-1 for S the shift; compared near the scans
        degrees, distance = pose_errors(np.linalg.inv(to_far) @ result.poses[i] @ to_far, truth[i])
        assert degrees < 0.2 and distance < 0.002


# -- the command ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def scan_files(tmp_path_factory):
    """Four ring scans as PLY with an extra field, and a fifth scan of something else, far away."""
    folder = tmp_path_factory.mktemp("scans")
    scans, truth = ring_scans(seed=2)
    paths = []
    for i, scan in enumerate(scans):
        scan.fields["intensity"] = np.full(len(scan), i, np.float32)
        paths.append(folder / f"scan{i}.ply")
        pointfield.write(paths[-1], scan)
    stray = np.random.default_rng(5).normal(size=(1500, 3)).astype(np.float32) + [5.0, 0, 0]
    paths.append(folder / "stray.ply")
    pointfield.write(paths[-1], PointCloud(stray, {"colors": np.zeros((1500, 3), np.uint8),
                                                   "intensity": np.full(1500, 9, np.float32)}))
    return paths, truth


def test_cloud_align_writes_the_merged_cloud_and_the_poses_beside_it(scan_files, tmp_path, capsys):
    paths, truth = scan_files
    out = tmp_path / "merged.ply"
    assert main(["cloud", "align", *map(str, paths), "--out", str(out), "--method", "gicp", "--voxel", "0.02"]) == 0
    captured = capsys.readouterr()
    assert "pointfield: warning: stray.ply: overlaps none" in captured.err
    assert "scan0.ply -> scan3.ply: fitness" in captured.out and "loop closure" in captured.out
    merged = pointfield.read(out)
    assert len(merged) == 4 * 3000 and set(merged.fields) == {"colors", "intensity"}
    document = json.loads((tmp_path / "merged.poses.json").read_text())
    assert [s["left_out"] for s in document["scans"]] == [False] * 4 + [True]
    assert document["merged"]["points"] == len(merged)
    for i in range(4):  # each scan's points where the true pose puts them
        mine = merged.fields["intensity"] == i
        original = pointfield.read(paths[i]).points.astype(np.float64)
        expected = original @ truth[i][:3, :3].T + truth[i][:3, 3]
        assert np.abs(merged.points[mine] - expected).max() < 0.003
        assert pose_errors(np.array(document["scans"][i]["pose"]), truth[i])[0] < 0.2
    assert {p["kind"] for p in document["pairs"] if p["linked"]} == {"odometry", "loop closure"}


def test_the_merge_in_chunks_is_the_merge_in_memory(scan_files, tmp_path):
    paths, truth = scan_files
    out = tmp_path / "merged.ply"
    written = streamed.write_moved(paths[:4], truth, out, points=700)  # 3,000-point scans in 5 chunks each
    merged, expected = pointfield.read(out), [aligned(pointfield.read(p), t) for p, t in zip(paths[:4], truth)]
    assert written == len(merged) == 12_000
    np.testing.assert_array_equal(merged.points, np.concatenate([e.points for e in expected]))
    for name in ("colors", "intensity"):
        np.testing.assert_array_equal(merged.fields[name], np.concatenate([e.fields[name] for e in expected]))


def test_cloud_align_thins_scans_past_the_memory_budget_while_reading(scan_files, tmp_path, capsys, monkeypatch):
    paths, truth = scan_files
    monkeypatch.setattr(memory, "resident_bytes", lambda: 0)  # the budget, not this test process, decides
    monkeypatch.setattr(streamed, "PAIR_BYTES_PER_POINT", 15_000)  # 6,000 points need 90 MB: past the 64 MiB 256M leaves
    out = tmp_path / "merged.laz"
    assert main(["cloud", "align", *map(str, paths[:4]), "--out", str(out), "--method", "gicp", "--voxel", "0.02",
                 "--memory", "256M"]) == 0
    captured = capsys.readouterr()
    assert "read thinned while streaming to --voxel 0.02" in captured.err
    merged = pointfield.read(out)
    assert len(merged) == 4 * 3000  # the merge is written from the files, every point
    document = json.loads((tmp_path / "merged.poses.json").read_text())
    assert all(pose_errors(np.array(document["scans"][i]["pose"]), truth[i])[0] < 0.3 for i in range(4))


def test_cloud_align_refuses_in_one_line_naming_the_voxel_that_fits(scan_files, tmp_path, capsys, monkeypatch):
    paths, _ = scan_files
    monkeypatch.setattr(memory, "resident_bytes", lambda: 0)
    monkeypatch.setattr(streamed, "PAIR_BYTES_PER_POINT", 40_000)
    code = main(["cloud", "align", *map(str, paths[:4]), "--out", str(tmp_path / "m.ply"), "--voxel", "0.02",
                 "--memory", "256M"])
    err = capsys.readouterr().err
    assert code != 0 and err.count("\n") == 1
    assert "MiB that --memory 256 MiB leaves beside the interpreter; give --voxel 0.0" in err and not (tmp_path / "m.ply").exists()


def test_cloud_register_holds_to_the_memory_budget_too(scan_files, tmp_path, capsys, monkeypatch):
    paths, truth = scan_files
    monkeypatch.setattr(memory, "resident_bytes", lambda: 0)
    monkeypatch.setattr(streamed, "PAIR_BYTES_PER_POINT", 15_000)
    out = tmp_path / "moved.ply"
    assert main(["cloud", "register", str(paths[1]), str(paths[0]), "--method", "gicp", "--init", _identity(tmp_path),
                 "--voxel", "0.02", "--memory", "256M", "--out", str(out), "--json"]) == 0
    found = np.array(json.loads(capsys.readouterr().out)["transformation"])
    assert pose_errors(found, truth[1])[0] < 0.3
    assert len(pointfield.read(out)) == 3000


def test_cloud_register_counts_text_scans_without_reading_them_twice_or_warning(scan_files, tmp_path, capsys):
    paths, _ = scan_files
    text = []
    for path in paths[:2]:
        text.append(tmp_path / f"{path.stem}.xyz")
        pointfield.write(text[-1], pointfield.read(path))
    assert main(["cloud", "register", *map(str, text), "--method", "gicp", "--init", _identity(tmp_path),
                 "--voxel", "0.02"]) == 0
    assert "warning" not in capsys.readouterr().err


def _identity(folder) -> str:
    path = folder / "identity.json"
    path.write_text(json.dumps(np.eye(4).tolist()))
    return str(path)


@pytest.mark.parametrize("arguments, message", [
    (["{0}"], "at least two scans"),
    (["{0}", "{0}"], "given twice"),
    (["{0}", "missing.ply"], "missing.ply"),
    (["{0}", "{1}", "--voxel", "-1"], "--voxel must be a positive number"),
    (["{0}", "{1}", "--min-fitness", "2"], "between 0 and 1"),
    (["{0}", "{1}", "--memory", "lots"], "--memory 'lots'"),
    (["{0}", "{empty}"], "no points"),
])
def test_cloud_align_bad_input_is_one_line(scan_files, tmp_path, capsys, arguments, message):
    paths, _ = scan_files
    empty = tmp_path / "empty.ply"
    pointfield.write(empty, PointCloud(np.zeros((0, 3), np.float32)))
    filled = [a.format(paths[0], paths[1], empty=empty) if "{" in a else a for a in arguments]
    filled = [str(tmp_path / a) if a == "missing.ply" else a for a in filled]
    code = main(["cloud", "align", *filled, "--out", str(tmp_path / "out.ply")])
    err = capsys.readouterr().err
    assert code != 0 and err.count("\n") == 1 and err.startswith("pointfield: error:") and message in err, err
    assert not (tmp_path / "out.ply").exists()


# -- real scans ----------------------------------------------------------------------------------


def test_the_bunny_pair_and_a_third_view_align_to_pcls_ground_truth(shared_data):
    """bun0, bun4 and bun0's left half moved by a known motion: bun4's pose is the inverse of PCL's bun0 -> bun4."""
    bun0 = pointfield.read(shared_data / "registration" / "pcl_bun0.pcd")
    bun4 = pointfield.read(shared_data / "registration" / "pcl_bun4.pcd")
    truth = np.array([[0.825336, 0, -0.564642, 0.037267], [0, 1, 0, 0], [0.564642, 0, 0.825336, 0.038325],
                      [0, 0, 0, 1]])
    half = bun0.points[:, 0] < np.median(bun0.points[:, 0]) + 0.01
    motion = shift(0.05, 40.0)
    third = PointCloud((bun0.points[half].astype(np.float64) @ motion[:3, :3].T + motion[:3, 3]).astype(np.float32))
    result = align([bun0, bun4, third], method="global")
    assert result.left_out == []
    degrees, distance = pose_errors(result.poses[1], np.linalg.inv(truth))
    assert degrees < 2.0 and distance < 0.005, (degrees, distance)
    degrees, distance = pose_errors(result.poses[2], np.linalg.inv(motion))
    assert degrees < 2.0 and distance < 0.005, (degrees, distance)


def test_three_strips_of_an_aerial_survey_align_to_a_centimetre(shared_data, tmp_path, capsys):
    """autzen_trim.laz cut into three strips that overlap by 150 m, two of them moved by about a degree and a metre
    about the survey's centre (UTM coordinates): cloud align puts every point back within 2 cm, every field kept."""
    survey = pointfield.read(shared_data / "las" / "autzen_trim.laz")
    x, centre, rng = survey.points[:, 0], survey.points.mean(axis=0), np.random.default_rng(0)
    paths, truth = [], []
    for k, low in enumerate((x.min(), x.min() + 350, x.min() + 700)):
        strip = survey.select(np.flatnonzero((x >= low) & (x < low + 500)))
        pose = np.eye(4)
        if k:
            pose[:3, :3] = Rotation.from_rotvec(np.radians([0.3, -0.2, 1.0]) * rng.uniform(0.5, 1, 3)).as_matrix()
            pose[:3, 3] = centre - pose[:3, :3] @ centre + rng.normal(0, 1.0, 3)
        paths.append(tmp_path / f"strip{k}.laz")
        pointfield.write(paths[-1], aligned(strip, np.linalg.inv(pose)))
        truth.append(pose)
    out = tmp_path / "merged.laz"
    assert main(["cloud", "align", *map(str, paths), "--out", str(out), "--method", "gicp", "--voxel", "3"]) == 0
    assert "strip0.laz -> strip2.laz: fitness 0.000, RMSE 0: not linked (not tried" in capsys.readouterr().out
    poses = [np.array(s["pose"]) for s in json.loads((tmp_path / "merged.poses.json").read_text())["scans"]]
    for path, pose, true in zip(paths, poses, truth):
        points = pointfield.read(path).points
        error = (points @ pose[:3, :3].T + pose[:3, 3]) - (points @ true[:3, :3].T + true[:3, 3])
        assert np.sqrt(np.mean(np.sum(error**2, axis=1))) < 0.02
    merged = pointfield.read(out)
    assert len(merged) == sum(len(pointfield.read(p)) for p in paths)
    assert set(survey.fields) <= set(merged.fields)
