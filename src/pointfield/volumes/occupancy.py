"""Occupancy maps for robots: occupied, free and unknown space from scans and their sensor origins, as OctoMap.

Each scan is a set of points and the sensor origin they were seen from. As OctoMap's
``insertPointCloud`` does (Hornung et al. 2013), every ray from the origin to a point passes
through free cells and ends in an occupied one; per scan, a cell is updated once (occupied wins
over free when rays both end and pass there), in log-odds:

    L(cell) <- clamp(L(cell) + log(p / (1 - p)), L_min, L_max)
    p = 0.7 for a hit, 0.4 for a miss; clamped to probabilities [0.1192, 0.971]   (OctoMap's defaults)

A cell is occupied when ``L > 0`` (probability above 1/2), free when ``L <= 0``, unknown when no
ray reached it. The cells a ray passes through are found exactly by Amanatides and Woo's voxel
traversal (the 3D DDA OctoMap's ``computeRayKeys`` runs), vectorised over the rays of a scan. A
ray longer than ``max_range`` marks free space up to that range and no hit (OctoMap's rule).

Cells are ``floor(p / size)`` on a lattice through the world origin, as in OctoMap (within
``2^20`` cells of it along each axis). The map is sparse: sorted cell keys and their log-odds.
:func:`write_octomap` writes it as OctoMap's ``.bt``, which OctoMap's tools and pyoctomap read;
:func:`read_octomap` reads a ``.bt`` back (OctoMap's own, pruned or not), a level of the tree at a time,
and :func:`read_octomap_grid` only its occupied cells, as a :class:`VoxelGrid`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from pointfield.atomic import atomic_path
from pointfield.errors import FormatError, PointfieldError
from pointfield.volumes.voxels import VoxelGrid, human_bytes


def logit(p: float) -> float:
    return float(np.log(p / (1 - p)))


HIT, MISS = logit(0.7), logit(0.4)
CLAMP = (logit(0.1192), logit(0.971))
"""OctoMap's clamping thresholds (AbstractOccupancyOcTree's defaults): how sure a cell can get, so how many
misses turn a well-seen wall free again."""
KEY_BITS = 21
KEY_OFFSET = 1 << (KEY_BITS - 1)


def cell_keys(cells: np.ndarray) -> np.ndarray:
    """``(N,)`` int64 keys of ``(N, 3)`` integer cells, increasing in lexicographic order."""
    shifted = cells.astype(np.int64) + KEY_OFFSET
    if len(shifted) and (shifted.min() < 0 or shifted.max() >= 1 << KEY_BITS):
        raise PointfieldError(f"a cell lies more than {KEY_OFFSET:,} voxels from the origin: use a larger voxel")
    return (shifted[:, 0] << (2 * KEY_BITS)) | (shifted[:, 1] << KEY_BITS) | shifted[:, 2]


def key_cells(keys: np.ndarray) -> np.ndarray:
    mask = (1 << KEY_BITS) - 1
    return np.stack([keys >> (2 * KEY_BITS), (keys >> KEY_BITS) & mask, keys & mask], axis=1) - KEY_OFFSET


def traverse(start: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The cells each segment passes through before its end cell (Amanatides and Woo), in voxel units.

    ``start``, ``end`` ``(R, 3)`` float64 positions divided by the voxel size. Returns ``(ray, cells)``:
    ``(M,)`` the segment of each visited cell and ``(M, 3)`` the cells, the start cell included and
    the end cell not. A segment crosses exactly ``|end_cell - start_cell|_1`` cell faces.
    """
    cell = np.floor(start).astype(np.int64)
    last = np.floor(end).astype(np.int64)
    direction = end - start
    step = np.sign(direction).astype(np.int64)
    with np.errstate(divide="ignore", invalid="ignore"):
        delta = np.where(direction != 0, 1.0 / np.abs(direction), np.inf)
        boundary = np.where(step > 0, cell + 1 - start, start - cell)
        t_max = np.where(direction != 0, boundary * delta, np.inf)
    remaining = np.abs(last - cell).sum(axis=1)
    rays, cells = [np.flatnonzero(remaining > 0)], [cell[remaining > 0]]
    active = np.flatnonzero(remaining > 0)
    while len(active):
        axis = np.argmin(t_max[active], axis=1)
        cell[active, axis] += step[active, axis]
        t_max[active, axis] += delta[active, axis]
        remaining[active] -= 1
        active = active[remaining[active] > 0]
        rays.append(active)
        cells.append(cell[active])
    return np.concatenate(rays), np.concatenate(cells)


