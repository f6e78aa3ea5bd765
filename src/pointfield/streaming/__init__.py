"""Clouds larger than memory, and larger than one machine: every verb a window of points at a time.

The pieces, in the order data flows through them:

=====================  ====================================================================
``chunks.py``          :func:`read_chunks` / :func:`open_source`: a file as windows of points
``writers.py``         :func:`open_writer`: a file written chunk by chunk, atomically
``spill.py``           chunks parked on disk between two passes (per tile, per voxel range)
``voxels.py``          the exact one-pass voxel accumulator, bounded by spilling key ranges
``downsample.py``      ``downsample``: voxel (centroid, nearest), random, every
``crop.py``            ``crop``: box or polygon
``tile.py``            ``tile``: square tiles, with an optional buffer
``merge.py``           ``merge``, ``convert``, ``convert_folder``
``stats.py``           ``stats``: bounds, counts per class, field ranges, in one pass
``select.py``          a per-chunk rule applied here or on Dask, written in order
``distributed.py``     the same verbs on a Dask cluster: by file, and by piece and tile
``memory.py``          the ``--memory`` budget, shared between chunks and running state
``jobs.py``            skipped outputs, scratch folders, progress bars
``arrays.py``          per-column reductions of ``(N, 3)`` chunks, ten times numpy's per-axis ones
=====================  ====================================================================

Every verb gives the result of its in-memory definition (``clouds.ops.voxel_downsample``,
:func:`~.crop.crop_cloud`, :func:`~.tile.tile_cloud`, ...) exactly, for any chunk size, any
memory budget and any number of Dask workers. ``docs/streaming.md`` is the guide.
"""

from pointfield.streaming.chunks import StreamingFallback, open_source, read_chunks
from pointfield.streaming.crop import crop
from pointfield.streaming.downsample import downsample
from pointfield.streaming.merge import convert, convert_folder, merge
from pointfield.streaming.stats import stats
from pointfield.streaming.tile import tile
from pointfield.streaming.writers import open_writer

__all__ = [
    "StreamingFallback",
    "convert",
    "convert_folder",
    "crop",
    "downsample",
    "merge",
    "open_source",
    "open_writer",
    "read_chunks",
    "stats",
    "tile",
]
