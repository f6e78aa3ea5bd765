"""Reading OctoMap's .bt level by level: the same leaves, cells and refusals as the node-by-node walk."""

from __future__ import annotations

import numpy as np
import pytest
from volumes.test_occupancy import room_scan

from pointfield.errors import FormatError
from pointfield.volumes.occupancy import (
    BtTree,
    OccupancyMap,
    octree_leaves,
    octree_leaves_by_walk,
    read_bt_header,
    read_octomap,
    read_octomap_by_walk,
    read_octomap_grid,
    write_octomap,
)

ORIGINS = [np.array([2.0, 2.0, 1.5]), np.array([1.0, 3.0, 1.0])]


def small_room(rays: int = 3000) -> OccupancyMap:
    occupancy = OccupancyMap(0.1)
    for seed, origin in enumerate(ORIGINS):
        occupancy.insert_scan(room_scan(origin, rays, seed), origin)
    return occupancy


def leaves_or_error(parse, tree: BtTree, **options) -> tuple:
    """The leaves sorted by (depth, key), or the error's message."""
    try:
        keys, depths, occupied = parse(tree, **options)
    except FormatError as error:
        return ("refused", str(error))
    order = np.lexsort((keys, depths))
    return keys[order].tolist(), depths[order].tolist(), occupied[order].tolist()


@pytest.fixture(scope="module")
def trees(tmp_path_factory) -> dict[str, BtTree]:
    """Our unpruned .bt of a small room and OctoMap's own pruned one of the same scans."""
    folder = tmp_path_factory.mktemp("bt")
    write_octomap(folder / "ours.bt", small_room())
    found = {"ours": read_bt_header(folder / "ours.bt")}
    try:
        import pyoctomap
    except ImportError:
        return found
    tree = pyoctomap.OcTree(0.1)
    for seed, origin in enumerate(ORIGINS):
        tree.insertPointCloud(room_scan(origin, 3000, seed), origin)
    tree.writeBinary(str(folder / "theirs.bt"))
    found["theirs"] = read_bt_header(folder / "theirs.bt")
    return found


def test_the_level_by_level_parse_finds_the_walks_leaves_in_ours_and_octomaps_pruned_tree(trees):
    if "theirs" not in trees:
        pytest.skip("pyoctomap is not installed: only our unpruned tree is compared")
    for tree in trees.values():
        fast = leaves_or_error(octree_leaves, tree)
        assert fast[0] != "refused" and fast == leaves_or_error(octree_leaves_by_walk, tree)
    assert max(leaves_or_error(octree_leaves, trees["theirs"])[1]) == 16
    assert min(leaves_or_error(octree_leaves, trees["theirs"])[1]) < 16  # pruned: leaves above the last level


def test_the_map_read_is_byte_for_byte_the_old_readers(trees):
    for tree in trees.values():
        fast, walked = read_octomap(tree.path), read_octomap_by_walk(tree.path)
        assert fast.size == walked.size and len(fast.keys) > 1000
        assert fast.keys.tobytes() == walked.keys.tobytes() and fast.log_odds.tobytes() == walked.log_odds.tobytes()


def test_a_cut_or_corrupted_tree_is_refused_as_the_walk_refuses_it(trees):
    tree = trees.get("theirs", trees["ours"])
    rng = np.random.default_rng(0)
    cuts = np.linspace(tree.at, len(tree.data) - 1, 12).astype(int)
    variants = [tree._replace(data=tree.data[:cut]) for cut in cuts]
    for _ in range(12):
        data = np.frombuffer(tree.data, np.uint8).copy()
        data[rng.integers(tree.at, len(data), 3)] = rng.integers(0, 256, 3)
        variants.append(tree._replace(data=data.tobytes()))
    # deep chains: one inner child per word reaches past OctoMap's 16 levels
    chains = np.array([0x0003, 0x0300, 0x00C2, 0xC001, 0x0009, 0x0000], np.uint16)
    for _ in range(60):
        words = chains[rng.choice(len(chains), int(rng.integers(1, 30)), p=[0.3, 0.3, 0.15, 0.15, 0.05, 0.05])]
        variants.append(BtTree(tree.path, b"data\n" + words.astype("<u2").tobytes(), 5, 20, 0.1))
    outcomes = set()
    for variant in variants:
        for options in ({}, {"max_bytes": 50_000}, {"max_bytes": 50_000, "occupied_only": True}):
            fast = leaves_or_error(octree_leaves, variant, **options)
            assert fast == leaves_or_error(octree_leaves_by_walk, variant, **options)
            outcomes.add(fast[1].split(": ")[1][:12] if fast[0] == "refused" else "read")
    # every kind of refusal, and some trees that still read, were met
    assert {"the tree is ", "a node at by", "its leaves c", "the tree has", "read"} <= outcomes


def test_the_occupied_grid_of_a_bt_has_the_maps_occupied_cells(trees):
    for tree in trees.values():
        grid = read_octomap_grid(tree.path)
        expected = read_octomap(tree.path).to_grid("occupied")
        assert len(grid) > 100 and grid.size == pytest.approx(0.1)
        assert np.array_equal(np.sort(grid.centres(), axis=0), np.sort(expected.centres(), axis=0))


def test_the_occupied_grid_expands_no_free_leaf(tmp_path):
    # One occupied cell and a free leaf of 8^15 cells at depth 1: only the occupied cell is made.
    root = 1 << 0 | 3 << 2  # child 0 a free leaf, child 1 inner
    chain = [3 << 0] * 14  # child 0 inner, down to depth 15
    last = 2  # child 0 an occupied leaf at depth 16
    words = np.array([root, *chain, last], "<u2")
    bt = tmp_path / "one.bt"
    bt.write_bytes(f"# Octomap OcTree binary file\nid OcTree\nsize {1 + 2 + 14 + 1}\nres 0.5\ndata\n".encode()
                   + words.tobytes())
    grid = read_octomap_grid(bt, max_bytes=1 << 20)
    # OctoMap key (2^15, 0, 0) is our cell (0, -2^15, -2^15).
    assert len(grid) == 1 and np.allclose(grid.centres(), [[0.25, -(2**15) * 0.5 + 0.25, -(2**15) * 0.5 + 0.25]])
    with pytest.raises(FormatError, match="cover at least 35,184,372,088,832 cells"):
        read_octomap(bt, max_bytes=1 << 20)