BATCH_CELLS = 1 << 21
"""Cells visited per batch of rays in :meth:`OccupancyMap.insert_scan`: about 64 bytes each while traversed."""
BYTES_PER_CELL = 48
"""What a known cell of the map costs at the peak of an update: its key and log-odds, the merged copies of
:meth:`OccupancyMap._update` and the scan's unique keys (:func:`occupancy_bytes`)."""


def ray_batches(start: np.ndarray, ends: np.ndarray, batch_cells: int) -> list[np.ndarray]:
    """``ends`` ``(R, 3)`` (voxel units) cut into consecutive batches whose rays from ``start`` ``(3,)`` visit
    about ``batch_cells`` cells together (``|end_cell - start_cell|_1 + 1`` each; a batch holds at least one ray)."""
    lengths = np.abs(np.floor(ends) - np.floor(start)).sum(axis=1) + 1
    batch = np.floor_divide(np.cumsum(lengths) - lengths, max(int(batch_cells), 1)).astype(np.int64)
    cuts = np.flatnonzero(np.diff(batch)) + 1
    return np.split(ends, cuts) if len(ends) else []


def occupancy_bytes(scans: list[tuple[np.ndarray, np.ndarray]], size: float, max_range: float | None = None) -> int:
    """An upper bound on the memory a map of cells of ``size`` built from ``scans`` takes at its peak.

    ``scans`` ``[(points (N, 3), origin (3,)), ...]``. The cells a map can know are the cells its rays
    visit, and no more than those of the box around the origins and ray ends; each costs
    :data:`BYTES_PER_CELL`, and a batch of rays :data:`BATCH_CELLS` times 64 bytes more.
    """
    low, high = np.full(3, np.inf), np.full(3, -np.inf)
    visited = 0.0
    for points, origin in scans:
        ends = _ray_ends(np.asarray(points, np.float64).reshape(-1, 3), np.asarray(origin, np.float64), max_range)[0]
        if not len(ends):
            continue
        cells = np.floor(ends / size)
        start = np.floor(np.asarray(origin, np.float64) / size)
        visited += float((np.abs(cells - start).sum(axis=1) + 1).sum())
        low = np.minimum(low, np.minimum(cells.min(axis=0), start))
        high = np.maximum(high, np.maximum(cells.max(axis=0), start))
    box = float(np.prod(high - low + 1)) if visited else 0.0
    return int(min(box, visited) * BYTES_PER_CELL + min(visited, BATCH_CELLS) * 64)


def _ray_ends(points: np.ndarray, origin: np.ndarray, max_range: float | None) -> tuple[np.ndarray, np.ndarray]:
    """``(ends (N, 3), hit (N,))``: the finite points, those farther than ``max_range`` from ``origin`` moved
    back to that range (OctoMap's rule: free up to there, no hit)."""
    points = points[np.isfinite(points).all(axis=1)]
    if max_range is None:
        return points, np.ones(len(points), bool)
    offset = points - origin
    length = np.linalg.norm(offset, axis=1)
    hit = length <= max_range
    return np.where(hit[:, None], points, origin + offset * (max_range / np.maximum(length, 1e-300))[:, None]), hit


