"""``tile``: cut a cloud into square tiles in x y, as PDAL's ``filters.splitter`` does.

Tile ``(i, j)`` holds the points with ``origin + (i, j) * size <= (x, y) < origin + (i + 1,
j + 1) * size``; with ``buffer = b`` it also holds the points within ``b`` of that square
(``[.. - b, .. + b)`` on each side), so neighbouring tiles overlap by ``2b``. Points keep their
file order inside a tile; points with a NaN x or y belong to no tile. Tiles are written to
``OUTDIR/<stem>_<i>_<j><suffix>``, then ``OUTDIR/tiles.json`` lists them; a tile file that
exists is complete (written atomically) and a re-run skips it. :func:`tile_cloud` is the
in-memory definition.

Streaming: one pass sorts each chunk's points into one spill per tile on disk; then each
tile is written from its spill. On Dask, pieces of the file are sorted in parallel and each
tile is written by a worker, from the pieces' spills in file order.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np

from pointfield.atomic import atomic_path
from pointfield.clouds.arrays import finite_corners
from pointfield.clouds.cloud import PointCloud
from pointfield.errors import PointfieldError
from pointfield.streaming import distributed
from pointfield.streaming.chunks import open_source
from pointfield.streaming.jobs import (
    Job,
    indexed_chunks,
    progress_bar,
    scratch_folder,
    streaming_job,
    summary,
)
from pointfield.streaming.memory import DEFAULT_MEMORY
from pointfield.streaming.spill import Spill
from pointfield.streaming.writers import open_writer

MANIFEST = "tiles.json"


def tile_memberships(points: np.ndarray, size: float, buffer: float, origin: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """``[(tiles (M, 2) int64, rows (M,))]``: every (tile, point) pair, point order kept.

    Each pair comes from one ``(di, dj)`` offset of the buffered range; a point appears at
    most once per tile.
    """
    u = points[:, :2].astype(np.float64) - origin
    finite = np.isfinite(u).all(axis=1)
    rows = np.flatnonzero(finite)
    u = u[finite]
    first = np.floor((u - buffer) / size).astype(np.int64)
    last = np.floor((u + buffer) / size).astype(np.int64)
    span = int((last - first).max(initial=0)) + 1
    pairs = []
    for di in range(span):
        for dj in range(span):
            tile = first + [di, dj]
            valid = np.all(tile <= last, axis=1)
            pairs.append((tile[valid], rows[valid]))
    return pairs


def tile_rows(points: np.ndarray, size: float, buffer: float, origin: np.ndarray) -> dict[tuple[int, int], np.ndarray]:
    """Tile ``(i, j)`` -> the rows of ``points`` it holds, in increasing order."""
    rows_of: dict[tuple[int, int], list[np.ndarray]] = {}
    for tiles, rows in tile_memberships(points, size, buffer, origin):
        for key, group in _group(tiles, rows):
            rows_of.setdefault(key, []).append(group)
    return {key: np.sort(np.concatenate(groups)) for key, groups in rows_of.items()}


def tile_cloud(cloud: PointCloud, size: float, buffer: float = 0.0, origin: Any = (0.0, 0.0)) -> dict[tuple[int, int], PointCloud]:
    """In memory: tile ``(i, j)`` -> its points, in file order (module docstring)."""
    tiles = tile_rows(cloud.points, size, buffer, np.asarray(origin, np.float64))
    return {key: cloud.select(rows) for key, rows in sorted(tiles.items())}


def _group(tiles: np.ndarray, rows: np.ndarray) -> list[tuple[tuple[int, int], np.ndarray]]:
    if len(rows) == 0:
        return []
    order = np.lexsort((tiles[:, 1], tiles[:, 0]))
    tiles, rows = tiles[order], rows[order]
    starts = np.flatnonzero(np.r_[True, np.any(tiles[1:] != tiles[:-1], axis=1)])
    ends = np.r_[starts[1:], len(rows)]
    return [((int(tiles[a, 0]), int(tiles[a, 1])), rows[a:b]) for a, b in zip(starts, ends, strict=True)]


def tile_name(stem: str, key: tuple[int, int], suffix: str) -> str:
    return f"{stem}_{key[0]}_{key[1]}{suffix}"


class TileSpills:
    """One spill per tile under a folder, and the bounds of each tile's points."""

    def __init__(self, folder: Path, piece: int | None = None):
        self.folder, self.piece = folder, piece
        self.spills: dict[tuple[int, int], Spill] = {}
        self.bounds: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}

    def add(self, chunk: PointCloud, size: float, buffer: float, origin: np.ndarray) -> None:
        for key, rows in tile_rows(chunk.points, size, buffer, origin).items():
            part = chunk.select(rows)
            if key not in self.spills:
                name = f"tile_{key[0]}_{key[1]}"
                path = self.folder / f"{name}.spill"
                if self.piece is not None:
                    (self.folder / name).mkdir(exist_ok=True)
                    path = self.folder / name / f"piece-{self.piece:06d}.spill"
                self.spills[key] = Spill(path, chunk)
            self.spills[key].append(part)
            part_low, part_high, finite = finite_corners(part.points)
            if finite:
                low, high = self.bounds.get(key, (np.full(3, np.inf), np.full(3, -np.inf)))
                self.bounds[key] = (np.minimum(low, part_low), np.maximum(high, part_high))


