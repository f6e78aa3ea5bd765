"""``merge`` and ``convert``, streamed: many files into one, one file into another format, and a
folder of scans into a folder in another format.

``merge`` concatenates its inputs in the order given. The result has the fields every input
has (others are dropped, with a warning), each in the dtype numpy promotes the inputs' dtypes
to, and points in the promoted dtype of all inputs; metadata comes from the first input.
:func:`merge_clouds` is the in-memory definition.

``convert_folder`` converts every point-cloud file under a folder (recursively) into the
same relative path under another folder, with a new suffix; it is one task per file on Dask,
and outputs that exist are skipped (they are complete: every file is written atomically).
"""

from __future__ import annotations

import json
import os
import warnings
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.formats import formats
from pointfield.errors import PointfieldError
from pointfield.streaming import distributed
from pointfield.streaming.chunks import StreamingFallback
from pointfield.streaming.jobs import output_done, progress_bar, streaming_job, summary
from pointfield.streaming.memory import DEFAULT_MEMORY, plan
from pointfield.streaming.select import keep_all, select_to_file
from pointfield.streaming.tiling import MANIFEST, tile_memberships


def common_layout(templates: list[PointCloud]) -> tuple[np.dtype, dict[str, np.dtype], list[str]]:
    """The points dtype, the fields (name -> dtype) of a merge, and the fields it drops."""
    points = np.result_type(*[t.points.dtype for t in templates])
    names = [n for n in templates[0].fields if all(n in t.fields for t in templates)]
    dropped = sorted({n for t in templates for n in t.fields} - set(names))
    fields = {}
    for name in names:
        shapes = {t.fields[name].shape[1:] for t in templates}
        if len(shapes) > 1:
            dropped.append(name)
            continue
        fields[name] = np.result_type(*[t.fields[name].dtype for t in templates])
    return points, fields, dropped


def conform(points_dtype: np.dtype, fields: dict[str, np.dtype], cloud: PointCloud, index: np.ndarray) -> PointCloud:
    """The rule of ``merge``: ``cloud`` with the merge's fields and dtypes."""
    return PointCloud(
        cloud.points.astype(points_dtype, copy=False),
        {name: cloud.fields[name].astype(dtype, copy=False) for name, dtype in fields.items()},
        None,
        cloud.metadata,
    )


def merge_clouds(clouds: list[PointCloud]) -> PointCloud:
    """In memory, the merge of ``clouds`` (module docstring)."""
    points, fields, _ = common_layout(clouds)
    parts = [conform(points, fields, c, np.arange(len(c))) for c in clouds]
    return PointCloud(
        np.concatenate([p.points for p in parts]),
        {n: np.concatenate([p.fields[n] for p in parts]) for n in fields},
        None,
        dict(clouds[0].metadata),
    )


def merge(
    sources: list[str | os.PathLike[str]],
    out: str | os.PathLike[str],
    *,
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
    what: str = "merge",
    drop_buffers: bool = False,
) -> dict[str, Any]:
    """Concatenate ``sources`` into ``out``, chunk by chunk (module docstring).

    ``drop_buffers``: the sources are tiles that ``tile`` cut with a buffer; each keeps only the
    points of its own square (found in the ``tiles.json`` beside it), so that merging every tile
    gives each point once, in tile order. Without it the buffers' points come once per tile that
    holds them. Other options as :func:`~pointfield.streaming.downsample`. Returns a summary.
    """
    if not sources:
        raise PointfieldError("merge needs at least one input")
    cores = [tile_core(Path(source)) for source in sources] if drop_buffers else None
    names = [str(s) for s in sources]
    if output_done(out, overwrite):
        return summary(sources=names, out=out, skipped=True)
    with streaming_job(sources, columns=columns, memory=memory, points=points, workers=workers,
                       scheduler=scheduler, client=client, scratch=scratch, progress=progress) as job:
        points_dtype, fields, dropped = common_layout(job.templates)
        if dropped:
            warnings.warn(f"fields not in every input are left out of the merge: {', '.join(dropped)}", stacklevel=2)
        rule = keep_all if len(sources) == 1 else partial(conform, points_dtype, fields)
        if cores is not None:
            rule = [partial(keep_core, core, rule) for core in cores]
        written = select_to_file(job, Path(out), rule, encoding, what)
    return summary(sources=names, out=out, input_points=sum(s.count for s in job.sources),
                   output_points=written, skipped=False)


def tile_core(path: Path) -> tuple[float, float, float, int, int]:
    """``(origin x, origin y, size, i, j)`` of tile file ``path``, from the ``tiles.json`` beside it."""
    manifest = path.parent / MANIFEST
    try:
        document = json.loads(manifest.read_text(encoding="utf-8"))
        settings = document["settings"]
        (entry,) = [t for t in document["tiles"] if t["file"] == path.name]
        origin, size, (i, j) = settings["origin"], float(settings["size"]), entry["tile"]
    except (OSError, ValueError, KeyError, TypeError):
        raise PointfieldError(f"{path}: --drop-buffers needs the {MANIFEST} that `cloud tile` wrote beside the "
                              f"tile, listing it") from None
    return float(origin[0]), float(origin[1]), size, int(i), int(j)


