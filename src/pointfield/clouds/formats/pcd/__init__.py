"""PCD, the Point Cloud Library's format: ``ascii``, ``binary`` and ``binary_compressed`` (LZF).

A PCD file is a text header, one keyword per line, then the data::

    # .PCD v0.7 - Point Cloud Data file format
    VERSION 0.7
    FIELDS x y z rgb
    SIZE 4 4 4 4
    TYPE F F F F
    COUNT 1 1 1 1
    WIDTH 640
    HEIGHT 480
    VIEWPOINT 0 0 0 1 0 0 0
    POINTS 307200
    DATA binary_compressed

``TYPE`` is ``I`` (signed), ``U`` (unsigned) or ``F`` (float) and ``SIZE`` its width in bytes:
I1 I2 I4 I8, U1 U2 U4 U8, F4 F8, and F2 (float16, which pointfield reads and writes although PCL
itself has no such type). ``COUNT`` is the number of components of a field (33 for FPFH).
Lines starting with ``#`` are comments. Old ``VERSION .5`` headers may leave out ``COUNT`` (1),
``WIDTH`` / ``HEIGHT`` (``POINTS`` x 1) and ``VIEWPOINT``; the oldest even ``SIZE`` and ``TYPE``
(F4), as PCL assumes. The data after the ``DATA`` line is

- ``ascii``: one line per point, the values separated by spaces (tabs and commas, which PDAL
  writes, are read too);
- ``binary``: the points one after another, each the fields' values packed in header order
  (little-endian, no alignment);
- ``binary_compressed``: uint32 compressed size, uint32 uncompressed size, then one LZF block
  that expands to the same values laid out column by column: every point's first field, then
  every point's second field, ...

How a file maps onto a :class:`PointCloud`:

- ``x y z`` (any case) become ``points`` in the file's precision (F4 -> float32, F8 -> float64);
  other fields keep their dtype, ``COUNT`` K > 1 gives an ``(N, K)`` field, and the
  ``normal_x normal_y normal_z`` triple becomes ``normals``. Fields named ``_`` are padding and
  are skipped.
- A packed colour field decodes to ``colors``: ``rgb`` (TYPE F or U, SIZE 4) to ``(N, 3)`` uint8
  and ``rgba`` to ``(N, 4)`` uint8. PCL packs the channels into one 32-bit word as
  ``0xAARRGGBB``, so the little-endian bytes on disk are B, G, R, A; a float ``rgb`` is that word's
  bits reinterpreted, never a numeric value. Separate ``red green blue [alpha]`` fields also
  become ``colors``, in their own dtype.
- ``HEIGHT > 1`` marks an organised cloud (PCL's ``isOrganized()``): ``shape`` is
  ``(HEIGHT, WIDTH)``, row-major, and invalid returns stay as NaN points so the grid survives. A
  ``WIDTH 1 x HEIGHT 1000`` file is therefore organised with shape ``(1000, 1)``; ``HEIGHT 1``
  reads as unorganised (``shape`` None), so a cloud of shape ``(1, W)`` comes back without one.
- A file without x/y/z (feature descriptors) reads as :class:`Records` of its fields.
- ``metadata``: ``encoding``, ``version`` (the header's VERSION, e.g. ``".5"``), ``viewpoint``
  (7 floats: tx ty tz qw qx qy qz, the sensor pose) and ``comments`` (header comments other than
  PCL's ``# .PCD`` banner). The writer writes ``viewpoint`` and ``comments`` back.

Writing: ``colors`` of dtype uint8 become one packed field (``rgb`` TYPE F for ``(N, 3)``, with
a zero alpha byte so the float is always a small finite number, as open3d writes it; ``rgba``
TYPE U for ``(N, 4)``); colours of any other dtype become ``red green blue [alpha]`` fields.
``normals`` become ``normal_x normal_y normal_z``. Every other ``(N,)`` or ``(N, K)`` numeric
field is written with its own dtype (bool as U1, read back as uint8). Fields PCD cannot hold
(more than 2 dimensions, non-numeric, names with spaces or ``_``) and a mesh's faces are left out
with a warning naming them. An ``(N, 1)`` field reads back as ``(N,)``: PCD has no way to tell
them apart.

Round trip: binary and binary_compressed give back every dtype and bit. ascii gives back the same
dtypes (the header carries them) and values: floats are printed in their shortest round-trip form
for their own precision, so every finite value, infinity and NaN survive, but NaN payload bits do
not. That is why the ascii writer stores packed colours as TYPE U integers, as PCL does (packed
float colours can be NaN patterns). When reading an ascii ``rgb`` of TYPE F, a column of whole
numbers in [0, 2**32) is taken as that integer word (PCL's own ascii output), anything else as a
float whose bits are the word.

Modules: ``header`` (the header's keywords, types and checks), ``reader``, ``writer``, and
``chunks`` (reading and writing a window of points at a time, for :mod:`pointfield.streaming`).
"""

from pointfield.clouds.formats.pcd.chunks import PcdChunkWriter, open_pcd_chunks, pcd_chunk_writer
from pointfield.clouds.formats.pcd.header import (
    ENCODINGS,
    MAX_HEADER_BYTES,
    looks_like_pcd,
    parse_header,
)
from pointfield.clouds.formats.pcd.reader import read_pcd
from pointfield.clouds.formats.pcd.writer import write_pcd
from pointfield.clouds.formats.registry import Format, register

__all__ = [
    "ENCODINGS",
    "MAX_HEADER_BYTES",
    "PcdChunkWriter",
    "looks_like_pcd",
    "open_pcd_chunks",
    "parse_header",
    "read_pcd",
    "write_pcd",
]

register(
    Format(
        name="pcd",
        description="Point Cloud Library PCD (ascii, binary, binary_compressed LZF)",
        suffixes=(".pcd",),
        read=read_pcd,
        write=write_pcd,
        encodings=ENCODINGS,
        aliases={"compressed": "binary_compressed"},
        signature=looks_like_pcd,
        holds_records=True,
        open_chunks=open_pcd_chunks,
        chunk_writer=pcd_chunk_writer,
    )
)
