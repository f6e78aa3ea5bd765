"""Predicting scans of any size within a memory budget: ``segment predict RUN scan --memory 2G``.

A scene run predicts a scan by preparing it (grid subsampling, features), covering it with
windows that vote, and handing each point its grid cell's vote (:mod:`~.scene_crops`). Read
whole, that holds the file and its arrays in memory. Streamed, it holds one tile:

1. **survey** (one pass of :func:`~pointfield.streaming.read_chunks` windows): the finite
   bounds, the range of ``intensity``, and the points per column of the cover grid (x y cells
   ``COVER_CELL_RADII`` radii wide), from which the tile side is chosen: the largest multiple of
   a cell whose densest tile, halo included, fits what the budget leaves beside the interpreter,
   the model and one batch of crops;
2. **levels and tiles** (a second pass): histograms giving the floor (the 1st percentile of z,
   what the ``height`` feature is measured from) and the intensity scale (its 99th percentile),
   and every point, with its position in the file, parked in the spill of its tile and of each
   neighbour whose halo holds it (:func:`pointfield.streaming.tiling.tile_rows`, as
   ``cloud tile --buffer`` cuts tiles);
3. **tiles**: each tile is read back whole, prepared with the scan's numbers
   (:class:`ScanFrame`: offset, grid corner, floor, intensity scale), covered and voted on; the
   labels and confidences of its own points go to a results file at their file positions;
4. **write** (a third pass): the scan again, window by window, each point with its label and
   confidence, through :func:`pointfield.streaming.open_writer` (atomic, any format).

Why tiles give the whole scan's labels. The halo is ``radius * (COVER_CELL_RADII + 1) + 2 *
grid`` wide: every cover cell within a radius of the tile is then whole in it (each cell's
windows depend on its own points alone), every window reaching the tile holds all its points,
and every grid cell of those points is whole (the grid is the scan's, from its corner). So each
own point is voted on by the windows, chunks and crops the whole scan gives it. What differs is
only which crops share a batch, which moves the probabilities by float rounding: a label can
change only where two classes tie to that rounding. The in-memory path uses the same
:class:`ScanFrame`, computed from the cloud in one piece, so the two agree.

The floor and the intensity scale come from fixed histograms (``HISTOGRAM_BINS`` bins over the
value range; integer intensities one bin per value, so exact), the same numbers for a scan read
whole or in any windows. Training measures the floor on the subsampled scan with
``np.percentile``; here it is the raw points' percentile to within ``range / HISTOGRAM_BINS``
(a few millimetres): both are the floor's height, where the floor holds a percent of the points.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.datasets.labelled import as_scan, labels_of_codes, with_class_lookup
from pointfield.clouds.scene_crops import COVER_CELL_RADII, prepare_scene, vote
from pointfield.errors import FormatError, OptionError
from pointfield.streaming.chunks import StreamingFallback, open_source
from pointfield.streaming.jobs import bytes_per_point, indexed_chunks, progress_bar, scratch_folder, template_of
from pointfield.streaming.memory import parse_memory, resident_bytes, returning_freed_arrays
from pointfield.streaming.spill import Spill, from_records
from pointfield.streaming.tiling import TileSpills
from pointfield.streaming.writers import open_writer

HISTOGRAM_BINS = 1 << 16
EXACT_INTEGER_SPAN = 1 << 20
FLOOR_PERCENTILE = 1.0
INTENSITY_PERCENTILE = 99.0
ROW = "__row__"
KEY_SPAN = 1 << 31  # a cover column (i, j) is counted under the key i * KEY_SPAN + j + KEY_SPAN / 2
FEATURE_FIELDS = ("colors", "intensity", "normals")
# Bytes a point of a tile costs while the tile is prepared and voted on, beyond its spill record
# (read, then copied into arrays): float64 and float32 coordinates, the coordinate sort, the grid
# cells and np.unique's copies, the inverse index, the k-d tree, the vote's float64 totals. Measured
# as the peak resident growth (ru_maxrss) of that work on 200k and 800k points of the benchmark's
# street scan (grid 0.2 m): 177 bytes a point, the cover's index arrays aside; rounded up.
TILE_BYTES_PER_POINT = 256
# What one forward pass at inference adds to the resident size: a fixed part (the allocator's and
# oneDNN's scratch) and a part per crop point. Measured on the CPU as the peak resident growth of
# one pass (ru_maxrss) over untrained models: PointNet++ 229 MB for 8 crops of 4096 points, 112 MB
# for 4 of 512; PTv3 442 MB and 93 MB; rounded up to 128 MB + 8 kB (PTv3 16 kB) per crop point.
INFERENCE_FIXED_BYTES = 128 << 20
INFERENCE_BYTES_PER_CROP_POINT = {"pointnet2": 8 << 10, "ptv3": 16 << 10}
DEFAULT_INFERENCE_BYTES = 16 << 10
RESULT = np.dtype([("label", "<i4"), ("confidence", "<f4")])


# ---------------------------------------------------------------------------------------------
# The scan's own numbers, from windows of points
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ScanFrame:
    """What every piece of one scan is prepared with (module doc).

    ``offset`` (3,) is subtracted from float64 coordinates (:func:`~.labelled.as_scan`);
    ``origin`` (3,) is the grid's corner in that frame, the minimum of the finite points;
    ``floor`` the z the height feature starts from; ``intensity_scale`` what intensity is
    divided by (None: the scan has none).
    """

    offset: np.ndarray
    origin: np.ndarray
    floor: float
    intensity_scale: float | None


class Histogram:
    """Percentiles of a stream of values from a histogram over ``[low, high]`` fixed in advance:
    one bin per value for integers spanning fewer than ``EXACT_INTEGER_SPAN`` (exact), else
    ``HISTOGRAM_BINS`` bins with values spread evenly inside each. The counts, and so the answer,
    do not depend on how the values are split into windows."""

    def __init__(self, low: float, high: float, integer: bool):
        self.low, self.high = float(low), float(high)
        self.exact = integer and high - low < EXACT_INTEGER_SPAN
        self.bins = int(high - low) + 1 if self.exact else HISTOGRAM_BINS
        self.counts = np.zeros(self.bins, np.int64)

    def add(self, values: np.ndarray) -> None:
        values = np.asarray(values, np.float64).ravel()
        if self.exact:
            self.counts += np.bincount((values - self.low).astype(np.int64), minlength=self.bins)
        elif self.high > self.low:
            self.counts += np.histogram(values, self.bins, (self.low, self.high))[0]
        else:
            self.counts[0] += len(values)

    def ranked(self, k: int) -> float:
        """The ``k``-th smallest value (from 0)."""
        total = np.cumsum(self.counts)
        b = int(np.searchsorted(total, k, side="right"))
        if self.exact:
            return self.low + b
        width = (self.high - self.low) / self.bins
        before = total[b] - self.counts[b]
        return self.low + width * (b + (k - before + 0.5) / self.counts[b])

    def percentile(self, q: float) -> float:
        """``np.percentile``'s linear rule between the two ranked values around ``q``."""
        n = int(self.counts.sum())
        if n == 0:
            return 1.0
        index = q / 100 * (n - 1)
        k = int(math.floor(index))
        lower, upper = self.ranked(k), self.ranked(min(k + 1, n - 1))
        return lower + (upper - lower) * (index - k)


