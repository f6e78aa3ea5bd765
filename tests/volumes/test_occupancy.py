"""Occupancy maps: exact ray traversal, occupied / free / unknown from scans, OctoMap's answers, queries."""

from __future__ import annotations

import numpy as np
import pytest

from pointfield.volumes.occupancy import CLAMP, OccupancyMap, read_octomap, traverse, write_octomap

ROOM = (np.array([0.05, 0.05, 0.05]), np.array([3.95, 3.95, 2.95]))
"""Walls in the middle of 0.1 cells, so that no wall lies on a cell face."""


def room_scan(origin: np.ndarray, rays: int = 20_000, seed: int = 0) -> np.ndarray:
    """Where rays in random directions from ``origin`` meet the walls of :data:`ROOM`: a simulated lidar sweep."""
    direction = np.random.default_rng(seed).normal(size=(rays, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    low, high = ROOM
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(direction > 0, (high - origin) / direction, (low - origin) / direction)
    t = np.nan_to_num(t, nan=np.inf, posinf=np.inf).min(axis=1)
    return origin + direction * t[:, None]


SCANS = [(np.array([2.0, 2.0, 1.5]), 0), (np.array([1.0, 3.0, 1.0]), 1)]


def mapped() -> OccupancyMap:
    occupancy = OccupancyMap(0.1)
    for origin, seed in SCANS:
        occupancy.insert_scan(room_scan(origin, seed=seed), origin)
    return occupancy


def test_traversal_visits_every_cell_a_segment_crosses_once():
    start, end = np.array([[0.5, 0.5, 0.5]]), np.array([[3.7, 1.2, 0.5]])
    _, cells = traverse(start, end)
    # 3 steps in x and 1 in y: 4 face crossings, so 4 cells before the end cell (3, 1, 0).
    assert len(cells) == 4 and cells[0].tolist() == [0, 0, 0]
    assert (np.abs(np.diff(cells, axis=0)).sum(axis=1) == 1).all()  # one face at a time
    assert np.abs(cells[-1] - [3, 1, 0]).sum() == 1
    # Dense samples of the segment fall in no cell outside the traversal (plus the end cell).
    samples = np.floor(start + np.linspace(0, 1, 10_001)[:, None] * (end - start)).astype(int)
    assert {tuple(c) for c in samples} == {tuple(c) for c in cells} | {(3, 1, 0)}


def test_walls_are_occupied_the_room_free_and_outside_unknown():
    occupancy = mapped()
    low, high = ROOM
    wall_cells = np.unique(np.floor(np.concatenate([room_scan(o, seed=s) for o, s in SCANS]) / 0.1), axis=0)
    state = occupancy.state((wall_cells + 0.5) * 0.1)
    assert (state != 0).all()  # free space is never marked where a wall is
    assert (state == 1).mean() > 0.99
    inside = np.random.default_rng(2).uniform(low + 0.2, high - 0.2, (2000, 3))
    assert (occupancy.state(inside) == 0).mean() > 0.99
    assert (occupancy.state(np.array([[5.0, 5.0, 5.0], [-1.0, 2.0, 1.0]])) == -1).all()
    assert not occupancy.is_free(np.array([[5.0, 5.0, 5.0]]))[0]  # unknown is not free


def test_distance_to_the_nearest_obstacle():
    occupancy = mapped()
    distance = occupancy.distance_to_obstacle(np.array([[2.0, 2.0, 1.5], [0.5, 2.0, 1.5]]))
    # From the room's centre the nearest wall (the floor at z = 0.05) is 1.45 away; cell centres add up to 0.1.
    assert distance[0] == pytest.approx(1.45, abs=0.1)
    assert distance[1] == pytest.approx(0.45, abs=0.1)


def test_occupied_cells_become_a_voxel_grid_with_probabilities():
    grid = mapped().to_grid("occupied")
    assert len(grid) > 1000 and (grid.fields["probability"] > 0.5).all()
    assert np.allclose(grid.origin, [0.0, 0.0, 0.0], atol=1e-9)  # the lattice of the map, cells from 0


def test_the_map_agrees_with_octomap_cell_for_cell():
    octomap = pytest.importorskip("pyoctomap")
    ours = mapped()
    tree = octomap.OcTree(0.1)
    for origin, seed in SCANS:
        tree.insertPointCloud(room_scan(origin, seed=seed), origin)
    centres = ours.to_grid("known").centres()
    nodes = [tree.search(c) for c in centres]
    theirs = np.array([-1 if node is None else int(tree.isNodeOccupied(node)) for node in nodes])
    assert (ours.state(centres) == theirs).mean() > 0.999


def test_a_bt_file_reads_back_in_octomap_with_every_cell_as_it_was(tmp_path):
    octomap = pytest.importorskip("pyoctomap")
    ours = mapped()
    write_octomap(tmp_path / "room.bt", ours)
    tree = octomap.OcTree(0.1)
    assert tree.readBinary(str(tmp_path / "room.bt"))
    centres = ours.to_grid("known").centres()
    theirs = np.array([-1 if (node := tree.search(c)) is None else int(tree.isNodeOccupied(node)) for c in centres])
    assert np.array_equal(ours.state(centres), theirs)


def test_a_cell_hit_or_missed_scan_after_scan_saturates_at_octomaps_clamping_thresholds():
    occupancy = OccupancyMap(0.1)
    origin = np.array([0.05, 0.05, 0.05])
    for _ in range(20):  # the ray crosses the cells at x 0.1 .. 0.9 (missed) and ends in the one at x 1.0 (hit)
        occupancy.insert_scan(np.array([[1.05, 0.05, 0.05]]), origin)
    probability = 1 / (1 + np.exp(-occupancy.log_odds.astype(np.float64)))
    hit = occupancy.state(np.array([[1.05, 0.05, 0.05]]))[0] == 1
    # OctoMap's AbstractOccupancyOcTree: clamping thresholds 0.971 and 0.1192, not 0.97 and 0.12.
    assert hit and probability.max() == pytest.approx(0.971, abs=1e-6)
    assert probability.min() == pytest.approx(0.1192, abs=1e-6)


def test_rays_traversed_in_small_batches_give_the_same_map():
    whole, batched = OccupancyMap(0.1), OccupancyMap(0.1)
    for origin, seed in SCANS:
        whole.insert_scan(room_scan(origin, seed=seed), origin)
        batched.insert_scan(room_scan(origin, seed=seed), origin, batch_cells=5000)  # about 60 batches a scan
    assert np.array_equal(whole.keys, batched.keys) and np.array_equal(whole.log_odds, batched.log_odds)


def test_our_bt_reads_back_cell_for_cell(tmp_path):
    ours = mapped()
    write_octomap(tmp_path / "room.bt", ours)
    back = read_octomap(tmp_path / "room.bt")
    assert back.size == 0.1 and np.array_equal(back.keys, ours.keys)
    assert np.array_equal(back.log_odds > 0, ours.log_odds > 0)
    assert set(np.unique(back.log_odds)) <= {np.float32(CLAMP[0]), np.float32(CLAMP[1])}  # as OctoMap's reader sets


def test_octomaps_own_pruned_bt_reads_as_octomap_sees_it(tmp_path):
    octomap = pytest.importorskip("pyoctomap")
    tree = octomap.OcTree(0.1)
    for origin, seed in SCANS:
        tree.insertPointCloud(room_scan(origin, seed=seed), origin)
    tree.writeBinary(str(tmp_path / "theirs.bt"))  # pruned: eight equal children stored as their parent
    ours = mapped()
    write_octomap(tmp_path / "ours.bt", ours)  # unpruned
    assert (tmp_path / "theirs.bt").stat().st_size < (tmp_path / "ours.bt").stat().st_size / 2
    theirs = read_octomap(tmp_path / "theirs.bt")
    centres = theirs.to_grid("known").centres()
    expected = np.array([-1 if (node := tree.search(c)) is None else int(tree.isNodeOccupied(node)) for c in centres])
    assert np.array_equal(theirs.state(centres), expected)
    assert len(theirs.keys) == len(ours.keys)
