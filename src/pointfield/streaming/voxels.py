"""Voxel downsampling in one pass over chunks, with bounded memory, equal bit for bit to memory.

The definition is :func:`pointfield.clouds.ops.voxel_downsample`'s:

- the grid starts at the minimum corner of the finite points, ``origin = min_i p_i`` per axis,
  and point p falls in voxel ``floor((p - origin) / size)``; non-finite points are dropped;
- **centroid** (the default): a voxel's point is the mean of its points,
  ``sum_i p_i / n`` in float64, cast to the points' dtype; floating-point fields are averaged
  the same way (``normals`` renormalised to unit length), every other field takes the value of
  the voxel's first point (first in the file);
- **nearest**: a voxel's point is its point nearest the voxel centre
  ``origin + (cell + 0.5) * size``, with all of that point's fields; of equally near points,
  the first in the file (:func:`voxel_nearest` is the in-memory reference);
- voxels come out in lexicographic order of their ``(i, j, k)`` grid coordinates.

Why chunks give the same bits. A floating-point sum depends on the order of its terms. The
in-memory version adds each voxel's points one after another in file order (``np.add.at``);
:class:`VoxelAccumulator` keeps each voxel's running sums and continues them, chunk after
chunk, with the same ``np.add.at``: every voxel sees the same additions in the same order
however the file is chunked, and however voxels are divided between tiles or Dask workers, as
long as each voxel's points reach one accumulator in file order. Counts, the first point and
the nearest point are order-free or tie-broken by the point's index in the file.

Memory. The accumulator holds one entry per occupied voxel (about 60 bytes plus the fields).
:func:`reduce_voxels` watches its size: past its budget it cuts the voxel key range into
partitions at quantiles of the keys seen so far, parks the state of the largest partitions on
disk and sends their later points to disk too; each parked partition is reduced on its own at
the end (recursively, if it is still too big). Keys are ``(i * ny + j) * nz + k``: a key range
is a run of whole voxels in output order, so partitions never split a voxel and their results
simply follow each other.
"""

from __future__ import annotations

import itertools
import tempfile
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pointfield.clouds.arrays import finite_rows
from pointfield.clouds.cloud import PointCloud
from pointfield.errors import PointfieldError
from pointfield.streaming.spill import Spill

MODES = ("centroid", "nearest")
KEY_END = 2**62
# Voxels per piece when state is written to disk: a few tens of MB of records at a time.
RECORDS_PIECE = 1 << 18
# How deep reduce_voxels may split a partition that is still too big when its turn comes.
MAX_DEPTH = 6


@dataclass(frozen=True)
class VoxelGrid:
    """Cubes of side ``size`` from ``origin`` (float64 (3,)); ``shape`` cells per axis."""

    origin: np.ndarray
    size: float
    shape: tuple[int, int, int]

    @classmethod
    def covering(cls, low: np.ndarray, high: np.ndarray, size: float) -> VoxelGrid:
        """The grid from ``low`` that holds every point up to ``high``."""
        if not size > 0:
            raise ValueError(f"voxel size must be positive, got {size}")
        low = np.asarray(low, np.float64)
        high = np.asarray(high, np.float64)
        last = np.floor((high[None] - low) / size).astype(np.int64)[0]
        shape = tuple(int(v) + 1 for v in np.maximum(last, 0))
        if float(shape[0]) * shape[1] * shape[2] >= KEY_END:
            raise PointfieldError(
                f"a voxel of {size} over a box of {high - low} makes {shape} cells, more than "
                "2**62: use a larger voxel, or tile the cloud first (cloud tile)"
            )
        return cls(low, float(size), shape)  # type: ignore[arg-type]

    def cells(self, points: np.ndarray) -> np.ndarray:
        """``(N, 3)`` int64 voxel coordinates of float64 points (the in-memory formula)."""
        return np.floor((points - self.origin) / self.size).astype(np.int64)

    def keys(self, cells: np.ndarray) -> np.ndarray:
        """``(N,)`` int64 keys, increasing in lexicographic order of the cells."""
        _, ny, nz = self.shape
        return (cells[:, 0] * ny + cells[:, 1]) * nz + cells[:, 2]

    def centres(self, cells: np.ndarray) -> np.ndarray:
        return self.origin + (cells + 0.5) * self.size

    def x_range(self, first: int, stop: int) -> tuple[int, int]:
        """The key range of the slab of cells with ``first <= i < stop``."""
        _, ny, nz = self.shape
        return first * ny * nz, stop * ny * nz