@dataclass
class OccupancyMap:
    """A sparse probabilistic occupancy map of cubes of side ``size`` (module docstring)."""

    size: float
    keys: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    log_odds: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    _obstacles: cKDTree | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if not self.size > 0:
            raise PointfieldError(f"the voxel size must be positive, got {self.size}")

    def insert_scan(self, points: np.ndarray, origin: np.ndarray, max_range: float | None = None,
                    batch_cells: int = BATCH_CELLS) -> None:
        """Update the map with the rays from ``origin`` ``(3,)`` to each of ``points`` ``(N, 3)`` (world units).

        The rays are traversed in batches of about ``batch_cells`` visited cells (each batch's cells
        reduced to unique keys before the next), so that a scan's working memory is bounded by its
        batch and the cells it sees, not by the sum of its rays' lengths; the map does not depend on it.
        """
        origin = np.asarray(origin, np.float64).reshape(3)
        ends, hit = _ray_ends(np.asarray(points, np.float64).reshape(-1, 3), origin, max_range)
        start = origin / self.size
        passed = [np.unique(cell_keys(traverse(np.broadcast_to(start, (len(part), 3)), part)[1]))
                  for part in ray_batches(start, ends / self.size, batch_cells)]
        occupied = np.unique(cell_keys(np.floor(ends[hit] / self.size).astype(np.int64)))
        ends_free = cell_keys(np.floor(ends[~hit] / self.size).astype(np.int64))  # cut at max_range: free to there
        free = np.setdiff1d(np.unique(np.concatenate([*passed, ends_free])), occupied, assume_unique=True)
        self._update(free, MISS)
        self._update(occupied, HIT)
        self._obstacles = None

    def _update(self, keys: np.ndarray, change: float) -> None:
        merged = np.union1d(self.keys, keys)
        values = np.zeros(len(merged), np.float32)
        values[np.searchsorted(merged, self.keys)] = self.log_odds
        at = np.searchsorted(merged, keys)
        values[at] = np.clip(values[at] + change, *CLAMP)
        self.keys, self.log_odds = merged, values

    def _log_odds_at(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        keys = cell_keys(np.floor(np.asarray(points, np.float64).reshape(-1, 3) / self.size).astype(np.int64))
        at = np.minimum(np.searchsorted(self.keys, keys), max(len(self.keys) - 1, 0))
        known = (self.keys[at] == keys) if len(self.keys) else np.zeros(len(keys), bool)
        return known, np.where(known, self.log_odds[at] if len(self.keys) else 0.0, 0.0)

    def state(self, points: np.ndarray) -> np.ndarray:
        """Per point ``(N,)`` int8: 1 occupied, 0 free, -1 unknown."""
        known, values = self._log_odds_at(points)
        return np.where(known, (values > 0).astype(np.int8), np.int8(-1)).astype(np.int8)

    def is_free(self, points: np.ndarray) -> np.ndarray:
        """``(N,)`` bool: the point's cell was seen and is free (unknown is not free: a planner must not go there)."""
        return self.state(points) == 0

    def occupied_cells(self) -> np.ndarray:
        return key_cells(self.keys[self.log_odds > 0])

    def distance_to_obstacle(self, points: np.ndarray) -> np.ndarray:
        """``(N,)`` distance from each point to the nearest occupied cell's centre (inf with none)."""
        if self._obstacles is None:
            centres = (self.occupied_cells() + 0.5) * self.size
            self._obstacles = cKDTree(centres) if len(centres) else None
        if self._obstacles is None:
            return np.full(len(np.asarray(points).reshape(-1, 3)), np.inf)
        distance, _ = self._obstacles.query(np.asarray(points, np.float64).reshape(-1, 3), workers=-1)
        return distance

    def to_grid(self, which: str = "occupied") -> VoxelGrid:
        """The ``occupied`` (or ``free``, or ``known``) cells as a :class:`VoxelGrid` with their ``probability``."""
        chosen = {"occupied": self.log_odds > 0, "free": self.log_odds <= 0,
                  "known": np.ones(len(self.keys), bool)}[which]
        cells = key_cells(self.keys[chosen])
        if not len(cells):
            return VoxelGrid(np.zeros((0, 3), np.int64), np.zeros(3), self.size)
        low = cells.min(axis=0)
        probability = (1 / (1 + np.exp(-self.log_odds[chosen]))).astype(np.float32)
        return VoxelGrid(cells - low, low * self.size, self.size, {"probability": probability},
                         metadata={"occupancy": which})


OCTOMAP_DEPTH = 16
OCTOMAP_OFFSET = 1 << (OCTOMAP_DEPTH - 1)


def _morton(keys: np.ndarray) -> np.ndarray:
    """48-bit Morton codes of ``(N, 3)`` 16-bit OctoMap keys: at each level, bit x | y << 1 | z << 2 (OctoMap's child index)."""
    code = np.zeros(len(keys), np.int64)
    for bit in range(OCTOMAP_DEPTH):
        for axis in range(3):
            code |= ((keys[:, axis] >> bit) & 1).astype(np.int64) << (3 * bit + axis)
    return code


def write_octomap(path: str | os.PathLike[str], occupancy: OccupancyMap) -> None:
    """Write the map as an OctoMap binary tree (``.bt``), as ``OcTree::writeBinary`` does, atomically.

    OctoMap's binary format keeps each cell as occupied or free (no probability): after a header,
    the tree depth first, two bytes per inner node giving each of its 8 children 2 bits -- 0
    unknown, 1 (bit ``2i``) a free leaf, 2 (bit ``2i + 1``) an occupied leaf, 3 an inner node --
    children 0..3 in the first byte, 4..7 in the second. Cells must lie within 2^15 of the origin
    (OctoMap's 16-level key space). The tree is written unpruned.

    Built level by level on the cells' Morton codes, without a walk: the inner nodes at depth ``d``
    are the distinct codes shifted right by ``3 (16 - d)``, each child adds its 2 bits to its parent's
    word, and depth-first order is the order of (code shifted back left, depth): a node comes before
    its first child, which has the same shifted-back code, and its subtree before its next sibling.
    """
    cells = key_cells(occupancy.keys) + OCTOMAP_OFFSET
    if len(cells) and (cells.min() < 0 or cells.max() >= 1 << OCTOMAP_DEPTH):
        raise PointfieldError(f"{path}: a cell lies more than {OCTOMAP_OFFSET:,} voxels from the origin, beyond "
                              "OctoMap's 16-level keys: use a larger voxel")
    code = _morton(cells)
    order = np.argsort(code)
    code, occupied = code[order], (occupancy.log_odds > 0)[order]
    positions, depths, words = [], [], []
    nodes = 1 if len(code) else 0
    children, kinds = code, np.where(occupied, 2, 1)  # the leaves, at depth 16
    for depth in range(OCTOMAP_DEPTH - 1, -1, -1):  # inner nodes at this depth, from their children below
        parents, parent_of = np.unique(children >> 3, return_inverse=True)
        word = np.bincount(parent_of, weights=kinds << (2 * (children & 7)), minlength=len(parents))
        positions.append(parents << (3 * (OCTOMAP_DEPTH - depth)))
        depths.append(np.full(len(parents), depth))
        words.append(word.astype(np.uint16))
        nodes += len(children)
        children, kinds = parents, np.full(len(parents), 3)
    if len(code):
        positions, depths, words = (np.concatenate(a) for a in (positions, depths, words))
        body = words[np.lexsort((depths, positions))].astype("<u2").tobytes()
    else:
        body = b""
    header = (f"# Octomap OcTree binary file\n# written by pointfield\nid OcTree\nsize {nodes}\n"
              f"res {occupancy.size!r}\ndata\n").encode("ascii")
    with atomic_path(Path(path)) as tmp:
        tmp.write_bytes(header + body)


OCTOMAP_MAGIC = b"# Octomap OcTree binary file"
MAX_BT_HEADER = 4096
READ_BYTES_PER_CELL = 96
"""Bytes a cell costs while a ``.bt``'s leaves are expanded into cells: its leaf index, offsets, key, order."""
MORE_MEMORY = "give more --memory"
"""What a reader over its budget advises, unless told otherwise."""


def read_octomap(path: str | os.PathLike[str], max_bytes: int | None = None) -> OccupancyMap:
    """Read an OctoMap binary tree (``.bt``, as ``OcTree::readBinary`` does) into an :class:`OccupancyMap`.

    The format is :func:`write_octomap`'s. As OctoMap's reader does, an occupied leaf gets the upper
    clamping log-odds and a free one the lower (the file keeps no probabilities). A leaf above the
    last level (OctoMap prunes eight equal children into their parent) stands for all the cells
    below it; their count is checked against ``max_bytes`` (``READ_BYTES_PER_CELL`` each) before they
    are made. A header other than OctoMap's, a tree cut short, or a node count other than the
    header's ``size`` raise :class:`~pointfield.errors.FormatError` naming the file. The tree is
    parsed without a walk (:func:`octree_leaves`).
    """
    tree = read_bt_header(Path(path))
    occupancy = OccupancyMap(tree.resolution)
    if tree.size == 0:
        return occupancy
    keys, depths, occupied = octree_leaves(tree, max_bytes)
    occupancy.keys, occupied = _expand_leaves(keys, depths, occupied)
    occupancy.log_odds = np.where(occupied, np.float32(CLAMP[1]), np.float32(CLAMP[0]))
    return occupancy


def read_octomap_grid(path: str | os.PathLike[str], max_bytes: int | None = None,
                      advice: str = MORE_MEMORY) -> VoxelGrid:
    """The occupied cells of an OctoMap ``.bt`` as a :class:`VoxelGrid` (how ``cloud render`` and ``view`` draw it).

    As :func:`read_octomap`, but only the occupied leaves are expanded into cells (a pruned map's
    free leaves can stand for far more cells than its obstacles), and ``max_bytes`` counts only
    those (``advice`` ends the message of a map over it). The grid's origin is the corner of its lowest cell on OctoMap's lattice; it has no
    fields (a ``.bt`` keeps no probabilities) and says ``occupancy: occupied`` in its metadata.
    """
    tree = read_bt_header(Path(path))
    cells = np.zeros((0, 3), np.int64)
    if tree.size:
        keys, depths, occupied = octree_leaves(tree, max_bytes, occupied_only=True, advice=advice)
        cells = key_cells(_expand_leaves(keys[occupied], depths[occupied], occupied[occupied])[0])
    low = cells.min(axis=0) if len(cells) else np.zeros(3, np.int64)
    return VoxelGrid(cells - low, low * tree.resolution, tree.resolution, metadata={"occupancy": "occupied"})


class BtTree(NamedTuple):
    """A ``.bt`` file's bytes with what its header says: the tree's child words start at byte ``at``."""

    path: Path
    data: bytes
    at: int
    size: int
    resolution: float


def read_bt_header(path: Path) -> BtTree:
    """Read a ``.bt`` and check its header: OctoMap's first line, ``id OcTree``, numeric ``size`` and ``res``."""
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    data = path.read_bytes()
    if not data.startswith(OCTOMAP_MAGIC):
        raise FormatError(path, f"not an OctoMap binary tree: expected {OCTOMAP_MAGIC.decode()!r} on the first line")
    header: dict[str, str] = {}
    at = 0
    while True:
        end = data.find(b"\n", at, MAX_BT_HEADER)
        if end < 0:
            raise FormatError(path, f"the header has no 'data' line in its first {MAX_BT_HEADER} bytes")
        line = data[at:end].decode("ascii", "replace").strip()
        at = end + 1
        if line == "data":
            break
        if line and not line.startswith("#"):
            name, _, value = line.partition(" ")
            header[name] = value.strip()
    if header.get("id", "OcTree") != "OcTree":
        raise FormatError(path, f"holds an OctoMap {header['id']!r}; only OcTree (.bt) is read")
    try:
        size, resolution = int(header["size"]), float(header["res"])
    except (KeyError, ValueError):
        raise FormatError(path, "the header needs numeric 'size' and 'res' lines") from None
    if not (resolution > 0 and np.isfinite(resolution)) or size < 0:
        raise FormatError(path, f"the header's 'res' must be positive and 'size' not negative, got {resolution}, {size}")
    return BtTree(path, data, at, size, resolution)


OCTOMAP_CORNER = int(cell_keys(np.full((1, 3), -OCTOMAP_OFFSET))[0])
"""The :func:`cell_keys` key of OctoMap's key (0, 0, 0): OctoMap key ``k`` is our cell ``k - 2^15``, and since our
keys pack x, y, z in 21-bit fields, the key of OctoMap key ``(x, y, z)`` is this plus ``x << 42 | y << 21 | z``."""
CHILD_STEPS = np.array([(i & 1) << (2 * KEY_BITS) | (i >> 1 & 1) << KEY_BITS | (i >> 2 & 1) for i in range(8)], np.int64)
"""Child ``i``'s step in packed keys (OctoMap's ``computeChildIdx``: x is bit 0 of ``i``, y bit 1, z bit 2)."""
CHILD_KINDS = (np.arange(1 << 16)[:, None] >> (2 * np.arange(8)) & 3).astype(np.uint8)
"""``(65536, 8)``: per 16-bit child word, each child's 2 bits (0 unknown, 1 free, 2 occupied, 3 inner)."""
INNER_CHILDREN = (CHILD_KINDS == 3).sum(axis=1)
"""Per child word, how many of its children are inner nodes."""
CHILDREN = (CHILD_KINDS != 0).sum(axis=1)
"""Per child word, how many children it has (leaves and inner nodes)."""


def _cut_short(path: Path, at: int, nodes: int, size: int) -> FormatError:
    return FormatError(path, f"the tree is cut short at byte {at}: {nodes:,} of the header's {size:,} nodes read "
                       "(a truncated file?)")


def _too_deep(path: Path, at: int) -> FormatError:
    return FormatError(path, f"a node at byte {at} has children below OctoMap's {OCTOMAP_DEPTH} levels")


def _too_big(path: Path, cells: int, resolution: float, max_bytes: int, advice: str) -> FormatError:
    return FormatError(path, f"its leaves cover at least {cells:,} cells of {resolution:g}, "
                       f"{human_bytes(cells * READ_BYTES_PER_CELL)} to read, more than the "
                       f"{human_bytes(max_bytes)} allowed ({advice})")


def octree_leaves(tree: BtTree, max_bytes: int | None = None, occupied_only: bool = False,
                  advice: str = MORE_MEMORY) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The leaves of a ``.bt``'s tree, parsed level by level, without a walk.

    Returns ``(keys (L,) int64, depths (L,) int8, occupied (L,) bool)``: the :func:`cell_keys` key
    of each leaf's lowest cell, its depth (1 .. 16; a leaf at depth ``d`` covers ``2^(16 - d)``
    cells per axis) and its state, in no particular order. Raises what
    :func:`octree_leaves_by_walk` (the node-by-node walk of ``OcTree::readBinaryNode``, the
    reference this is tested against) raises, for the same first fault in file order: a tree cut
    short, a node below 16 levels, leaves covering more than ``max_bytes`` (those of occupied
    leaves only with ``occupied_only``; the message ends with ``advice``), a node count other than ``size``.

    The words are the inner nodes in depth-first order, children 0..7. With ``k_i`` the inner
    children of word ``i``, a depth-first reader's stack holds ``S_i = 1 + sum_{j<i} (k_j - 1)``
    nodes before it pops word ``i``; the tree ends at the first word after which it is empty. The
    ``m``-th inner child (``m = 0 .. k_p - 1``) of word ``p`` was pushed at stack slot
    ``S_p - 2 + k_p - m`` and is the first word after ``p`` with ``S = S_p - 1 + k_p - m`` (the
    stack shrinks by at most one a word and the slots below the top are untouched until popped).
    So a node's first inner child is the word after it, and each next one is the first word after the
    one before where the stack is one shorter. One sorted search finds every word's next sibling, and
    the tree is then read a level at a time, in file order within each level.
    """
    path, data, at, size, resolution = tree
    count = (len(data) - at) // 2
    if count == 0:
        raise _cut_short(path, at, 1, size)
    words = np.frombuffer(data, "<u2", count=count, offset=at)
    inner_children = INNER_CHILDREN[words]
    after = np.cumsum(inner_children - 1) + 1  # the stack's size after each word
    empty = np.flatnonzero(after == 0)
    total = int(empty[0]) + 1 if len(empty) else count
    words, inner_children = words[:total], inner_children[:total]
    before = np.concatenate([[1], after[: total - 1]])  # S_i
    stride = total + 1  # S_i <= 7 total + 1: (S, word) packed in one int64 below 2^63 for any file under 2 GB
    ranked = np.sort(before * stride + np.arange(total))  # the words by (S, word)
    # The next sibling of word i: the first word after it where the stack is one shorter, S_i - 1 (or none:
    # total). Asked for every word at once, in the order of ``ranked``, so the questions come sorted too.
    at_rank = np.minimum(np.searchsorted(ranked, ranked - stride + 1), total - 1)
    landed = ranked[at_rank]
    found = landed // stride == ranked // stride - 1
    next_sibling = np.full(total + 1, total)
    next_sibling[ranked[found] % stride] = landed[found] % stride
    cells_of = np.zeros(total if max_bytes is not None else 0, np.int64)  # cells each word's leaves add
    keys, depths, occupied = [], [], []
    nodes, prefixes = np.zeros(1, np.int64), np.full(1, OCTOMAP_CORNER, np.int64)
    too_deep = total
    for depth in range(OCTOMAP_DEPTH):
        kinds = CHILD_KINDS[words[nodes]].ravel()  # (n * 8,): node by node, children 0..7
        bit = OCTOMAP_DEPTH - 1 - depth  # the key bit this level's children differ in
        leaves = np.flatnonzero((kinds - 1) < 2)  # free or occupied (uint8: unknown wraps to 255)
        row = leaves >> 3
        keys.append(prefixes[row] + (CHILD_STEPS[leaves & 7] << bit))
        depths.append(np.full(len(leaves), depth + 1, np.int8))
        occupied.append(kinds[leaves] == 2)
        if max_bytes is not None:
            counted = row[occupied[-1]] if occupied_only else row
            cells_of[nodes] = np.bincount(counted, minlength=len(nodes)) * 8**bit
        inner = np.flatnonzero(kinds == 3)
        if depth + 1 == OCTOMAP_DEPTH:
            too_deep = int(nodes[inner[0] >> 3]) if len(inner) else total  # nodes are in file order
            break
        # A node's first inner child is the word after it, each next one the one before's next sibling.
        counts = inner_children[nodes]
        starts = np.cumsum(counts) - counts  # where each node's inner children begin in ``inner``
        child_words = np.empty(len(inner), np.int64)
        parents = np.flatnonzero(counts)
        current = nodes[parents] + 1
        for rank in range(8):
            more = counts[parents] > rank
            parents, current = parents[more], current[more]
            if not len(parents):
                break
            child_words[starts[parents] + rank] = current
            current = next_sibling[current]
        present = child_words < total  # else it lies past the end of a cut file
        nodes = child_words[present]
        prefixes = prefixes[inner[present] >> 3] + (CHILD_STEPS[inner[present] & 7] << bit)
        if not len(nodes):
            break
    over = total
    if max_bytes is not None:
        exceeded = np.flatnonzero(np.cumsum(cells_of) * READ_BYTES_PER_CELL > max_bytes)
        over = int(exceeded[0]) if len(exceeded) else total
    if too_deep < total and too_deep <= over:
        raise _too_deep(path, at + 2 * too_deep)
    if over < total:
        raise _too_big(path, int(cells_of[: over + 1].sum()), resolution, max_bytes, advice)
    nodes_read = 1 + int(CHILDREN[words].sum())
    if not len(empty):
        raise _cut_short(path, at + 2 * count, nodes_read, size)
    if nodes_read != size:
        raise FormatError(path, f"the tree has {nodes_read:,} nodes but the header says {size:,}")
    return np.concatenate(keys), np.concatenate(depths), np.concatenate(occupied)


def octree_leaves_by_walk(tree: BtTree, max_bytes: int | None = None, occupied_only: bool = False,
                          advice: str = MORE_MEMORY) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`octree_leaves` by a walk node by node, as ``OcTree::readBinaryNode`` reads: the slow, obviously
    right reference the fast parse is tested against (leaves in file order)."""
    path, data, at, size, resolution = tree
    leaves: list[tuple[int, int, int, int, bool]] = []  # (x, y, z) OctoMap key, depth, occupied
    nodes, cells = 1, 0
    stack = [(0, 0, 0, 0)]  # the nodes with children still to read, in file order: key prefix and depth
    while stack:
        x, y, z, depth = stack.pop()
        if at + 2 > len(data):
            raise _cut_short(path, at, nodes, size)
        bits = data[at] | data[at + 1] << 8
        at += 2
        inner = []
        bit = OCTOMAP_DEPTH - 1 - depth  # the key bit this node's children differ in
        for child in range(8):
            kind = (bits >> (2 * child)) & 3
            if kind == 0:
                continue
            nodes += 1
            key = (x | (child & 1) << bit, y | (child >> 1 & 1) << bit, z | (child >> 2 & 1) << bit, depth + 1)
            if kind == 3:
                if depth + 1 == OCTOMAP_DEPTH:
                    raise _too_deep(path, at - 2)
                inner.append(key)
            else:
                leaves.append((*key, kind == 2))
                if kind == 2 or not occupied_only:
                    cells += 8 ** (OCTOMAP_DEPTH - depth - 1)
        stack.extend(reversed(inner))  # depth first, children in order 0..7
        if max_bytes is not None and cells * READ_BYTES_PER_CELL > max_bytes:
            raise _too_big(path, cells, resolution, max_bytes, advice)
    if nodes != size:
        raise FormatError(path, f"the tree has {nodes:,} nodes but the header says {size:,}")
    table = np.asarray(leaves, np.int64).reshape(-1, 5)
    return cell_keys(table[:, :3] - OCTOMAP_OFFSET), table[:, 3], table[:, 4].astype(bool)


