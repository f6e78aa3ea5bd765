"""XYZ, TXT, PTS and CSV: one point per line of numbers in a text file.

Reading. A file is a few optional preamble lines, then one row of numbers per point::

    7                                  <- Leica count line (PTS): the number of points
    # x y z red green blue             <- names: a '#' or '//' comment, or a bare header line
    1.5 2.0 -0.25 255 128 0
    ...

- Separators: runs of spaces or tabs, commas, or semicolons; the first row decides.
- Count line: a line holding one integer, before the rows, is the number of points. It is
  checked against the rows: fewer rows is a FormatError; of more rows, the declared number is
  read, as PDAL reads them, with a warning that says how many rows were left out (PDAL's own
  ``bunny_8.pts`` declares 8 points over 9 rows, and its tests read 8).
- Names: a bare first line of names (a CSV header), or a comment line whose names include x, y
  and z and are as many as the values in a row (CloudCompare's ``//X,Y,Z,R,G,B``, pointfield's
  ``# x y z red green blue``). Named columns are grouped by :func:`columns_to_cloud_parts`:
  ``red green blue [alpha]`` (or ``r g b [a]``) -> ``colors``, ``nx ny nz`` -> ``normals``; and
  ``name[0] name[1] ... name[K-1]`` -> one ``(N, K)`` field ``name``.
- Without names, the number of values in a row decides:

  ===  ==============================================================
  3    x y z
  4    x y z intensity
  6    x y z red green blue; x y z nx ny nz for ``.xyzn``, or when every row's last three
       values are a unit vector and some are negative (ModelNet's normal_resampled ``.txt``)
  7    ``.pts``: x y z intensity red green blue (Leica); else x y z red green blue alpha
  *    x y z field_3 field_4 ...
  ===  ==============================================================

- ``columns=`` names the columns instead (``"x,y,z,intensity,label"`` or a list of names).

Dtypes: text carries none. Every value reads as float64, points included, except colours
written as integers (no ``.`` or exponent in the first row's colour values): those read as uint8
when every colour is a whole number in 0..255, as uint16 in 0..65535. ``nan``, ``inf`` and
``-inf`` are values like any other (a cloud with NaN points round-trips).

Writing. ``.xyz``, ``.txt``, ``.xyzn``, ``.xyzrgb``: a ``# x y z ...`` names line, then the rows
separated by spaces; ``.csv``: a bare ``x,y,z,...`` header (what CSV tools expect) and commas.
``colors`` are written as ``red green blue [alpha]``, ``normals`` as ``nx ny nz``, an ``(N, K)``
field as ``name[0] ... name[K-1]``. ``.pts`` is written as Leica PTS: the count line, then
``x y z [intensity] [red green blue]``; other fields are left out with a warning. Floats are
printed as the shortest text that reads back as the same float64: a float32 value is printed as
its exact float64 value (``%.9g`` would give back the float32 but not ``float64(value)``), and
integers as integers. So reading back gives, for every column, ``float64(original)``; colours
that are whole numbers (uint8, or floats such as 255.0, which print as ``255``) come back as
uint8 / uint16.
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.formats.ascii import (
    TableError,
    read_table,
    rows_of_numbers,
    write_rows,
)
from pointfield.clouds.formats.columns import (
    cloud_to_columns,
    columns_to_cloud_parts,
    group_components,
)
from pointfield.clouds.formats.registry import Format, register
from pointfield.errors import FormatError

SUFFIXES = (".xyz", ".txt", ".pts", ".csv", ".xyzn", ".xyzrgb")

TEXT_NAMES = {"colors": ("red", "green", "blue", "alpha"), "normals": ("nx", "ny", "nz")}

# Lines before the first row of numbers: comments, a count line, a header. Real files have a few;
# a file with more is not a point file, and stopping early keeps garbage from being scanned.
MAX_PREAMBLE_LINES = 1000
# A row holds one point: a few dozen values. Longer lines are not rows, and splitting them in
# Python would be slow.
MAX_LINE_BYTES = 1 << 20
MAX_COLUMNS = 10_000

COLOR_COMPONENTS = frozenset(
    {"red", "green", "blue", "alpha", "r", "g", "b", "a"}
    | {f"diffuse_{c}" for c in ("red", "green", "blue", "alpha")}
)

_INTEGER = re.compile(rb"[+-]?[0-9]+")
_SEPARATORS = re.compile(r"[\s,;]+")
_BYTE_SEPARATORS = re.compile(rb"[\s,;]+")
# What the reader accepts as a column name (see _is_name_row).
_WRITABLE_NAME = re.compile(r"[A-Za-z_][^\s,;#\"]*")



@dataclass
class _Preamble:
    """What the lines before the first row of numbers say."""

    count: int | None = None
    header: str | None = None  # a bare line of names
    comments: list[str] = field(default_factory=list)  # comment lines, marker removed
    data_start: int = 0  # byte offset of the first row
    data_line: int = 1  # its line number, from 1
    first_row: list[bytes] | None = None  # its values as text; None when the file has no rows
    delimiter: str = " "


def read_text(path: Path, columns: str | Sequence[str] | None = None) -> PointCloud:
    """Read an XYZ / TXT / PTS / CSV file (see the module docstring for the layouts).

    ``columns`` names the columns, as ``"x,y,z,intensity"`` or a list of names, overriding the
    file's header and the layout guessed from the number of values per row.
    """
    data = path.read_bytes()
    preamble = _read_preamble(data, path)
    width = len(preamble.first_row) if preamble.first_row is not None else None
    names, guessed = _column_names(preamble, width, path, columns)
    if preamble.first_row is None:
        parsed = [np.zeros(0) for _ in names]
    else:
        parsed = _parse_rows(data, preamble, len(names), path)
    n = len(parsed[0])
    if preamble.count is not None:
        if n < preamble.count:
            raise FormatError(
                path, f"the count line says {preamble.count} points but only {n} row(s) follow"
            )
        if n > preamble.count:
            warnings.warn(
                f"{path}: the count line says {preamble.count} points but {n} rows follow; "
                f"the first {preamble.count} were read, as PDAL reads them",
                stacklevel=3,
            )
            parsed = [column[: preamble.count] for column in parsed]
    if guessed and names[3:] == ["red", "green", "blue"] and _are_normals(parsed[3:]):
        names[3:] = ["nx", "ny", "nz"]
    raw = dict(zip(names, parsed, strict=True))
    named = group_components(_with_color_dtype(raw, preamble, names))
    points, fields = columns_to_cloud_parts(named, path)
    if points is None:
        raise FormatError(
            path, f"the columns {names} name no x, y and z; name them with columns='x,y,z,...'"
        )
    fields = {name: np.ascontiguousarray(values) for name, values in fields.items()}
    return PointCloud(points, fields, None, {"encoding": "text"})


def _read_preamble(data: bytes, path: Path) -> _Preamble:
    """Walk the lines before the first row of numbers: count line, header, comments."""
    preamble = _Preamble()
    position = 3 if data.startswith(b"\xef\xbb\xbf") else 0  # a UTF-8 byte-order mark
    line_number = 0
    while position < len(data):
        end = data.find(b"\n", position)
        end = len(data) if end < 0 else end
        line = data[position:end].strip()
        line_number += 1
        if len(line) > MAX_LINE_BYTES:
            raise FormatError(path, f"line {line_number} is {len(line)} bytes long; not a row")
        if line_number > MAX_PREAMBLE_LINES:
            raise FormatError(path, f"no row of numbers in the first {MAX_PREAMBLE_LINES} lines")
        if line.startswith((b"#", b"//")):
            # Comments may be in any encoding; only one that names the columns matters.
            preamble.comments.append(line.lstrip(b"#/").decode("utf-8", "replace").strip())
        elif preamble.count is None and preamble.header is None and _INTEGER.fullmatch(line):
            preamble.count = int(line)
            if preamble.count < 0:
                raise FormatError(
                    path, f"line {line_number}: negative point count {preamble.count}"
                )
        elif line and _is_number_row(line):
            preamble.data_start, preamble.data_line = position, line_number
            preamble.delimiter = _delimiter_of(line)
            preamble.first_row = _split_row(line, preamble.delimiter)
            if len(preamble.first_row) > MAX_COLUMNS:
                raise FormatError(
                    path, f"line {line_number} holds {len(preamble.first_row)} values; not a row"
                )
            return preamble
        elif line and preamble.header is None and _is_name_row(line):
            preamble.header = _decode_header(line, line_number, path)
        elif line:
            raise FormatError(
                path, f"line {line_number}: expected a row of numbers, found {line[:60]!r}"
            )
        position = end + 1
    if preamble.count is None and preamble.header is None and not preamble.comments:
        raise FormatError(path, "empty file: no rows of numbers")
    return preamble


def _is_number_row(line: bytes) -> bool:
    try:
        [float(token) for token in _BYTE_SEPARATORS.split(line.rstrip(b",;"))]
    except ValueError:
        return False
    return True


def _is_name_row(line: bytes) -> bool:
    """A header names columns: every name starts with a letter or ``_``."""
    return all(
        token[:1].isalpha() or token[:1] == b"_" or token[:1] == b'"'
        for token in _BYTE_SEPARATORS.split(line)
    )


def _decode_header(line: bytes, line_number: int, path: Path) -> str:
    try:
        return line.decode("utf-8").strip()
    except UnicodeDecodeError:
        raise FormatError(path, f"line {line_number}: header is not UTF-8 text") from None


def _delimiter_of(row: bytes) -> str:
    for delimiter in (";", ",", "\t"):
        if delimiter.encode() in row:
            return delimiter
    return " "


def _split_row(row: bytes, delimiter: str) -> list[bytes]:
    if delimiter == " ":
        return row.split()
    # A delimiter closing every row ("1,2,3,") ends the row; it opens no empty column.
    separator = delimiter.encode()
    return [token.strip() for token in row.rstrip(separator).split(separator)]


def _split_names(text: str) -> list[str]:
    """Names separated as the line separates them, so comma-separated names may hold spaces."""
    delimiter = _delimiter_of(text.encode("utf-8"))
    parts = text.split() if delimiter == " " else text.split(delimiter)
    return [part.strip().strip('"').strip() for part in parts]


def _column_names(
    preamble: _Preamble, width: int | None, path: Path, columns: str | Sequence[str] | None
) -> tuple[list[str], bool]:
    """The name of each column: ``columns=``, else the header, else by the row width.

    The flag says whether the names were guessed from the row width.
    """
    if columns is not None:
        names = _SEPARATORS.split(columns.strip()) if isinstance(columns, str) else list(columns)
        _check_names(names, width, path, "columns=")
        return names, False
    if preamble.header is not None:
        names = _split_names(preamble.header)
        _check_names(names, width, path, "the header line")
        return names, False
    for comment in reversed(preamble.comments):
        names = _split_names(comment)
        lower = {name.lower() for name in names}
        if (
            {"x", "y", "z"} <= lower
            and len(lower) == len(names)
            and all(names)
            and (width is None or len(names) == width)
        ):
            return names, False
    if width is None:
        if preamble.count is None:
            raise FormatError(path, "no rows of numbers, and no line naming x y z columns")
        return ["x", "y", "z"], True
    if width < 3:
        raise FormatError(
            path,
            f"line {preamble.data_line}: rows have {width} value(s); a point needs x y z",
        )
    return _names_by_width(width, path.suffix.lower()), True


def _are_normals(columns: list[np.ndarray]) -> bool:
    """Whether three unnamed columns are unit normals rather than colours.

    True when every row is a unit vector (to 1e-3) and some component is negative, which no
    colour is: ModelNet's ``modelnet40_normal_resampled`` rows are ``x,y,z,nx,ny,nz``.
    """
    vectors = np.stack(columns, axis=1)
    if len(vectors) == 0 or not (vectors < 0).any():
        return False
    return bool(np.all(np.abs(np.linalg.norm(vectors, axis=1) - 1) < 1e-3))


def _check_names(names: list[str], width: int | None, path: Path, origin: str) -> None:
    if not all(isinstance(name, str) and name for name in names):
        raise FormatError(path, f"{origin} has an empty column name: {names}")
    if len(set(names)) != len(names):
        raise FormatError(path, f"{origin} names a column twice: {names}")
    if width is not None and len(names) != width:
        raise FormatError(
            path, f"{origin} names {len(names)} columns {names} but rows have {width} values"
        )


def _names_by_width(width: int, suffix: str) -> list[str]:
    xyz = ["x", "y", "z"]
    if width == 4:
        return [*xyz, "intensity"]
    if width == 6:
        return [*xyz, "nx", "ny", "nz"] if suffix == ".xyzn" else [*xyz, "red", "green", "blue"]
    if width == 7:
        if suffix == ".pts":
            return [*xyz, "intensity", "red", "green", "blue"]
        return [*xyz, "red", "green", "blue", "alpha"]
    return xyz + [f"field_{i}" for i in range(3, width)]


def _parse_rows(data: bytes, preamble: _Preamble, width: int, path: Path) -> list[np.ndarray]:
    """The rows' ``width`` columns, each ``(N,)`` float64.

    pyarrow's CSV reader is the fast path; it needs exactly one delimiter between values.
    Anything else (runs of spaces, tabs mixed with spaces, ``1, 2, 3``) goes to
    :func:`rows_of_numbers`, which also names the line of any error.
    """
    body = memoryview(data)[preamble.data_start :]
    try:
        return read_table(body, [np.dtype(np.float64)] * width, preamble.delimiter)
    except TableError:
        pass
    text = data[preamble.data_start :]
    if preamble.delimiter != " ":
        text = text.translate(_DELIMITERS_TO_SPACES)
    table, _ = rows_of_numbers(text, width, path, preamble.data_line)
    return list(table.T)


_DELIMITERS_TO_SPACES = bytes.maketrans(b",;", b"  ")


def _with_color_dtype(
    columns: dict[str, np.ndarray], preamble: _Preamble, names: list[str]
) -> dict[str, np.ndarray]:
    """Colour columns written as integers become uint8 (0..255) or uint16 (0..65535)."""
    colors = [name for name in names if name.lower() in COLOR_COMPONENTS]
    if not colors or preamble.first_row is None:
        return columns
    first = {name: preamble.first_row[i] for i, name in enumerate(names)}
    if any(re.search(rb"[.eEnNiI]", first[name]) for name in colors):
        return columns
    values = [columns[name] for name in colors]
    whole = all(np.array_equal(v, np.floor(v)) for v in values)  # False for NaN and inf
    if not whole:
        return columns
    low = min((v.min() for v in values if len(v)), default=0)
    high = max((v.max() for v in values if len(v)), default=0)
    if low < 0 or high > 65535:
        return columns
    dtype = np.uint8 if high <= 255 else np.uint16
    return {name: v.astype(dtype) if name in colors else v for name, v in columns.items()}


# ----------------------------------------------------------------------------------------------
# Writing


def write_text(path: Path, cloud: PointCloud, encoding: str | None = None) -> None:
    """Write ``cloud`` as XYZ / TXT / CSV with a names line, or as Leica PTS for ``.pts``."""
    if path.suffix.lower() == ".pts":
        _write_pts(path, cloud)
        return
    delimiter = "," if path.suffix.lower() == ".csv" else " "
    columns = _columns_to_write(cloud)
    header = delimiter.join(columns) if delimiter == "," else "# " + " ".join(columns)
    with open(path, "wb") as file:
        file.write((header + "\n").encode("utf-8"))
        write_rows(file, list(columns.values()), delimiter, floats_as=np.float64)


def _columns_to_write(cloud: PointCloud) -> dict[str, np.ndarray]:
    """``(N,)`` numeric columns named as the reader names them; unwritable fields warned about."""
    columns = cloud_to_columns(cloud.points, {}, TEXT_NAMES)
    skipped = []
    for name, values in cloud.fields.items():
        parts = cloud_to_columns(None, {name: values}, TEXT_NAMES)
        expanded: dict[str, np.ndarray] = {}
        for part_name, part in parts.items():
            if part.ndim == 2:
                expanded.update({f"{part_name}[{k}]": part[:, k] for k in range(part.shape[1])})
            else:
                expanded[part_name] = part
        taken = {n.lower() for n in columns} & {n.lower() for n in expanded}
        if taken or any(_unwritable(n, v) for n, v in expanded.items()):
            skipped.append(name)
            continue
        columns.update(expanded)
    if skipped:
        warnings.warn(
            f"text files cannot hold field(s) {', '.join(map(repr, skipped))} (numbers only, "
            f"(N,) or (N, K), unique names that start with a letter or '_' and hold no spaces, "
            f"commas, semicolons or '#'); they were not written",
            stacklevel=4,
        )
    return columns


def _unwritable(name: str, values: np.ndarray) -> bool:
    """Whether a column cannot be written so that the reader finds it again by its name."""
    if not _WRITABLE_NAME.fullmatch(name):
        return True
    return values.ndim != 1 or values.dtype.kind not in "biuf"


def _write_pts(path: Path, cloud: PointCloud) -> None:
    """Leica PTS: the count line, then x y z [intensity] [red green blue]."""
    columns = list(cloud.points.T)
    written = set()
    intensity = cloud.fields.get("intensity")
    if intensity is not None and intensity.ndim == 1 and intensity.dtype.kind in "biuf":
        columns.append(intensity)
        written.add("intensity")
    colors = cloud.fields.get("colors")
    if (
        colors is not None
        and colors.ndim == 2
        and colors.shape[1] in (3, 4)
        and colors.dtype.kind in "biuf"
    ):
        columns.extend(colors[:, :3].T)
        written.add("colors")
        if colors.shape[1] == 4:
            warnings.warn("PTS holds no alpha; the colours' alpha was not written", stacklevel=4)
    dropped = [name for name in cloud.fields if name not in written]
    if dropped:
        warnings.warn(
            f"PTS holds x y z, intensity and red green blue only; field(s) "
            f"{', '.join(map(repr, dropped))} were not written",
            stacklevel=4,
        )
    with open(path, "wb") as file:
        file.write(f"{len(cloud)}\n".encode())
        write_rows(file, columns, floats_as=np.float64)


register(
    Format(
        name="text",
        description="XYZ / TXT / CSV rows of numbers, Leica PTS (count line)",
        suffixes=SUFFIXES,
        read=read_text,
        write=write_text,
        encodings=("text",),
        aliases={"ascii": "text"},
        signature=None,
    )
)
