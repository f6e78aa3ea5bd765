"""ASPRS LAS / LAZ / COPC lidar files, through laspy (LAZ through its lazrs or LASzip backend).

Reading
    ``points`` are the scaled coordinates ``x = X * scale + offset`` as float64 (UTM-sized
    coordinates do not survive float32). Every other dimension of the point format becomes a
    field under its laspy name and natural dtype: ``intensity`` uint16, bit fields such as
    ``return_number``, ``classification`` or ``synthetic`` as uint8, ``gps_time`` float64, extra
    bytes dimensions in their declared type (``(N, K)`` for K-element ones, float64 for scaled
    ones). ``red green blue`` become ``colors`` ``(N, 3)`` uint16; ``nir`` stays its own field.
    Extra dimensions ``nx ny nz`` become ``normals``, an extra ``alpha`` joins ``colors`` as
    ``(N, 4)``, and extra dimensions ``name[0] .. name[K-1]`` (how this writer stores ``(N, K)``
    fields with K > 3) become one ``(N, K)`` field ``name``.
    COPC files read as the LAZ files they are (``metadata["las_copc"]`` is True). Uncompressed
    files are memory-mapped and each dimension copied once into its own array, so reading holds
    the output arrays and little more.

Writing
    ``encoding`` is ``"las"`` or ``"laz"``; the registry picks ``"laz"`` for a ``.laz`` path. The point
    format is the one the cloud was read with (``metadata["las_point_format"]``) when it came
    from LAS, grown if new fields need more; otherwise the smallest standard format whose
    dimensions hold the cloud's LAS-named fields (``colors`` -> 2/3/7, ``gps_time`` -> 1/3/6/7,
    classification above 31 -> 6+, ...). Every other field becomes an extra bytes dimension of its
    own dtype: ``(N, 2)`` and ``(N, 3)`` fields as 2- and 3-element types, ``(N, K)`` uint8 as
    LAS's K-byte type, other wider ones as K scalar dimensions ``name[i]``, ``normals`` as
    ``nx ny nz``. Extra bytes have no bool, float16 or big-endian types: those come back as
    uint8, float32 and little-endian, with the same values.
    LAS quantises coordinates: ``X = round((x - offset) / scale)`` in int32. Scales and offsets
    come from the metadata of a LAS cloud; otherwise offset = the floored minimum corner and
    scale = 0.001 (a larger power of ten if the extent needs it), so a cloud from another format
    comes back within ``scale / 2`` of where it was, as float64. Points with NaN or infinite
    coordinates cannot be stored; they are dropped with a warning.
    Standard dimensions have fixed types. Values that fit are stored exactly and read back in the
    LAS type; colours of other dtypes are converted to uint16 (uint8 * 257, float in [0, 1] *
    65535), float ``intensity`` in [0, 1] is scaled by 65535, anything else that does not fit is
    rounded and clipped; NaN in an integer dimension is written as 0. Field names LAS cannot
    hold are changed: a well-known spelling of a standard dimension becomes it (E57's
    ``las:pointSourceId``, PDAL's ``PointSourceId`` or ``GpsTime`` -> ``point_source_id``,
    ``gps_time``), other names have ``:`` and non-ASCII characters replaced by ``_`` (numpy's
    buffers, through which laspy writes, refuse ``:``). One warning lists every such change.
    :class:`Records` (no x, y, z) are refused by the registry, as for NPZ. COPC is read, not
    written: a ``.copc.laz`` output is refused with a FormatError that says so (the octree
    ordering and hierarchy EVLR a COPC reader expects are not written); write ``.laz`` and convert
    it with PDAL's ``writers.copc`` or untwine.

Metadata (read, and used by the writer to write a LAS cloud back faithfully)
    ``scales``, ``offsets`` (3 floats each), ``las_version`` ("1.4"), ``las_point_format``
    (0..10), ``las_copc``, ``las_header`` (file_source_id, global_encoding, system_identifier,
    guid, creation_date, generating_software), ``las_extra_dimensions`` (name -> dtype, count,
    description, scales, offsets), and ``las_vlrs`` / ``las_evlrs``: every (extended) variable
    length record as ``{"user_id", "record_id", "description", "data": bytes}`` (CRS records
    included: GeoTIFF keys, WKT), except those the writer regenerates (LASzip, extra bytes) and
    the COPC index, which a re-written file no longer matches. The writer records itself as the
    generating software. Waveform data packets are not read.

LAZ backends: lazrs reads LAZ; where it fails, LASzip's own decompressor (PyPI ``laszip``) is
tried, and a file both refuse is one FormatError giving both reasons. Files of the LASzip 1.2r0
compressor (one pointwise stream whose LASzip record declares variable-size chunks) go to LASzip
directly: lazrs panics on them. The report Rust prints to standard error when lazrs panics is
kept off the terminal (``library.rust_panics_quiet``).

Hostile files: the header's sizes, counts, VLR and EVLR lengths and, for LAZ, the chunk table are
checked against the file's size before laspy, lazrs or LASzip allocate anything, and every laspy /
lazrs / LASzip failure (including lazrs panics) becomes a :class:`FormatError` naming the file.

Modules: ``layout`` (those checks), ``reader``, ``dimensions`` (which dimension each field is
written to), ``writer``, ``library`` (laspy's, lazrs's and LASzip's errors as FormatErrors), and
``chunks`` (reading, COPC queries and writing a window of points at a time, for
:mod:`pointfield.streaming`).
"""

from pointfield.clouds.formats.las.chunks import (
    CopcSource,
    LasChunkWriter,
    LasSource,
    las_chunk_writer,
    open_las_chunks,
)
from pointfield.clouds.formats.las.layout import is_las
from pointfield.clouds.formats.las.reader import read_las
from pointfield.clouds.formats.las.writer import coordinates_fit, refuse_copc_output, write_las
from pointfield.clouds.formats.registry import Format, register

__all__ = [
    "CopcSource",
    "LasChunkWriter",
    "LasSource",
    "coordinates_fit",
    "is_las",
    "open_las_chunks",
    "read_las",
    "write_las",
]

register(
    Format(
        name="las",
        description="ASPRS LAS / LAZ / COPC lidar (laspy + lazrs, LASzip for old LAZ)",
        suffixes=(".las", ".laz"),
        read=read_las,
        write=write_las,
        encodings=("las", "laz"),
        aliases={"binary": "las", "compressed": "laz"},
        signature=is_las,
        suffix_encodings={".laz": "laz"},
        open_chunks=open_las_chunks,
        chunk_options=("bounds", "level", "resolution"),
        chunk_writer=las_chunk_writer,
        check_output=refuse_copc_output,
    )
)