def keep_core(core: tuple[float, float, float, int, int], rule: Any, cloud: PointCloud,
              index: np.ndarray) -> PointCloud:
    """The rule of ``merge --drop-buffers``: the points of the tile's own square, as ``tile``
    found them (:func:`~pointfield.streaming.tiling.tile_memberships` without a buffer: each
    finite point is in exactly one square), then ``rule``."""
    ox, oy, size, i, j = core
    ((squares, rows),) = tile_memberships(cloud.points, size, 0.0, np.array([ox, oy]))
    keep = rows[(squares == [i, j]).all(axis=1)]
    return rule(cloud.select(keep), index[keep])


def convert(source: str | os.PathLike[str], out: str | os.PathLike[str], **options: Any) -> dict[str, Any]:
    """Convert one file to the format of ``out``'s suffix, chunk by chunk, fields preserved.

    Options as :func:`merge`.
    """
    return merge([source], out, what="convert", **options)


def cloud_files(folder: Path, pattern: str | None = None) -> list[Path]:
    """The files under ``folder`` (any depth) matching ``pattern`` (``"*.bin"``), else those
    with a point-cloud suffix; sorted, hidden files left out."""
    suffixes = {s for fmt in formats() for s in fmt.suffixes}
    found = folder.rglob(pattern) if pattern else (p for p in folder.rglob("*") if p.suffix.lower() in suffixes)
    return sorted(p for p in found if p.is_file() and not p.name.startswith("."))


def convert_task(source: str, out: str, encoding: str | None, points: int, columns: int | None,
                 overwrite: bool) -> dict[str, Any]:
    """Convert one file (a task of :func:`convert_folder`); a bad file is reported, not raised."""
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            result = convert(source, out, encoding=encoding, points=points, columns=columns, overwrite=overwrite)
    except PointfieldError as error:
        return {"source": source, "error": str(error)}
    # A task's warnings would be lost on a worker: the files read or written whole go back with the result.
    return {**result, "whole": [str(w.message) for w in caught if issubclass(w.category, StreamingFallback)]}


def convert_folder(
    folder: str | os.PathLike[str],
    outdir: str | os.PathLike[str],
    suffix: str | None = None,
    *,
    pattern: str | None = None,
    encoding: str | None = None,
    memory: str | int = DEFAULT_MEMORY,
    points: int | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    client: Any = None,
    overwrite: bool = False,
    progress: bool = False,
    columns: int | None = None,
) -> dict[str, Any]:
    """Convert every point-cloud file under ``folder`` into ``outdir``, same relative paths.

    ``suffix`` (``".laz"``) is the outputs' format; None keeps each file's own. ``pattern``
    (``"*.bin"``) picks the inputs; by default every file with a point-cloud suffix. Outputs
    that exist are skipped unless ``overwrite``. A file that cannot be read does not stop the
    others: once they are done, a PointfieldError names every file that failed and why.
    Returns how many files were converted and skipped.
    """
    folder, outdir = Path(folder), Path(outdir)
    if not folder.is_dir():
        raise PointfieldError(f"{folder}: not a folder")
    suffix = suffix if suffix is None or suffix.startswith(".") else f".{suffix}"
    inputs = cloud_files(folder, pattern)
    chunk_points = points or plan(memory, 64).chunk_points
    jobs = []
    skipped = 0
    targets: dict[Path, Path] = {}
    for path in inputs:
        target = outdir / path.relative_to(folder)
        target = target.with_suffix(suffix) if suffix else target
        if target in targets:
            raise PointfieldError(
                f"{targets[target]} and {path} would both be written to {target}; choose the "
                "inputs with a pattern (--pattern '*.bin')"
            )
        targets[target] = path
        if target.exists() and not overwrite:
            skipped += 1
            continue
        jobs.append((str(path), str(target), encoding, chunk_points, columns, overwrite))
    with distributed.cluster(workers, scheduler, client) as dask_client, \
            progress_bar(len(jobs), f"convert {folder.name}", progress, "file") as bar:
        results = distributed.run_tasks(dask_client, convert_task, jobs, bar)
    whole = [message for r in results for message in r.get("whole", ())]
    if whole:
        warnings.warn(f"{len(whole)} of the files could not be streamed and were held whole in memory "
                      f"(first: {whole[0]})", StreamingFallback, stacklevel=2)
    failed = [r for r in results if "error" in r]
    if failed:
        raise PointfieldError(
            f"{len(failed)} of {len(jobs)} files could not be converted (the others were): "
            + "; ".join(r["error"] for r in failed[:5]) + (" ..." if len(failed) > 5 else "")
        )
    return summary(source=folder, out=outdir, files=len(inputs), converted=len(jobs), skipped=skipped,
                   points=sum(r.get("output_points", 0) for r in results))
