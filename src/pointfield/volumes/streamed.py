"""Voxelizing a cloud bigger than memory: :func:`~pointfield.volumes.voxelize_cloud`'s grid, a chunk at a time.

Two passes over the file (:mod:`pointfield.streaming`'s chunk readers): the first finds the
finite points' bounds, which fix the grid exactly as the in-memory version does (origin at the
minimum corner, :class:`pointfield.streaming.voxels.VoxelGrid`'s keys); the second reduces each
chunk to per-voxel partial sums -- counts, sums of the floating-point fields and colours, and
counts of each (voxel, value) of the integer fields -- and merges them into running sums kept in
key order. What is held is one row per occupied voxel (and per voxel and label), never the
points, so the memory goes with the grid, not the file; past the state's share of ``memory`` the
job stops and names the voxel that fits.

The result has the in-memory grid's voxels, counts and majority labels exactly; means are sums
added in another order, so they agree to rounding (a colour's rounded mean can differ by one where
it lies on a half).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.errors import PointfieldError
from pointfield.streaming.chunks import open_source
from pointfield.streaming.jobs import finite_bounds, indexed_chunks
from pointfield.streaming.memory import DEFAULT_MEMORY, plan
from pointfield.streaming.voxels import VoxelGrid as GridLayout
from pointfield.volumes.voxels import VoxelGrid, human_bytes

BYTES_PER_POINT = 64
"""What a point of a chunk costs while it is reduced: its record, float64 coordinates, cells, keys, order."""


@dataclass
class _Sums:
    """Running per-voxel sums in key order: ``keys``, ``counts``, ``sums[name]``, ``votes[name]``."""

    keys: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    counts: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    sums: dict[str, np.ndarray] = field(default_factory=dict)
    votes: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=dict)

    @property
    def nbytes(self) -> int:
        held = self.keys.nbytes + self.counts.nbytes + sum(v.nbytes for v in self.sums.values())
        return held + sum(k.nbytes + v.nbytes + c.nbytes for k, v, c in self.votes.values())

    def add(self, keys: np.ndarray, counts: np.ndarray, sums: dict[str, np.ndarray],
            votes: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]) -> None:
        """Merge one chunk's reduced rows (each sorted by key, or by key then value) into the running ones."""
        every = np.concatenate([self.keys, keys])
        merged, inverse = np.unique(every, return_inverse=True)
        total = np.zeros(len(merged), np.int64)
        np.add.at(total, inverse, np.concatenate([self.counts, counts]))
        for name, values in sums.items():
            held = self.sums.get(name, np.zeros((0, *values.shape[1:])))
            out = np.zeros((len(merged), *values.shape[1:]))
            np.add.at(out, inverse, np.concatenate([held, values]))
            self.sums[name] = out
        self.keys, self.counts = merged, total
        for name, (vote_keys, vote_values, vote_counts) in votes.items():
            held_keys, held_values, held_counts = self.votes.get(
                name, (np.zeros(0, np.int64), np.zeros(0, vote_values.dtype), np.zeros(0, np.int64)))
            pairs = np.stack([np.concatenate([held_keys, vote_keys]),
                              np.concatenate([held_values, vote_values]).astype(np.int64)], axis=1)
            unique, where = np.unique(pairs, axis=0, return_inverse=True)
            count = np.zeros(len(unique), np.int64)
            np.add.at(count, where.reshape(-1), np.concatenate([held_counts, vote_counts]))
            self.votes[name] = (unique[:, 0], unique[:, 1].astype(vote_values.dtype), count)


def _reduce(layout: GridLayout, cloud: PointCloud) -> tuple[np.ndarray, np.ndarray, dict, dict]:
    points = np.asarray(cloud.points, np.float64)
    finite = np.isfinite(points).all(axis=1)
    keys = layout.keys(layout.cells(points[finite]))
    merged, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
    sums: dict[str, np.ndarray] = {}
    votes: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    for name, values in cloud.fields.items():
        values = np.asarray(values)[finite]
        if name == "counts":
            continue
        if np.issubdtype(values.dtype, np.floating) or name == "colors":
            out = np.zeros((len(merged), *values.shape[1:]))
            np.add.at(out, inverse, values.astype(np.float64))
            sums[name] = out
        elif values.ndim == 1 and (np.issubdtype(values.dtype, np.integer) or values.dtype == bool):
            pairs, count = np.unique(np.stack([keys, values.astype(np.int64)], axis=1), axis=0, return_counts=True)
            votes[name] = (pairs[:, 0], pairs[:, 1].astype(values.dtype), count)
    return merged, counts, sums, votes


def voxelize_file(path: str | os.PathLike[str], size: float, memory: str | int = DEFAULT_MEMORY,
                  columns: int | None = None) -> VoxelGrid:
    """:func:`~pointfield.volumes.voxelize_cloud` of the cloud in ``path``, read in chunks within ``memory`` (module docstring)."""
    source = open_source(path, columns=columns)
    budget = plan(memory, BYTES_PER_POINT)
    low, high, count = finite_bounds(source, budget.chunk_points)
    if count == 0:
        raise PointfieldError(f"{path}: no finite points to voxelize")
    layout = GridLayout.covering(low, high, size)
    template: PointCloud | None = None
    running = _Sums()
    for chunk, _ in indexed_chunks(source, budget.chunk_points):
        template = template or chunk
        running.add(*_reduce(layout, chunk))
        if running.nbytes > budget.state_bytes:
            # Occupied voxels of a surface go with 1 / size^2: the voxel whose count would fit, from the share read.
            fits = size * float(np.sqrt(running.nbytes / budget.state_bytes))
            raise PointfieldError(
                f"{path}: the occupied voxels of {size:g} need more than the {human_bytes(budget.state_bytes)} of "
                f"--memory left for them ({human_bytes(running.nbytes)} before the end of the file): a voxel of "
                f"{fits:.3g} or larger may fit (or give more --memory)")
    counts = running.counts
    fields: dict[str, np.ndarray] = {"counts": counts}
    for name, total in running.sums.items():
        dtype = np.asarray(template.fields[name]).dtype
        mean = total / counts.reshape(-1, *[1] * (total.ndim - 1))
        if name == "normals":
            mean /= np.maximum(np.linalg.norm(mean, axis=1, keepdims=True), 1e-12)
        fields[name] = (mean if np.issubdtype(dtype, np.floating) else np.rint(mean)).astype(dtype)
    for name, (keys, values, votes) in running.votes.items():
        # Most votes per voxel, ties to the smallest value: the rows are in (key, value) order.
        best = np.lexsort((values, -votes, keys))
        leader = np.r_[True, keys[best][1:] != keys[best][:-1]]
        fields[name] = values[best][leader]
    keys = running.keys
    ny, nz = layout.shape[1], layout.shape[2]
    coords = np.stack([keys // (ny * nz), (keys // nz) % ny, keys % nz], axis=1)
    return VoxelGrid(coords, layout.origin, size, fields, layout.shape,
                     {"source": str(path), "points": int(counts.sum())})