class Survey:
    """The first pass: finite bounds, the intensity range, points per cover column of side ``cell``."""

    def __init__(self, cell: float):
        self.cell = cell
        self.low, self.high = np.full(3, np.inf), np.full(3, -np.inf)
        self.points = 0
        self.finite = 0
        self.float64 = False
        self.intensity: list[float] | None = None
        self.integer_intensity = True
        self.keys = np.zeros(0, np.int64)
        self.counts = np.zeros(0, np.int64)

    def add(self, chunk: PointCloud) -> None:
        self.points += len(chunk)
        self.float64 = chunk.points.dtype == np.float64
        finite = np.isfinite(chunk.points).all(axis=1)
        points = chunk.points[finite].astype(np.float64)
        self.finite += len(points)
        if len(points):
            self.low = np.minimum(self.low, points.min(axis=0))
            self.high = np.maximum(self.high, points.max(axis=0))
            cells = np.floor(points[:, :2] / self.cell).astype(np.int64)
            keys, counts = np.unique(cells[:, 0] * KEY_SPAN + (cells[:, 1] + KEY_SPAN // 2), return_counts=True)
            keys, where = np.unique(np.concatenate([self.keys, keys]), return_inverse=True)
            self.counts = np.bincount(where, np.concatenate([self.counts, counts]), len(keys)).astype(np.int64)
            self.keys = keys
        if "intensity" in chunk.fields and len(chunk):
            values = np.asarray(chunk.fields["intensity"])
            self.integer_intensity &= bool(np.issubdtype(values.dtype, np.integer))
            low, high = float(values.min()), float(values.max())
            self.intensity = [low, high] if self.intensity is None else [min(self.intensity[0], low),
                                                                          max(self.intensity[1], high)]

    def offset(self) -> np.ndarray:
        return np.floor(self.low) if self.float64 else np.zeros(3)

    def levels(self) -> Levels:
        return Levels(self)


class Levels:
    """The second pass: the histograms of z (in the scan's frame) and of intensity."""

    def __init__(self, survey: Survey):
        self.offset = survey.offset()
        low, high = self._frame(survey.low), self._frame(survey.high)
        self.origin = low
        self.z = Histogram(low[2], high[2], integer=False)
        self.intensity = None if survey.intensity is None else Histogram(*survey.intensity, survey.integer_intensity)

    def _frame(self, corner: np.ndarray) -> np.ndarray:
        """A corner as :func:`~.labelled.as_scan` stores it: float32 after the offset, back in float64."""
        return (corner - self.offset).astype(np.float32).astype(np.float64)

    def add(self, chunk: PointCloud) -> None:
        finite = np.isfinite(chunk.points).all(axis=1)
        z = chunk.points[finite, 2]
        self.z.add((z - self.offset[2] if z.dtype == np.float64 else z).astype(np.float32))
        if self.intensity is not None:
            self.intensity.add(chunk.fields["intensity"])

    def frame(self) -> ScanFrame:
        scale = None if self.intensity is None else self.intensity.percentile(INTENSITY_PERCENTILE)
        return ScanFrame(self.offset, self.origin, self.z.percentile(FLOOR_PERCENTILE), scale)


def frame_of(cloud: PointCloud, path: Path) -> ScanFrame:
    """The :class:`ScanFrame` of a scan held whole (what the streamed passes compute)."""
    survey = Survey(1.0)
    survey.add(cloud)
    if survey.finite == 0:
        raise FormatError(path, "has no points with finite coordinates")
    levels = survey.levels()
    levels.add(cloud)
    return levels.frame()


# ---------------------------------------------------------------------------------------------
# Streamed prediction
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TilePlan:
    """Tiles of ``size`` (a multiple of the cover cell) with ``halo``, and crops per batch."""

    size: float
    halo: float
    batch_size: int
    largest: int


def halo_of(config: dict[str, Any]) -> float:
    """The halo that gives a tile's points the whole scan's votes (module doc)."""
    return config["radius"] * (COVER_CELL_RADII + 1) + 2 * config["grid"]


def inference_bytes(config: dict[str, Any], batch_size: int) -> int:
    """What one forward pass of ``batch_size`` crops costs beside the model's weights."""
    per_point = INFERENCE_BYTES_PER_CROP_POINT.get(config["model"], DEFAULT_INFERENCE_BYTES)
    return INFERENCE_FIXED_BYTES + batch_size * config["points"] * per_point


def in_memory_bytes(points: int, template: PointCloud, config: dict[str, Any]) -> int:
    """About what predicting ``points`` points read whole needs beside the interpreter."""
    return points * (3 * bytes_per_point(template) + TILE_BYTES_PER_POINT) + inference_bytes(config,
                                                                                               config["batch_size"])


def plan_tiles(survey: Survey, config: dict[str, Any], budget: int, spill_bytes: int, path: Path) -> TilePlan:
    """The largest tiles whose densest one, halo included, fits ``budget`` (module doc), or a
    one-line refusal naming the budget the densest single cell would need."""
    cell = survey.cell
    halo = halo_of(config)
    resident = resident_bytes()
    per_point = spill_bytes + TILE_BYTES_PER_POINT
    i, j = survey.keys // KEY_SPAN, survey.keys % KEY_SPAN - KEY_SPAN // 2
    i0, j0 = int(i.min()), int(j.min())
    grid = np.zeros((int(i.max()) - i0 + 1, int(j.max()) - j0 + 1), np.int64)
    grid[i - i0, j - j0] = survey.counts
    table = np.zeros((grid.shape[0] + 1, grid.shape[1] + 1), np.int64)
    table[1:, 1:] = grid.cumsum(0).cumsum(1)
    reach = int(math.ceil(halo / cell))  # tiles are whole cells from the same origin

    def densest(k: int) -> int:
        """Points in the fullest tile of ``k`` x ``k`` cells, with ``reach`` cells around it."""
        def edges(start: int, length: int) -> tuple[np.ndarray, np.ndarray]:
            first = np.arange(start // k, (start + length - 1) // k + 1) * k - start
            return np.clip(first - reach, 0, length), np.clip(first + k + reach, 0, length)

        (a0, a1), (b0, b1) = edges(i0, grid.shape[0]), edges(j0, grid.shape[1])
        sums = (table[np.ix_(a1, b1)] - table[np.ix_(a0, b1)] - table[np.ix_(a1, b0)] + table[np.ix_(a0, b0)])
        return int(sums.max())

    smallest = densest(1)
    batch = config["batch_size"]
    while batch > 1 and resident + inference_bytes(config, batch) + smallest * per_point > budget:
        batch //= 2
    need = resident + inference_bytes(config, batch) + smallest * per_point
    if need > budget:
        raise OptionError(
            f"--memory {_size(budget)} is too small to predict {path}: this process ({_size(resident)}), the "
            f"model's pass over one crop of {config['points']} points and the densest tile ({smallest:,} points "
            f"within {halo:g} m) need about {_size(need)}; give --memory {_size(need, up=True)} or more")
    k = max(grid.shape)
    while k > 1 and resident + inference_bytes(config, batch) + densest(k) * per_point > budget:
        k = max(1, int(k * 0.7))
    return TilePlan(k * cell, halo, batch, densest(k))


def _size(size: int, up: bool = False) -> str:
    mib = size / (1 << 20)
    if mib >= 1024:
        gib = math.ceil(mib / 1024 * 10) / 10 if up else mib / 1024
        return f"{gib:.1f}G"
    return f"{math.ceil(mib) if up else round(mib)}M"


def predict_streamed(
    model: torch.nn.Module,
    config: dict[str, Any],
    device: torch.device,
    path: Path,
    target: Path,
    memory: str | int,
    *,
    progress: bool = False,
    scratch: str | os.PathLike[str] | None = None,
    encoding: str | None = None,
) -> dict[str, Any]:
    """Label ``path`` into ``target`` tile by tile within ``memory`` (module doc).

    Returns what :meth:`~.scene_tasks.SceneRun.predict` returns for a file, with ``tiles``,
    ``tile_size`` and ``halo``.
    """
    budget = parse_memory(memory)
    codes = np.asarray(config["codes"], np.int64)
    las = target.suffix.lower() in (".las", ".laz")
    with returning_freed_arrays():
        source = open_source(path)
        template = template_of(source)
        for feature, field in (("colour", "colors"), ("intensity", "intensity")):
            if feature in config["features"] and field not in template.fields:
                raise FormatError(path, f"has no {field!r} field, which this model takes as input")
        kept = [name for name in FEATURE_FIELDS if name in template.fields]
        window = max(1 << 14, min(1 << 20, budget // 16 // max(1, 4 * bytes_per_point(template))))
        survey = Survey(COVER_CELL_RADII * config["radius"])
        with progress_bar(source.count, f"survey {path.name}", progress) as bar:
            for chunk, _ in indexed_chunks(source, window, bar=bar):
                survey.add(chunk)
        if survey.finite == 0:
            raise FormatError(path, "has no points with finite coordinates")
        spill_template = _spill_cloud(template, kept, np.zeros(0, np.int64))
        spill_bytes = Spill(os.devnull, spill_template).dtype.itemsize
        tiles = plan_tiles(survey, config, budget, 2 * spill_bytes, path)
        levels = survey.levels()
        origin = np.zeros(2)
        target.parent.mkdir(parents=True, exist_ok=True)
        with scratch_folder(target, scratch) as folder:
            spills = TileSpills(folder)
            with progress_bar(source.count, f"tile {path.name}", progress) as bar:
                for chunk, index in indexed_chunks(source, window, bar=bar):
                    levels.add(chunk)
                    spills.add(_spill_cloud(chunk, kept, index), tiles.size, tiles.halo, origin)
            frame = levels.frame()
            results = folder / "results.bin"
            with open(results, "wb") as file:
                file.truncate(source.count * RESULT.itemsize)
            fd = os.open(results, os.O_RDWR)
            try:
                with progress_bar(survey.finite, f"predict {path.name}", progress) as bar:
                    for key in sorted(spills.spills):
                        spill = spills.spills[key]
                        own = _predict_tile(model, config, device, path, spill, key, tiles, frame, codes)
                        _write_results(fd, *own)
                        spill.remove()
                        bar.update(len(own[0]))
            finally:
                os.close(fd)
            counts = np.zeros(len(codes), np.int64)
            metadata = with_class_lookup(template.metadata, codes, config["classes"]) if las else template.metadata
            with open_writer(target, encoding, bounds=(survey.low, survey.high)) as writer, \
                    open(results, "rb") as file:
                for chunk, index in indexed_chunks(source, window):
                    file.seek(int(index[0]) * RESULT.itemsize if len(index) else 0)
                    answer = np.fromfile(file, RESULT, len(chunk))
                    real = np.isfinite(chunk.points).all(axis=1)
                    labels = np.where(real, answer["label"], -1)
                    counts += np.bincount(labels_of_codes(labels[real], codes), minlength=len(codes))[: len(codes)]
                    fields = dict(chunk.fields)
                    if las:
                        fields["classification"] = np.where(real, labels, 0).astype(np.uint8)
                    else:
                        fields["label"] = labels.astype(np.int32)
                    fields["confidence"] = np.where(real, answer["confidence"], 0).astype(np.float32)
                    writer.write(PointCloud(chunk.points, fields, None, metadata))
    return {"file": str(path), "output": str(target), "points": source.count,
            "classes": {n: int(c) for n, c in zip(config["classes"], counts) if c},
            "tiles": len(spills.spills), "tile_size": tiles.size, "halo": tiles.halo}


def _spill_cloud(chunk: PointCloud, kept: Sequence[str], index: np.ndarray) -> PointCloud:
    """What a tile needs of ``chunk``: coordinates, the feature fields, and each point's file row."""
    return PointCloud(chunk.points, {**{n: chunk.fields[n] for n in kept}, ROW: index}, None, {})


def _predict_tile(
    model: torch.nn.Module, config: dict[str, Any], device: torch.device, path: Path, spill: Spill,
    key: tuple[int, int], tiles: TilePlan, frame: ScanFrame, codes: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(rows, labels, confidences)`` of the tile's own finite points, voted with its halo."""
    records = next(spill.records(max(len(spill), 1)), None)
    if records is None:
        return np.zeros(0, np.int64), np.zeros(0, np.int32), np.zeros(0, np.float32)
    cloud, _ = from_records(records, {})
    del records
    rows = cloud.fields.pop(ROW)
    name = f"{path.name} tile {key[0]} {key[1]}"
    scan = as_scan(cloud, path, name, offset=frame.offset, intensity_scale=frame.intensity_scale)
    own = np.all(np.floor(cloud.points[:, :2].astype(np.float64) / tiles.size).astype(np.int64) == key, axis=1)
    del cloud
    if not own.any():  # a tile only some neighbours' halos reach
        return np.zeros(0, np.int64), np.zeros(0, np.int32), np.zeros(0, np.float32)
    prepared, inverse = prepare_scene(scan, config["grid"], config["features"], name, return_inverse=True,
                                      origin=frame.origin, floor=frame.floor)
    del scan
    own &= inverse >= 0
    wanted = np.zeros(len(prepared), bool)
    wanted[inverse[own]] = True
    probabilities = vote(model, prepared, radius=config["radius"], points=config["points"], shape=config["shape"],
                         features=config["features"], classes=len(config["classes"]), device=device,
                         batch_size=tiles.batch_size, wanted=wanted, reach=_reach(key, tiles.size, frame, config))
    voted = inverse[own]
    best = probabilities[voted].argmax(axis=1)
    confidence = probabilities[voted, best]
    return rows[own], codes[best].astype(np.int32), confidence.astype(np.float32)


def _reach(key: tuple[int, int], size: float, frame: ScanFrame, config: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """The x y box, in the scan's frame, where windows holding the tile's points have their centres:
    the tile (in the file's frame) grown by a radius and a grid cell (a voxel centroid may sit up to a
    cell off its points), rounded outwards."""
    margin = config["radius"] + config["grid"] + 1e-3
    low = np.asarray(key, np.float64) * size - frame.offset[:2] - margin
    return low, low + size + 2 * margin


def _write_results(fd: int, rows: np.ndarray, labels: np.ndarray, confidence: np.ndarray) -> None:
    """Each row's (label, confidence) at its place in the results file, a run of rows per write."""
    if len(rows) == 0:
        return
    records = np.empty(len(rows), RESULT)
    records["label"], records["confidence"] = labels, confidence
    breaks = np.flatnonzero(np.diff(rows) != 1) + 1
    for start, stop in zip(np.r_[0, breaks], np.r_[breaks, len(rows)], strict=True):
        os.pwrite(fd, records[start:stop].tobytes(), int(rows[start]) * RESULT.itemsize)


def wants_streaming(points: int, template: PointCloud, config: dict[str, Any], memory: str | int | None) -> bool:
    """Whether a scan of ``points`` points (``template``'s layout) should be streamed: when what
    reading it whole needs does not fit ``memory`` (default: the memory the system has free)."""
    import psutil

    budget = parse_memory(memory) if memory is not None else int(psutil.virtual_memory().available)
    return resident_bytes() + in_memory_bytes(points, template, config) > budget


def stream_info(path: Path) -> tuple[int, PointCloud] | None:
    """``(points, template)`` of a file that can be read in windows, or None (read it whole)."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error", StreamingFallback)
        try:
            source = open_source(path)
        except StreamingFallback:
            return None
    return source.count, template_of(source)


__all__ = ["ScanFrame", "frame_of", "predict_streamed"]