def stable_key_order(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(order, keys[order])``: the stable ascending order of ``(N,)`` int64 keys.

    numpy's stable argsort of int64 is a merge sort. Each key's position packed into its low
    bits, ``(key - min) << b | position``, makes the keys distinct, so numpy's vectorised
    (unstable) sort of the packed values gives the same order, about twice as fast; keys
    spanning too many bits for that fall back to the merge sort.
    """
    n = len(keys)
    if n == 0:
        return np.zeros(0, np.int64), keys.astype(np.int64)
    low = int(keys.min())
    shift = max(n - 1, 1).bit_length()
    if (int(keys.max()) - low).bit_length() + shift > 62:
        order = np.argsort(keys, kind="stable")
        return order, keys[order]
    packed = (keys - low) << shift
    packed |= np.arange(n, dtype=np.int64)
    packed.sort()
    order = packed & ((1 << shift) - 1)
    packed >>= shift
    packed += low
    return order, packed


def merge_places(keys: np.ndarray, new_keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where two sorted key arrays with no key in common go when merged into one sorted array:
    ``(at, old)``, the merged positions of ``new_keys`` and the mask of the places of ``keys``.

    :func:`merged` then builds each merged array (the keys, the slots) one at a time, so that
    the old copy of one can be freed before the next is built. ``np.insert`` does the same, a
    third slower (it sorts the positions and builds its mask once per array).
    """
    at = np.searchsorted(keys, new_keys)
    at += np.arange(len(new_keys))
    old = np.ones(len(keys) + len(new_keys), bool)
    old[at] = False
    return at, old


def merged(values: np.ndarray, new_values: np.ndarray, at: np.ndarray, old: np.ndarray) -> np.ndarray:
    """``values`` and ``new_values`` in the places :func:`merge_places` found."""
    out = np.empty(len(old), values.dtype)
    out[at] = new_values
    out[old] = values
    return out


def squared_distance(points: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """``|p - c|²`` per row, summed x, y, z in that order (the same bits in every caller)."""
    d = points - centres
    return d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2]


def voxel_nearest(cloud: PointCloud, size: float) -> PointCloud:
    """In memory, the voxel point nearest its voxel's centre, with its fields (module docstring).

    The reference the streaming ``nearest`` mode is tested against.
    """
    finite = cloud.select(np.isfinite(cloud.points).all(axis=1))
    if len(finite) == 0:
        return finite
    points = finite.points.astype(np.float64)
    grid = VoxelGrid.covering(points.min(axis=0), points.max(axis=0), size)
    cells = grid.cells(points)
    keys = grid.keys(cells)
    distance = squared_distance(points, grid.centres(cells))
    order = np.lexsort((np.arange(len(keys)), distance, keys))
    first = np.ones(len(order), bool)
    first[1:] = keys[order][1:] != keys[order][:-1]
    return finite.select(order[first])


class VoxelAccumulator:
    """Running per-voxel state, continued chunk after chunk (module docstring).

    ``template`` gives the fields and dtypes; ``mode`` is ``"centroid"`` or ``"nearest"``;
    ``state_bytes``, the state's share of a memory budget, stops its arrays growing ahead of need
    past that share. State lives in arrays indexed by a *slot* per voxel, in the order voxels
    were first seen; ``keys`` / ``slots`` is a sorted index from voxel key to slot.
    """

    def __init__(self, template: PointCloud, mode: str = "centroid", state_bytes: int | None = None):
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        self.mode = mode
        self.points_dtype = template.points.dtype
        self.specs = {name: (v.dtype, v.shape[1:]) for name, v in template.fields.items()}
        floating = {n for n, (dtype, _) in self.specs.items() if np.issubdtype(dtype, np.floating)}
        self.mean_fields = [n for n in self.specs if n in floating] if mode == "centroid" else []
        self.columns: dict[str, tuple[np.dtype, tuple[int, ...]]] = {"key": (np.dtype(np.int64), ()), "first": (np.dtype(np.int64), ())}
        if mode == "centroid":
            self.columns["count"] = (np.dtype(np.int64), ())
            self.columns["sum"] = (np.dtype(np.float64), (3,))
            for name in self.mean_fields:
                components = int(np.prod(self.specs[name][1], dtype=np.int64))
                self.columns[f"sum:{name}"] = (np.dtype(np.float64), (components,))
        else:
            self.columns["distance"] = (np.dtype(np.float64), ())
            self.columns["points"] = (self.points_dtype, (3,))
        for name, (dtype, shape) in self.specs.items():
            if name not in self.mean_fields:
                self.columns[f"value:{name}"] = (dtype, shape)
        self.record = np.dtype([(name, dtype, shape) for name, (dtype, shape) in self.columns.items()])
        # A voxel's bytes: its record, and its key and slot in the index.
        voxel_bytes = self.record.itemsize + 2 * np.dtype(np.int64).itemsize
        self.growth_limit = None if state_bytes is None else max(1024, state_bytes // voxel_bytes)
        """Voxels the state may grow to ahead of need (None: no limit), so that ``nbytes`` passes
        ``state_bytes`` by the voxels of one chunk rather than by half the state (see ``_reserve``)."""
        self.size = 0
        self.state = self._empty(0)
        # The index from key to slot: sorted ``keys`` / ``slots``, plus the keys first seen since
        # they were last merged into it, sorted too; merging when the recent ones reach a quarter
        # of the rest keeps inserting new voxels linear overall rather than per chunk.
        self.keys = np.zeros(0, np.int64)
        self.slots = np.zeros(0, np.int64)
        self.recent_keys = np.zeros(0, np.int64)
        self.recent_slots = np.zeros(0, np.int64)

    # -- state -----------------------------------------------------------------------------

    def _empty(self, capacity: int) -> dict[str, np.ndarray]:
        # Sums are stored per component so that np.add.at takes its fast 1-D path.
        state = {}
        for name, (dtype, shape) in self.columns.items():
            if name == "sum" or name.startswith("sum:"):
                for c in range(shape[0]):
                    state[f"{name}#{c}"] = np.zeros(capacity, dtype)
            else:
                state[name] = np.zeros((capacity, *shape), dtype)
        return state

    def _reserve(self, size: int) -> None:
        capacity = len(self.state["key"])
        if size <= capacity:
            return
        ahead = max(capacity * 3 // 2, 1024)
        if self.growth_limit is not None:
            # Growing 1.5x past the state's budget would make the job's peak depend on where the
            # budget falls between two growth steps (0.88 GB of state against a 0.65 GB budget on
            # one input, 0.71 GB on another), not on the budget: growth stops at the budget, and
            # beyond it only what the chunk needs is added, before the caller parks state.
            ahead = min(ahead, self.growth_limit)
        capacity = max(size, ahead)
        # Column by column, so that growing costs one column's copy on top of the state.
        for name in list(self.state):
            values = self.state.pop(name)
            grown = np.zeros((capacity, *values.shape[1:]), values.dtype)
            grown[: self.size] = values[: self.size]
            del values
            self.state[name] = grown

    @property
    def nbytes(self) -> int:
        index = self.keys.nbytes + self.slots.nbytes + self.recent_keys.nbytes + self.recent_slots.nbytes
        return sum(v.nbytes for v in self.state.values()) + index

    def index(self) -> tuple[np.ndarray, np.ndarray]:
        """The sorted voxel keys held and their slots."""
        if len(self.recent_keys):
            at, old = merge_places(self.keys, self.recent_keys)
            # One array at a time: the old keys are freed before the merged slots are built.
            self.keys = merged(self.keys, self.recent_keys, at, old)
            self.slots = merged(self.slots, self.recent_slots, at, old)
            self.recent_keys = self.recent_keys[:0]
            self.recent_slots = self.recent_slots[:0]
        return self.keys, self.slots

    def _lookup(self, keys: np.ndarray, slots: np.ndarray, unique: np.ndarray, slot: np.ndarray, missing: np.ndarray) -> None:
        """Fill ``slot`` for the ``missing`` unique keys found in one sorted index."""
        wanted = unique[missing]
        at = np.searchsorted(keys, wanted)
        found = at < len(keys)
        found[found] = keys[at[found]] == wanted[found]
        where = np.flatnonzero(missing)[found]
        slot[where] = slots[at[found]]

    def __len__(self) -> int:
        return self.size

    # -- adding points ------------------------------------------------------------------------

    def add(self, grid: VoxelGrid, cloud: PointCloud, index: np.ndarray, cells: np.ndarray | None = None) -> None:
        """Add a chunk of finite points; ``index`` ``(N,)`` is each point's position in the file.

        Chunks must come in file order: each voxel's sums continue in the order of its points.
        ``cells``, when the caller has them, are ``grid.cells`` of the points.
        """
        n = len(cloud)
        if n == 0:
            return
        points = np.asarray(cloud.points, np.float64)
        cells = grid.cells(points) if cells is None else cells
        order, sorted_keys = stable_key_order(grid.keys(cells))
        starts = np.ones(n, bool)
        starts[1:] = sorted_keys[1:] != sorted_keys[:-1]
        unique = sorted_keys[starts]
        group = np.empty(n, np.int64)  # each point's position in ``unique``
        group[order] = np.cumsum(starts) - 1

        slot = np.full(len(unique), -1, np.int64)
        self._lookup(self.keys, self.slots, unique, slot, slot < 0)
        if len(self.recent_keys):
            self._lookup(self.recent_keys, self.recent_slots, unique, slot, slot < 0)
        fresh = slot < 0
        new_count = int(fresh.sum())
        slot[fresh] = np.arange(self.size, self.size + new_count)
        self._reserve(self.size + new_count)
        at, old = merge_places(self.recent_keys, unique[fresh])
        self.recent_keys = merged(self.recent_keys, unique[fresh], at, old)
        self.recent_slots = merged(self.recent_slots, slot[fresh], at, old)
        if len(self.recent_keys) > max(1 << 16, len(self.keys) // 4):
            self.index()
        self.size += new_count
        state = self.state
        # New voxels take the next slots, in key order: their state is written as slices.
        new_slots = slice(self.size - new_count, self.size)
        state["key"][new_slots] = unique[fresh]

        if self.mode == "centroid":
            # First point of each voxel in this chunk: the stable sort keeps file order.
            new_first = order[starts][fresh]
            state["first"][new_slots] = index[new_first]
            for name in self.specs:
                if name not in self.mean_fields:
                    state[f"value:{name}"][new_slots] = cloud.fields[name][new_first]
            state["count"][slot] += np.diff(np.append(np.flatnonzero(starts), n))
            slots = slot[group]
            for axis in range(3):
                np.add.at(state[f"sum#{axis}"], slots, points[:, axis])
            for name in self.mean_fields:
                values = cloud.fields[name].reshape(n, -1)
                for c in range(values.shape[1]):
                    np.add.at(state[f"sum:{name}#{c}"], slots, values[:, c].astype(np.float64))
            return

        distance = squared_distance(points, grid.centres(cells))
        best_order = np.lexsort((index, distance, group))
        leader = np.ones(n, bool)
        leader[1:] = group[best_order][1:] != group[best_order][:-1]
        best = best_order[leader]  # per unique key, in key order, its nearest point in the chunk
        current = state["distance"][slot]
        better = fresh | (distance[best] < current)
        target, chosen = slot[better], best[better]
        state["distance"][target] = distance[chosen]
        state["first"][target] = index[chosen]
        state["points"][target] = cloud.points[chosen]
        for name in self.specs:
            state[f"value:{name}"][target] = cloud.fields[name][chosen]

    # -- results --------------------------------------------------------------------------------

    def finalize(self, metadata: dict[str, Any], low: int = 0, high: int = KEY_END) -> PointCloud:
        """The voxels with keys in ``[low, high)`` as a cloud, in key order (module docstring)."""
        keys, all_slots = self.index()
        first, stop = np.searchsorted(keys, [low, high])
        slots = all_slots[first:stop]
        state = self.state
        fields: dict[str, np.ndarray] = {}
        if self.mode == "centroid":
            counts = state["count"][slots]

            def mean(name: str, components: int) -> np.ndarray:
                sums = np.stack([state[f"{name}#{c}"][slots] for c in range(components)], axis=1)
                return sums / counts[:, None]

            points = mean("sum", 3).astype(self.points_dtype)
            for name, (dtype, shape) in self.specs.items():
                if name in self.mean_fields:
                    averaged = mean(f"sum:{name}", int(np.prod(shape, dtype=np.int64))).reshape(
                        (len(slots), *shape)
                    )
                    if name == "normals":
                        length = np.linalg.norm(averaged, axis=1, keepdims=True)
                        averaged = averaged / np.maximum(length, 1e-12)
                    fields[name] = averaged.astype(dtype)
                else:
                    fields[name] = state[f"value:{name}"][slots]
        else:
            points = state["points"][slots]
            fields = {name: state[f"value:{name}"][slots] for name in self.specs}
        return PointCloud(points, fields, None, dict(metadata))

    def finalize_chunks(
        self, metadata: dict[str, Any], low: int, high: int, points: int
    ) -> Iterator[PointCloud]:
        """:meth:`finalize` of ``[low, high)`` in pieces of at most ``points`` voxels."""
        keys, _ = self.index()
        first, stop = (int(v) for v in np.searchsorted(keys, [low, high]))
        for at in range(first, stop, points):
            end = min(at + points, stop)
            upper = int(keys[end]) if end < len(keys) else high
            yield self.finalize(metadata, int(keys[at]), min(upper, high))

    # -- moving state to and from disk ------------------------------------------------------

    def _records_of(self, slots: np.ndarray) -> np.ndarray:
        """The state of the voxels in ``slots`` as records (``self.record``), in that order."""
        records = np.empty(len(slots), self.record)
        for name, (_, shape) in self.columns.items():
            if name == "sum" or name.startswith("sum:"):
                for c in range(shape[0]):
                    records[name][:, c] = self.state[f"{name}#{c}"][slots]
            else:
                records[name] = self.state[name][slots]
        return records

    def write_records(self, low: int, high: int, into: Spill) -> tuple[int, int]:
        """Append the state of the voxels with keys in ``[low, high)`` to ``into`` as records, in
        key order, a piece at a time; returns where they lie in the index, ``keys[first:stop]``."""
        self.index()
        first, stop = (int(v) for v in np.searchsorted(self.keys, [low, high]))
        for at in range(first, stop, RECORDS_PIECE):
            into.append_records(self._records_of(self.slots[at : min(at + RECORDS_PIECE, stop)]))
        return first, stop

    def take(self, low: int, high: int, into: Spill) -> None:
        """Move the voxels with keys in ``[low, high)`` to ``into``, as records in key order.

        Memory: the records go out a piece at a time, and the state shrinks a column at a time,
        so that parking costs little more than the state already held (it is what happens when
        the state is at its largest).
        """
        first, stop = self.write_records(low, high, into)
        gone = np.sort(self.slots[first:stop])
        keep = np.ones(self.size, bool)
        keep[gone] = False
        for name in list(self.state):  # column by column, as _reserve
            values = self.state.pop(name)
            self.state[name] = values[: self.size][keep]
            del values
        del keep
        self.size -= len(gone)
        self.keys = np.concatenate([self.keys[:first], self.keys[stop:]])
        slots = np.concatenate([self.slots[:first], self.slots[stop:]])
        self.slots = None  # free the old index before its renumbered copy is built
        slots -= np.searchsorted(gone, slots)  # each kept slot moves down past the slots taken
        self.slots = slots

    def load(self, records: np.ndarray) -> None:
        """Add voxels from :meth:`take`'s records (their keys must be new here)."""
        n = len(records)
        slots = np.arange(self.size, self.size + n)
        self._reserve(self.size + n)
        for name, (_, shape) in self.columns.items():
            if name == "sum" or name.startswith("sum:"):
                for c in range(shape[0]):
                    self.state[f"{name}#{c}"][slots] = records[name][:, c]
            else:
                self.state[name][slots] = records[name]
        self.size += n
        self.index()
        at, old = merge_places(self.keys, records["key"])  # take() wrote them in key order
        self.keys = merged(self.keys, records["key"], at, old)
        self.slots = merged(self.slots, slots, at, old)


# ---------------------------------------------------------------------------------------------
# The bounded-memory driver


def drop_nonfinite(cloud: PointCloud, index: np.ndarray) -> tuple[PointCloud, np.ndarray]:
    """``cloud`` and ``index`` without the points that have a NaN or infinite coordinate."""
    finite = finite_rows(cloud.points)
    if finite is None:
        return cloud, index
    return cloud.select(finite), index[finite]


@dataclass
class _Partition:
    low: int
    high: int
    state: Spill | None = None
    points: Spill | None = None

    @property
    def parked(self) -> bool:
        return self.state is not None


def reduce_voxels(
    chunks: Iterable[tuple[PointCloud, np.ndarray]],
    grid: VoxelGrid,
    template: PointCloud,
    mode: str,
    state_bytes: int,
    scratch: Path,
    out_points: int = 1 << 20,
    key_range: tuple[int, int] = (0, KEY_END),
    initial: Spill | None = None,
    depth: int = 0,
    expected_points: int | None = None,
) -> Iterator[PointCloud]:
    """The voxel clouds of a stream of ``(chunk, index)`` in file order, in key order.

    ``index`` is each point's position in the file; non-finite points are dropped here. The
    accumulator is held to ``state_bytes`` by parking partitions on disk under ``scratch``
    (module docstring); the result comes in clouds of at most ``out_points`` voxels.
    ``expected_points``, the stream's length when known, sizes the partitions: from the state
    of the share seen so far, how many the whole will need. ``key_range`` and ``initial``
    (parked state) are for the recursive reduction of a partition.
    """
    metadata = dict(template.metadata)
    accumulator = VoxelAccumulator(template, mode, state_bytes)
    if initial is not None:
        for records in initial.records(RECORDS_PIECE):
            accumulator.load(records)
    partitions: list[_Partition] | None = None
    cuts = np.zeros(0, np.int64)
    seen = 0
    for cloud, index in chunks:
        seen += len(cloud)
        cloud, index = drop_nonfinite(cloud, index)
        if len(cloud) == 0:
            continue
        cells = grid.cells(np.asarray(cloud.points, np.float64))
        if partitions is not None:
            part = np.searchsorted(cuts, grid.keys(cells), side="right") - 1
            parked = np.array([p.parked for p in partitions])[part]
            if parked.any():
                for number in np.unique(part[parked]):
                    mine = part == number
                    partitions[number].points.append(cloud.select(mine), index[mine])
                kept = ~parked
                cloud, index, cells = cloud.select(kept), index[kept], cells[kept]
        accumulator.add(grid, cloud, index, cells)
        if accumulator.nbytes > state_bytes and depth < MAX_DEPTH:
            if partitions is None:
                share = seen / expected_points if expected_points else 1.0
                partitions = _partitions(accumulator, grid, key_range, state_bytes, share)
                cuts = np.array([p.low for p in partitions], np.int64)
            _park(accumulator, partitions, template, scratch, state_bytes)

    if partitions is None:
        yield from accumulator.finalize_chunks(metadata, *key_range, out_points)
        return
    # Park what is still held too (its state only; it has no points waiting), so that one
    # partition at a time is in memory while the parked ones are reduced in key order.
    for number, partition in enumerate(partitions):
        if not partition.parked:
            partition.state = Spill(scratch / f"state-{number}.spill", template, dtype=accumulator.record)
            accumulator.write_records(partition.low, partition.high, partition.state)
            partition.points = Spill(scratch / f"points-{number}.spill", template, with_index=True)
    del accumulator
    for number, partition in enumerate(partitions):
        folder = Path(tempfile.mkdtemp(prefix=f"part{number}-", dir=scratch))
        try:
            yield from reduce_voxels(
                ((cloud, index) for cloud, index in partition.points.chunks(out_points)),
                grid,
                template,
                mode,
                state_bytes,
                folder,
                out_points,
                (partition.low, partition.high),
                partition.state,
                depth + 1,
                len(partition.points),
            )
        finally:
            partition.state.remove()
            partition.points.remove()
            folder.rmdir()


def _partitions(
    accumulator: VoxelAccumulator, grid: VoxelGrid, key_range: tuple[int, int], state_bytes: int, share: float
) -> list[_Partition]:
    """Cut ``key_range`` into partitions of about a quarter budget each, by the end of the stream.

    The state held came from ``share`` of the stream, so the whole will need about
    ``nbytes / share``. Partitions are slabs of equal width along the grid's first axis where the
    range spans enough of them (the points yet to come may lie anywhere in it); within a single
    slab, at quantiles of the keys held.
    """
    expected = accumulator.nbytes / max(share, 1e-3)
    parts = int(min(256, max(2, np.ceil(4 * expected / max(state_bytes, 1)))))
    slab = grid.shape[1] * grid.shape[2]
    first, stop = key_range[0] // slab, min(grid.shape[0], -(-key_range[1] // slab))
    if stop - first >= parts:
        inner = [first + (stop - first) * k // parts for k in range(1, parts)]
        cuts = np.array([key_range[0], *(i * slab for i in inner)], np.int64)
    else:
        keys, _ = accumulator.index()
        inner = keys[(np.arange(1, parts) * len(keys)) // parts] if len(keys) else np.zeros(0, np.int64)
        cuts = np.concatenate([[key_range[0]], inner])
    cuts = np.unique(cuts)
    cuts = cuts[(cuts >= key_range[0]) & (cuts < key_range[1])]
    edges = [*cuts.tolist(), key_range[1]]
    return [_Partition(int(a), int(b)) for a, b in itertools.pairwise(edges)]


def _park(
    accumulator: VoxelAccumulator,
    partitions: list[_Partition],
    template: PointCloud,
    scratch: Path,
    state_bytes: int,
) -> None:
    """Move the largest partitions held in memory to disk until the state is half its budget."""
    while accumulator.nbytes > state_bytes // 2:
        held = [number for number, p in enumerate(partitions) if not p.parked]
        if not held:
            return
        keys, _ = accumulator.index()
        sizes = [np.diff(np.searchsorted(keys, [partitions[n].low, partitions[n].high]))[0] for n in held]
        _park_one(accumulator, partitions, held[int(np.argmax(sizes))], template, scratch)


def _park_one(accumulator: VoxelAccumulator, partitions: list[_Partition], number: int,
              template: PointCloud, scratch: Path) -> None:
    """Move partition ``number``'s state to disk; its points will follow it there."""
    partition = partitions[number]
    partition.state = Spill(scratch / f"state-{number}.spill", template, dtype=accumulator.record)
    accumulator.take(partition.low, partition.high, partition.state)
    partition.points = Spill(scratch / f"points-{number}.spill", template, with_index=True)
