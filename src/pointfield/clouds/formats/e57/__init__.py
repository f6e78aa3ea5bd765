"""ASTM E57 scans through pye57 (an optional dependency: ``pip install 'pointfield[e57]'``).

Reading
    All scans of the file become one cloud. Each scan's pose (unit quaternion ``q = (w, x, y, z)``
    and translation ``t``) is applied, ``p_world = R(q) p_scan + t``, so every point is in the
    file's one frame; normals are rotated with it, ``n_world = R(q) n_scan``. A ``scan_index``
    field (uint8, uint16 or uint32 as the number of scans needs) says which scan each point came
    from. ``points`` are float64 whatever the file stores (single or double floats, scaled
    integers). Scans with spherical coordinates only are converted to cartesian,
    ``x = r cos(el) cos(az)``, ``y = r cos(el) sin(az)``, ``z = r sin(el)``; a scan with
    neither is an error. Points whose ``cartesianInvalidState`` (``sphericalInvalidState`` for
    converted scans) is not 0 have no valid position and become NaN rows; the state is kept.
    Fields: ``colorRed/Green/Blue`` -> ``colors`` ``(N, 3)``, ``nor:normalX/Y/Z`` (the libE57
    normals extension) -> ``normals`` ``(N, 3)``, ``intensity``; every other per-point element
    (``rowIndex``, ``columnIndex``, ``timeStamp``, ``returnIndex``, ``cartesianInvalidState``,
    the spherical coordinates, extension elements as ``prefix:name``) keeps its E57 name.
    dtypes: single floats -> float32, double floats and scaled integers -> float64, integers ->
    the smallest integer type that holds the element's declared minimum and maximum (colours
    0..255 -> uint8). Scans that lack a field another scan has get NaN (floats) or 0 there.
    2D images are not read.

Writing (encoding ``"e57"``)
    One scan per ``scan_index`` value 0..max (points grouped by it, in a stable order), or one
    scan without that field; no pose, since the points are already in one frame. Coordinates are
    written as double floats for float64 points, single for float32 (NaN rows stay NaN);
    ``colors`` as ``colorRed/Green/Blue`` (integers over their dtype's range, or floats),
    ``normals`` as ``nor:normalX/Y/Z``, E57's own per-point elements under their names, and every
    other field as an element of a ``pointfield`` extension. A small table in the file maps the
    elements back to field names, components and dtypes, so pointfield reads back exactly the
    fields it wrote (``(N, K)`` fields, RGBA colours, bool, uint64 within int64, float16,
    the organised shape) while other E57 readers still see the standard elements.

Hostile files: the physical header (signature, page size, lengths) is checked before libE57
opens the file, libE57 checks every page's CRC, and each scan's declared record count is
checked against the bits its records need before anything is allocated. Every pye57 / libE57
failure becomes a :class:`FormatError` naming the file.

Modules: ``layout`` (the physical header and record counts, checked before libE57 reads by
them), ``library`` (pye57 imported lazily, its failures as FormatErrors, the buffers it passes),
``elements`` (cloud fields <-> E57 elements, both ways, and pointfield's field table),
``reader``, ``writer``.
"""

from pointfield.clouds.formats.e57.layout import is_e57
from pointfield.clouds.formats.e57.reader import read_e57
from pointfield.clouds.formats.e57.writer import write_e57
from pointfield.clouds.formats.registry import Format, register

__all__ = ["is_e57", "read_e57", "write_e57"]

register(
    Format(
        name="e57",
        description="ASTM E57 3D imaging data (pye57, optional)",
        suffixes=(".e57",),
        read=read_e57,
        write=write_e57,
        encodings=("e57",),
        aliases={"binary": "e57"},
        signature=is_e57,
    )
)
