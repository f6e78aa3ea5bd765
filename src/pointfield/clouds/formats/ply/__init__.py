"""PLY, the Stanford polygon format: point clouds and meshes, ascii and binary, read and write.

A PLY file is a short text header that declares *elements* (``vertex``, ``face``, ...) and their
*properties*, followed by the records of each element in the order they were declared::

    ply
    format binary_little_endian 1.0          (or ascii 1.0, binary_big_endian 1.0)
    comment any text
    obj_info any text
    element vertex 8
    property float x                         (scalar: <type> <name>)
    ...
    element face 6
    property list uchar int vertex_indices   (list: <count type> <item type> <name>)
    end_header
    <8 vertex records><6 face records>

In ascii files every record is one line of whitespace-separated numbers; in binary files records
are packed values of the declared types, a list being its count followed by its items. Type names
are ``char uchar short ushort int uint float double`` or their sized spellings ``int8 uint8 int16
uint16 int32 uint32 float32 float64``. Header lines may end in CRLF.

How a file maps onto pointfield objects:

- ``vertex`` -> ``points`` and ``fields`` through :func:`columns_to_cloud_parts` (``x y z`` become
  points; ``red green blue [alpha]`` become ``colors``; ``nx ny nz`` become ``normals``). Every
  value keeps the file's type (``float`` -> float32, ``double`` -> float64, ``uchar`` -> uint8),
  in native byte order. A list property with the same length K in every record becomes an
  ``(N, K)`` field; lists of varying length become an object array of arrays. A vertex element
  without ``x y z`` gives :class:`Records`.
- ``face`` with at least one record and a ``vertex_indices`` (or ``vertex_index``) list ->
  :class:`Mesh`: ``faces`` ``(F, K)`` in the file's integer type when every face has K corners,
  else an object array of index arrays; the face's other properties become ``face_fields``
  (grouped like vertex fields). ``element face 0`` gives a plain :class:`PointCloud`.
- Any other element -> ``metadata["ply_elements"][name]``, a dict of its columns (same shapes as
  above), written back on :func:`write_ply`.
- ``comment`` and ``obj_info`` lines -> ``metadata["comments"]`` / ``metadata["obj_info"]``, lists
  of str, written back. ``metadata["encoding"]`` is the file's format line.

Writing stores every field with its own dtype (ascii files declare types too, so dtypes round-trip
in all three encodings). Types PLY has no name for are converted when no value changes (bool ->
uchar, float16 -> float) and refused with a FormatError otherwise. PLY has no 64-bit integers:
int64 / uint64 fields are written as uint or int (the source's signedness first) when every
value fits in 32 bits, else as double when every value is exact in one (``|v| <= 2**53``), each with
a warning naming the field and the type it reads back as; larger values are refused. Faces'
vertex indices of any integer type are written as int without a warning. ``(N, K)`` fields other
than colours and normals are written as lists of K items. Ascii floats are written in the
shortest form that reads back to the same float32 / float64 value.

The package reads like the format: ``header`` (the header's grammar and types), ``reader`` (the
data section and how it maps onto pointfield objects), ``writer``, and ``chunks`` (the same,
a window of vertices at a time, for :mod:`pointfield.streaming`).
"""

from pointfield.clouds.formats.ply.chunks import PlyChunkWriter, open_ply_chunks, ply_chunk_writer
from pointfield.clouds.formats.ply.header import (
    ENCODINGS,
    SPLAT_PROPERTIES,
    is_ply,
    parse_header,
)
from pointfield.clouds.formats.ply.reader import read_ply
from pointfield.clouds.formats.ply.writer import write_ply
from pointfield.clouds.formats.registry import Format, register

__all__ = [
    "ENCODINGS",
    "SPLAT_PROPERTIES",
    "PlyChunkWriter",
    "is_ply",
    "open_ply_chunks",
    "parse_header",
    "read_ply",
    "write_ply",
]

register(
    Format(
        name="ply",
        description="Stanford PLY: point clouds and meshes, ascii or binary (little / big endian)",
        suffixes=(".ply",),
        read=read_ply,
        write=write_ply,
        encodings=ENCODINGS,
        aliases={"binary": "binary_little_endian", "ascii": "ascii"},
        signature=is_ply,
        holds_records=True,
        holds_faces=True,
        open_chunks=open_ply_chunks,
        chunk_writer=ply_chunk_writer,
    )
)
