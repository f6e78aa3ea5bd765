"""Predicting a folder of tiles as one scan, a task per tile: ``segment predict RUN TILES/ --out OUT/ --workers 4``.

A survey cut into tiles (``cloud tile``, a provider's delivery of 1 km squares) is one scan in
many files. Predicted one by one, each tile's crops would stop at its border, and the labels
would show a seam there: a window near the border sees half of what it sees in the whole scan.
Here each tile's windows see its neighbours' points too, so every point gets the votes the tiles
merged into one cloud would give it. Three rounds of one task per file, on the Dask cluster of
:func:`pointfield.streaming.distributed.cluster` (``workers`` / ``scheduler`` / ``client``, as
the streaming verbs), or one after another in this process without one:

1. **survey**: each file's finite bounds, intensity range and fields
   (:class:`~.scene_streaming.Survey`), merged into the whole scan's;
2. **levels**: each file's histograms of z and intensity on the scan's bins
   (:class:`~.scene_streaming.Levels`), summed into the scan's :class:`~.scene_streaming.ScanFrame`
   (offset, grid corner, floor, intensity scale): what the merged cloud is prepared with;
3. **predict**: a tile read whole, with the points of the files whose bounds meet its own bounds
   grown by the halo (:func:`~.scene_streaming.halo_of`, ``3 * radius + 2 * grid``), and of
   those only the points inside that box (a COPC neighbour is queried for the box alone); the
   windows reaching the tile are voted on (:func:`~.scene_crops.vote` with ``wanted`` and
   ``reach``), and the tile is written, labelled, to its output of the same name and format
   (atomically, with its ``.classes.json``).

Why the halo suffices is :mod:`~.scene_streaming`'s argument, with the tile's bounding box in
place of its square: every cover cell within a radius of the tile is whole in the box grown by
the halo, so are the windows holding the tile's points and their grid cells. The labels are
those of the merged cloud; only which crops share a batch differs, which can move the probabilities
by float rounding alone (:func:`~.scene_crops.vote` pads every crop to the run's size). A tile is read whole with its halo: tiles are
meant to be of a size that fits a worker.

A file that cannot be read is named in one line before anything is written (the survey reads
every file first).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.datasets.labelled import as_scan
from pointfield.clouds.formats import format_of, read
from pointfield.clouds.formats.chunked import concatenate
from pointfield.clouds.scene_crops import COVER_CELL_RADII, prepare_scene, vote
from pointfield.clouds.scene_streaming import FEATURE_FIELDS, Levels, ScanFrame, Survey, halo_of
from pointfield.errors import FormatError, PointfieldError
from pointfield.streaming import distributed
from pointfield.streaming.chunks import open_source
from pointfield.streaming.jobs import progress_bar

WINDOW_POINTS = 1 << 20  # points per window when a file is surveyed or its halo read


def predict_tiles(
    model: torch.nn.Module,
    config: dict[str, Any],
    device: torch.device,
    paths: Sequence[Path],
    targets: Sequence[Path],
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    client: Any = None,
    progress: bool = False,
) -> list[dict[str, Any]]:
    """Label the tiles ``paths`` of one scan into ``targets`` (module doc), a task per tile.

    Returns one dict per tile as :meth:`~.scene_tasks.SceneRun.predict` does (``file``,
    ``output``, ``points``, ``classes``), with ``neighbours``: the files whose points reached it.
    """
    if not paths:
        raise PointfieldError("no tiles to predict")
    cell = COVER_CELL_RADII * config["radius"]
    with distributed.cluster(workers, scheduler, client) as dask:
        calls = [(str(p), cell, config) for p in paths]
        with progress_bar(len(calls), "survey tiles", progress, "tile") as bar:
            surveys = distributed.run_tasks(dask, survey_task, calls, bar)
        survey = merged_survey([s for s, _ in surveys])
        if survey.finite == 0:
            raise FormatError(paths[0].parent, "the tiles have no points with finite coordinates")
        kept = [name for name in FEATURE_FIELDS if all(name in fields for _, fields in surveys)]
        with progress_bar(len(calls), "levels of tiles", progress, "tile") as bar:
            levels = distributed.run_tasks(dask, levels_task, [(str(p), survey) for p in paths], bar)
        frame = merged_levels(levels).frame()
        halo = halo_of(config)
        boxes = [(s.low, s.high) if s.finite else None for s, _ in surveys]
        shared = dask.scatter(model, broadcast=True, hash=False) if dask is not None else model
        calls = [(shared, config, device, str(path), str(target), frame, box, _neighbours(i, boxes, paths, halo),
                  halo, kept) for i, (path, target, box) in enumerate(zip(paths, targets, boxes, strict=True))]
        with progress_bar(len(calls), "predict tiles", progress, "tile") as bar:
            return distributed.run_tasks(dask, predict_tile_task, calls, bar)


def _neighbours(index: int, boxes: list[tuple[np.ndarray, np.ndarray] | None], paths: Sequence[Path],
                halo: float) -> list[str]:
    """The other files whose x y bounds meet tile ``index``'s grown by ``halo``."""
    own = boxes[index]
    if own is None:
        return []
    low, high = own[0][:2] - halo, own[1][:2] + halo
    return [str(paths[j]) for j, box in enumerate(boxes)
            if j != index and box is not None and np.all(box[0][:2] <= high) and np.all(box[1][:2] >= low)]


