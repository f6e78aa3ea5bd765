"""Registration past memory: scans read whole, or thinned while streaming, within a ``--memory`` budget;
and scans written moved, chunk by chunk, into one file of any size.

What registration holds is the clouds it registers (every scan, for ``align``) and, for the pair
being registered, its thinned levels, k-d trees, normals or covariances and features. The
budget check (:func:`registration_bytes`) counts the first at their arrays' size and the second
at :data:`PAIR_BYTES_PER_POINT`, measured. The point counts come from the files' headers, so a
pair that fits is read whole, exactly as before; one that does not is **thinned while reading**
(the streamed voxel reduction of ``cloud downsample``, one centroid per voxel, never more than a
chunk of the file in memory) rather than refused, because registration at the voxel works on
the thinned scans anyway (``register``'s coarse levels and global step, ``align``'s every pair),
and only the last sub-voxel refinement is given up -- each such choice is one of the notes. Only
when the thinned scans still do not fit is the job refused, in one line naming the voxel that
would fit (points on a surface fall with the square of the voxel).

:func:`write_moved` writes scans moved by their poses into one file through the streaming writer
(:func:`~pointfield.streaming.open_writer`), a chunk at a time: any size, every field kept
(those not in every scan are left out, with a warning, as ``cloud merge`` does).
"""

from __future__ import annotations

import os
import tempfile
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from pointfield.clouds import read
from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.formats.chunked import concatenate
from pointfield.errors import PointfieldError
from pointfield.registration.pairwise import aligned, check_transformation
from pointfield.streaming.chunks import ChunkSource, StreamingFallback, WholeSource, open_source
from pointfield.streaming.jobs import bytes_per_point, finite_bounds, indexed_chunks, scratch_folder, streaming_job
from pointfield.streaming.memory import DEFAULT_MEMORY, parse_memory, plan, usable_bytes
from pointfield.streaming.merging import common_layout, conform
from pointfield.streaming.voxels import VoxelGrid, reduce_voxels
from pointfield.streaming.writers import open_writer

PAIR_BYTES_PER_POINT = 1500
"""Peak resident growth per point of the pair being registered, measured on a 200,000-point pair
(``/usr/bin/time``-style ``ru_maxrss``): 250 bytes for point-to-plane, 330 generalized ICP, 1,250
coloured ICP (the numpy reference), 1,460 global (FPFH + RANSAC) then generalized ICP."""
HELD_BYTES_PER_POINT = 112
"""Per point of every scan held, beyond its fields: the float64 points, normals and intensity of its
:class:`~pointfield.registration.Scan`, and the shifted copy ``align`` registers."""
KEPT_FIELDS = ("normals", "colors")
"""What thinning keeps of a scan: what registration reads (:meth:`Scan.from_cloud`)."""


def registration_bytes(counts: Sequence[int], layouts: Sequence[int], pair: int) -> int:
    """Bytes registration needs: scans of ``counts`` points (``layouts`` bytes each) held, plus the
    largest pair being registered, ``pair`` points together."""
    held = sum(n * (b + HELD_BYTES_PER_POINT) for n, b in zip(counts, layouts))
    return int(held + PAIR_BYTES_PER_POINT * pair)


def _largest_pair(counts: Sequence[int]) -> int:
    return sum(sorted(counts)[-2:])


def _thin(source: ChunkSource, voxel: float, budget: int, scratch: str | os.PathLike[str]) -> PointCloud:
    """``source`` thinned to one centroid per voxel of ``voxel``, streamed (points, normals and colours only)."""
    path = source.path
    template = source.read(0, 0)
    kept = {name: template.fields[name] for name in KEPT_FIELDS if name in template.fields}
    template = PointCloud(template.points.astype(np.float64), kept, None, {})
    memory = plan(budget, bytes_per_point(template))
    low, high, finite = finite_bounds(source, memory.chunk_points)
    if finite == 0:
        raise PointfieldError(f"{path}: no finite points; registration needs at least 3")
    grid = VoxelGrid.covering(low, high, voxel)

    def chunks():
        for chunk, index in indexed_chunks(source, memory.chunk_points):
            yield PointCloud(chunk.points.astype(np.float64), {n: chunk.fields[n] for n in kept}, None, {}), index

    with scratch_folder(path, scratch) as folder:
        parts = list(reduce_voxels(chunks(), grid, template, "centroid", memory.state_bytes, folder,
                                   expected_points=source.count))
    return concatenate(parts) if parts else template