def tile(
    source: str | os.PathLike[str],
    outdir: str | os.PathLike[str],
    size: float,
    *,
    buffer: float = 0.0,
    origin: Any = (0.0, 0.0),
    suffix: str | None = None,
    encoding: str | None = None,
    memory: str | int = DEFAULT_MEMORY,
    points: int | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    client: Any = None,
    scratch: str | os.PathLike[str] | None = None,
    overwrite: bool = False,
    progress: bool = False,
    columns: int | None = None,
) -> dict[str, Any]:
    """Cut ``source`` into tiles of ``size`` (plus ``buffer``) under ``outdir``.

    ``suffix`` picks the tiles' format (default: the source's). Returns a summary listing the
    tiles; a finished job (its ``tiles.json`` there, every tile present) is skipped unless
    ``overwrite``.
    """
    if not size > 0 or buffer < 0:
        raise PointfieldError(f"tile size must be positive and buffer >= 0, got {size} and {buffer}")
    outdir = Path(outdir)
    source = Path(source)
    suffix = suffix if suffix is None or suffix.startswith(".") else f".{suffix}"
    suffix = suffix or source.suffix
    origin = np.asarray(origin, np.float64).reshape(2)
    settings = {"source": str(source), "size": float(size), "buffer": float(buffer),
                "origin": origin.tolist(), "suffix": suffix}
    manifest = outdir / MANIFEST
    if not overwrite and manifest.exists():
        done = json.loads(manifest.read_text())
        if done.get("settings") == settings and all((outdir / t["file"]).exists() for t in done["tiles"]):
            print(f"pointfield: {manifest} lists a finished tiling; skipped — pass --overwrite to redo it",
                  file=sys.stderr)
            return summary(source=source, out=outdir, skipped=True, tiles=done["tiles"])
    with streaming_job([source], columns=columns, memory=memory, points=points, workers=workers,
                       scheduler=scheduler, client=client, scratch=scratch, progress=progress) as job:
        outdir.mkdir(parents=True, exist_ok=True)
        with scratch_folder(outdir, job.scratch) as folder:
            if job.client is None:
                spilled = _spill_tiles(job, size, buffer, origin, folder)
            else:
                spilled = _spill_tiles_on_dask(job, size, buffer, origin, folder)
            keys = sorted(spilled)
            names = [tile_name(source.stem, key, suffix) for key in keys]
            writes = [(spilled[key][0], job.template, outdir / name, encoding, spilled[key][1], job.points, overwrite)
                      for key, name in zip(keys, names, strict=True)]
            with progress_bar(len(writes), "write tiles", job.progress, "tile") as bar:
                counts = distributed.run_tasks(job.client, write_tile, writes, bar)
    tiles = [{"file": name, "tile": list(key), "points": count} for key, name, count in zip(keys, names, counts, strict=True)]
    with atomic_path(manifest) as tmp:
        tmp.write_text(json.dumps({"settings": settings, "tiles": tiles}, indent=2) + "\n")
    return summary(source=source, out=outdir, input_points=job.source.count, tiles=tiles, skipped=False)


Spilled = dict[tuple[int, int], tuple[list[Path], tuple[np.ndarray, np.ndarray] | None]]


def _spill_tiles(job: Job, size: float, buffer: float, origin: np.ndarray, folder: Path) -> Spilled:
    """Sort the points into a spill per tile: tile -> (its spills, bounds of its finite points)."""
    spills = TileSpills(folder)
    with progress_bar(job.source.count, f"tile {job.source.path.name}", job.progress) as bar:
        for chunk, _ in indexed_chunks(job.source, job.points, bar=bar):
            spills.add(chunk, size, buffer, origin)
    return {key: ([spill.path], spills.bounds.get(key)) for key, spill in spills.spills.items()}


def _spill_tiles_on_dask(job: Job, size: float, buffer: float, origin: np.ndarray, folder: Path) -> Spilled:
    """:func:`_spill_tiles`, a task per piece of the file: a spill per tile and piece."""
    src = job.source
    calls = [(str(src.path), job.options, a, b, job.points, size, buffer, origin, str(folder), n)
             for n, (a, b) in enumerate(job.pieces(src))]
    with progress_bar(len(calls), f"tile {src.path.name} (pieces)", job.progress, "piece") as bar:
        results = distributed.run_tasks(job.client, tile_scatter_task, calls, bar)
    tiles: dict[tuple[int, int], list[Any]] = {}
    for found in results:  # in piece order, so each tile's spills are in file order
        for key, (path, low, high) in found.items():
            entry = tiles.setdefault(key, [[], np.full(3, np.inf), np.full(3, -np.inf)])
            entry[0].append(Path(path))
            if low is not None:
                entry[1], entry[2] = np.minimum(entry[1], low), np.maximum(entry[2], high)
    return {key: (paths, (low, high) if np.all(low <= high) else None) for key, (paths, low, high) in tiles.items()}


def write_tile(spill_paths: list[str | Path], template: PointCloud, path: Path, encoding: str | None,
               bounds: tuple[np.ndarray, np.ndarray] | None, points: int, overwrite: bool) -> int:
    """Write one tile from its spills, in order; an existing tile is kept unless ``overwrite``.

    Returns the points in the tile.
    """
    spills = [Spill(p, template) for p in spill_paths]
    if path.exists() and not overwrite:
        return sum(len(s) for s in spills)
    with open_writer(path, encoding, bounds=bounds) as writer:
        writer.write(template)
        for spill in spills:
            for chunk, _ in spill.chunks(points):
                writer.write(chunk)
        return writer.count


def tile_scatter_task(path: str, options: dict[str, Any], start: int, stop: int, points: int, size: float,
                      buffer: float, origin: np.ndarray, folder: str, piece: int) -> dict[tuple[int, int], Any]:
    """Sort a piece's points into per-tile spills; ``{tile: (spill path, min, max)}``."""
    source = open_source(path, **options)
    spills = TileSpills(Path(folder), piece)
    for chunk, _ in indexed_chunks(source, points, start, stop):
        spills.add(chunk, size, buffer, origin)
    return {key: (str(s.path), *spills.bounds.get(key, (None, None))) for key, s in spills.spills.items()}