def survey_task(path: str, cell: float, config: dict[str, Any]) -> tuple[Survey, list[str]]:
    """One file's :class:`Survey` and field names (a task): refuses a file lacking a field the model reads."""
    source = open_source(path)
    template = source.read(0, 0)
    for feature, field in (("colour", "colors"), ("intensity", "intensity")):
        if feature in config["features"] and field not in template.fields:
            raise FormatError(path, f"has no {field!r} field, which this model takes as input")
    survey = Survey(cell)
    for chunk in source.chunks(WINDOW_POINTS):
        survey.add(chunk)
    return survey, sorted(template.fields)


def merged_survey(surveys: Sequence[Survey]) -> Survey:
    """The survey of the files concatenated (what :func:`~.scene_streaming.frame_of` of the merged cloud sees)."""
    merged = Survey(surveys[0].cell)
    for survey in surveys:
        merged.points += survey.points
        merged.finite += survey.finite
        merged.low, merged.high = np.minimum(merged.low, survey.low), np.maximum(merged.high, survey.high)
        merged.float64 |= survey.float64  # concatenated coordinates take the wider type
        if survey.intensity is not None:
            merged.integer_intensity &= survey.integer_intensity
            merged.intensity = list(survey.intensity) if merged.intensity is None else [
                min(merged.intensity[0], survey.intensity[0]), max(merged.intensity[1], survey.intensity[1])]
    return merged


def levels_task(path: str, survey: Survey) -> Levels:
    """One file's histograms on the scan's bins (a task)."""
    levels = survey.levels()
    for chunk in open_source(path).chunks(WINDOW_POINTS):
        levels.add(chunk)
    return levels


def merged_levels(levels: Sequence[Levels]) -> Levels:
    """The files' histograms summed: every file counted on the same bins."""
    merged = levels[0]
    for other in levels[1:]:
        merged.z.counts += other.z.counts
        if merged.intensity is not None:
            merged.intensity.counts += other.intensity.counts
    return merged