def read_scans(paths: Sequence[str | os.PathLike[str]], voxel: float | None = None,
               memory: str | int | None = None, what: str = "registration",
               scratch: str | os.PathLike[str] | None = None) -> tuple[list[PointCloud], list[str]]:
    """``(clouds, notes)``: the scans at ``paths``, read whole when registering them fits ``memory``,
    else thinned to ``voxel`` while streaming (module docstring).

    ``voxel`` None: thinning uses 1/200 of the first scan's bounding-box diagonal (the floor
    :func:`~pointfield.registration.default_voxel` puts under the voxel). ``memory`` None: no
    limit, every scan read whole. ``scratch``: the folder where thinning parks voxels it cannot hold
    (default: the system's temporary folder). A :class:`PointfieldError` when the thinned scans do not fit.
    """
    paths = [Path(p) for p in paths]
    if memory is None:
        return [read(p) for p in paths], []
    budget = parse_memory(memory)
    usable = usable_bytes(budget)
    with warnings.catch_warnings():
        # A text file is read whole to be counted, as it would have been to be registered: no news.
        warnings.simplefilter("ignore", StreamingFallback)
        sources = [open_source(p) for p in paths]
    counts = [s.count for s in sources]
    layouts = [bytes_per_point(s.read(0, 0)) for s in sources]
    need = registration_bytes(counts, layouts, _largest_pair(counts))
    if need <= usable:
        return [s.cloud if isinstance(s, WholeSource) else read(p) for s, p in zip(sources, paths)], []
    notes = []
    if voxel is None:
        source = sources[0]
        low, high, _ = finite_bounds(source, plan(budget, layouts[0]).chunk_points)
        voxel = float(np.linalg.norm(high - low)) / 200.0
        if not (np.isfinite(voxel) and voxel > 0):
            raise PointfieldError(f"{paths[0]}: its points have no extent; registration needs a cloud with extent")
        reason = f"voxel {voxel:.4g} (1/200 of {paths[0].name}'s diagonal; set --voxel to choose)"
    elif not (np.isfinite(voxel) and voxel > 0):
        raise PointfieldError(f"--voxel must be a positive number, got {voxel}")
    else:
        reason = f"--voxel {voxel:g}"
    clouds: list[PointCloud] = []
    for k, source in enumerate(sources):
        clouds.append(_thin(source, voxel, budget, scratch or tempfile.gettempdir()))
        # The scans still to come, estimated at the share of their points the ones read kept.
        kept_share = sum(len(c) for c in clouds) / max(1, sum(counts[: k + 1]))
        estimate = [len(c) for c in clouds] + [int(kept_share * n) for n in counts[k + 1:]]
        thinned = registration_bytes(estimate, [bytes_per_point(clouds[0])] * len(estimate), _largest_pair(estimate))
        if thinned > usable:
            fit = voxel * np.sqrt(thinned / max(usable, 1)) * 1.1
            raise PointfieldError(
                f"{what} of {', '.join(p.name for p in paths)}: thinned to voxel {voxel:.4g} the scans hold about "
                f"{sum(estimate):,} points, {thinned / 2**20:,.0f} MiB for {what}, past the {usable / 2**20:,.0f} MiB "
                f"that --memory {budget / 2**20:,.0f} MiB leaves beside the interpreter; give --voxel {fit:.3g} or a "
                "larger --memory")
    notes.append(f"{sum(counts):,} points would take about {need / 2**20:,.0f} MiB in {what}, past --memory "
                 f"{budget / 2**20:,.0f} MiB: read thinned while streaming to {reason}, "
                 f"{sum(len(c) for c in clouds):,} points")
    return clouds, notes


def write_moved(paths: Sequence[str | os.PathLike[str]], poses: Sequence[np.ndarray | None],
                out: str | os.PathLike[str], memory: str | int | None = None, encoding: str | None = None,
                points: int | None = None) -> int:
    """Write each scan at ``paths`` moved by its pose (None: left out) into ``out``, chunk by chunk.

    ``poses`` ``(4, 4)`` each, as :func:`~pointfield.registration.aligned` applies them (normals
    turned, every other field kept). The format is ``out``'s suffix's; the file appears whole or
    not at all. ``points`` per chunk (default: what ``memory`` allows). The result is the in-memory
    one, ``aligned`` scan by scan and concatenated, whatever the chunks. Returns the points written.
    """
    if len(paths) != len(poses):
        raise PointfieldError(f"{len(paths)} scans but {len(poses)} poses")
    chosen = [(Path(p), check_transformation(t, f"pose of {p}")) for p, t in zip(paths, poses) if t is not None]
    if not chosen:
        raise PointfieldError("no scan to write: every one was left out")
    with streaming_job([p for p, _ in chosen], memory=memory or DEFAULT_MEMORY, points=points) as job:
        points_dtype, fields, dropped = common_layout(job.templates)
        if dropped:
            warnings.warn(f"{out}: fields not in every scan are left out: {', '.join(dropped)}", stacklevel=2)
        empty = np.zeros(0, np.int64)
        with open_writer(out, encoding) as writer:
            writer.write(conform(points_dtype, fields, job.template, empty))
            for source, (_, pose) in zip(job.sources, chosen):
                for chunk, index in indexed_chunks(source, job.points):
                    writer.write(conform(points_dtype, fields, aligned(chunk, pose), index))
            return writer.count


__all__ = ["read_scans", "registration_bytes", "write_moved"]
