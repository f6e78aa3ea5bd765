"""Clouds larger than memory, and larger than one machine: every verb a window of points at a time.

The pieces, in the order data flows through them:

=====================  ====================================================================
``chunks.py``          :func:`read_chunks` / :func:`open_source`: a file as windows of points
``readahead.py``       the next window read in a thread while this one is worked on
``writers.py``         :func:`open_writer`: a file written chunk by chunk, atomically
``spill.py``           chunks parked on disk between two passes (per tile, per voxel range)
``voxels.py``          the exact one-pass voxel accumulator, bounded by spilling key ranges
``downsampling.py``    ``downsample``: voxel (centroid, nearest), random, every
``cropping.py``        ``crop``: box or polygon
``tiling.py``          ``tile``: square tiles, with an optional buffer
``merging.py``         ``merge``, ``convert``, ``convert_folder``
``statistics.py``      ``stats``: bounds, counts per class, field ranges, in one pass
``select.py``          a per-chunk rule applied here or on Dask, written in order
``distributed.py``     where a job runs: here, or on a Dask cluster, by file or by piece and tile
``memory.py``          the ``--memory`` budget, shared between chunks and running state
``jobs.py``            a verb's job (inputs, budget, cluster), skipped outputs, scratch, progress
=====================  ====================================================================

How each format is read and written in windows is that format's business: its package registers
a chunk reader and writer beside its whole-file ones (:mod:`pointfield.clouds.formats.chunked`),
and ``chunks.py`` and ``writers.py`` ask the registry for them.

Every verb gives the result of its in-memory definition (``clouds.ops.voxel_downsample``,
:func:`~.cropping.crop_cloud`, :func:`~.tiling.tile_cloud`, ...) exactly, for any chunk size, any
memory budget and any number of Dask workers. ``docs/streaming.md`` is the guide.
"""

from pointfield.streaming.chunks import StreamingFallback, open_source, read_chunks
from pointfield.streaming.cropping import crop
from pointfield.streaming.downsampling import downsample
from pointfield.streaming.merging import convert, convert_folder, merge
from pointfield.streaming.statistics import stats
from pointfield.streaming.tiling import tile
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