def predict_tile_task(
    model: torch.nn.Module, config: dict[str, Any], device: torch.device, path: str, target: str, frame: ScanFrame,
    box: tuple[np.ndarray, np.ndarray] | None, neighbours: list[str], halo: float, kept: list[str],
) -> dict[str, Any]:
    """Label one tile with its neighbours' points within ``halo`` of its bounds ``box`` (a task)."""
    from pointfield.clouds.scene_tasks import check_scan_fields, write_labelled

    path_, target_ = Path(path), Path(target)
    data = read(path_)
    check_scan_fields(data, path_, config)
    classes = len(config["classes"])
    if box is None:  # no finite point: nothing to vote on, every point unlabelled
        return {**write_labelled(data, path_, target_, np.zeros((0, classes), np.float32),
                                 np.full(len(data), -1, np.int64), config), "neighbours": []}
    low, high = box[0][:2] - halo, box[1][:2] + halo
    parts = [_part(data, kept)]
    for other in neighbours:
        options = {"bounds": (*low, *high)} if "bounds" in format_of(other).chunk_options else {}
        for chunk in open_source(other, **options).chunks(WINDOW_POINTS):
            with np.errstate(invalid="ignore"):
                inside = np.all((chunk.points[:, :2] >= low) & (chunk.points[:, :2] <= high), axis=1)
            if inside.any():
                parts.append(_part(chunk.select(inside), kept))
    cloud = concatenate(parts) if len(parts) > 1 else parts[0]
    scan = as_scan(cloud, path_, path_.name, offset=frame.offset, intensity_scale=frame.intensity_scale)
    del cloud, parts
    prepared, inverse = prepare_scene(scan, config["grid"], config["features"], path_.name, return_inverse=True,
                                      origin=frame.origin, floor=frame.floor)
    own = inverse[: len(data)]
    wanted = np.zeros(len(prepared), bool)
    wanted[own[own >= 0]] = True
    margin = config["radius"] + config["grid"] + 1e-3  # as a streamed tile's reach (scene_streaming._reach)
    reach = (box[0][:2] - frame.offset[:2] - margin, box[1][:2] - frame.offset[:2] + margin)
    probabilities = vote(model.to(device), prepared, radius=config["radius"], points=config["points"],
                         shape=config["shape"], features=config["features"], classes=classes, device=device,
                         batch_size=config["batch_size"], wanted=wanted, reach=reach)
    return {**write_labelled(data, path_, target_, probabilities, own, config), "neighbours": neighbours}


def _part(cloud: PointCloud, kept: Sequence[str]) -> PointCloud:
    """What a tile's scan needs of ``cloud``: coordinates and the feature fields every tile has."""
    return PointCloud(cloud.points, {name: cloud.fields[name] for name in kept}, None, {})


def tile_targets(inputs: Sequence[str | os.PathLike[str]], out: Path) -> tuple[list[Path], list[Path]]:
    """The tiles named by ``inputs`` (files, and folders: their cloud files at any depth) and their
    outputs: ``out/<name>``, or ``out/<path inside the folder>`` for a folder's files."""
    from pointfield.clouds.formats import formats
    from pointfield.streaming.merging import cloud_files

    if out.suffix.lower() in {s for fmt in formats() for s in fmt.suffixes} and not out.is_dir():
        raise PointfieldError(f"{out}: tiles are written to a folder, each under its own name; give a folder")
    paths: list[Path] = []
    targets: list[Path] = []
    for given in map(Path, inputs):
        if given.is_dir():
            # Outputs written inside the folder (a re-run into TILES/labelled) are not tiles.
            inside = out.resolve() != given.resolve()  # OUT a folder within TILES/: not its own tiles
            found = [p for p in cloud_files(given) if not (inside and p.resolve().is_relative_to(out.resolve()))]
            if not found:
                raise PointfieldError(f"{given}: no point-cloud files in this folder")
            paths += found
            targets += [out / p.relative_to(given) for p in found]
        elif given.is_file():
            paths.append(given)
            targets.append(out / given.name)
        else:
            raise PointfieldError(f"{given}: no such file or folder")
    inputs_ = {p.resolve() for p in paths}
    seen: dict[Path, Path] = {}
    for path, target in zip(paths, targets, strict=True):
        if target.resolve() in inputs_:
            raise PointfieldError(f"{target}: the output would overwrite a tile that its neighbours read; "
                                  "give another output folder")
        if target in seen:
            raise PointfieldError(f"{seen[target]} and {path} would both be written to {target}")
        seen[target] = path
    return paths, targets


__all__ = ["predict_tiles", "tile_targets"]