def read_octomap_by_walk(path: str | os.PathLike[str], max_bytes: int | None = None) -> OccupancyMap:
    """:func:`read_octomap` as it was before it parsed a level at a time: the tree walked node by node
    (:func:`octree_leaves_by_walk`), each leaf's cells made by index arithmetic and the keys argsorted. The
    reference the fast reader is tested and benchmarked against; the map is the same, byte for byte."""
    tree = read_bt_header(Path(path))
    occupancy = OccupancyMap(tree.resolution)
    if tree.size == 0:
        return occupancy
    keys, depths, occupied = octree_leaves_by_walk(tree, max_bytes)
    span = 1 << (OCTOMAP_DEPTH - depths)  # cells per axis under each leaf
    counts = span**3
    owner = np.repeat(np.arange(len(keys)), counts)
    first = np.cumsum(counts) - counts
    local = np.arange(int(counts.sum()), dtype=np.int64) - first[owner]
    side = span[owner]
    offset = np.stack([local % side, local // side % side, local // (side * side)], axis=1)
    cells = cell_keys(key_cells(keys)[owner] + offset)
    order = np.argsort(cells)
    occupancy.keys = cells[order]
    occupancy.log_odds = np.where(occupied[owner], CLAMP[1], CLAMP[0]).astype(np.float32)[order]
    return occupancy


def _expand_leaves(keys: np.ndarray, depths: np.ndarray, occupied: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(cells, occupied)``: the sorted keys of the cells under leaves whose lowest cells have ``keys`` ``(L,)``,
    at ``depths`` ``(L,)`` (a leaf at the last level is its one cell), and each cell's leaf's ``occupied``.

    The leaves of one depth all cover the same block of ``span^3`` cells: its steps in packed keys are
    made once and added to every leaf's key. A key less :data:`OCTOMAP_CORNER` fits in 58 bits, so it
    carries its state in a lowest bit through one sort (several times faster than an argsort)."""
    packed = [np.zeros(0, np.int64)]
    for depth in np.flatnonzero(np.bincount(depths, minlength=OCTOMAP_DEPTH + 1)):
        leaves = np.flatnonzero(depths == depth)
        axis = np.arange(1 << (OCTOMAP_DEPTH - int(depth)), dtype=np.int64)  # cells per axis under such a leaf
        steps = (axis[:, None, None] << (2 * KEY_BITS) | axis[None, :, None] << KEY_BITS | axis[None, None, :]).ravel()
        first = (keys[leaves] - OCTOMAP_CORNER) << 1 | occupied[leaves]
        packed.append((first[:, None] + (steps << 1)).ravel())
    cells = np.sort(np.concatenate(packed))
    return (cells >> 1) + OCTOMAP_CORNER, (cells & 1).astype(bool)
