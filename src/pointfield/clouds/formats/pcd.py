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

- ``ascii``: one line per point, the values separated by spaces;
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
"""

from __future__ import annotations

import os
import re
import struct
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import lzf
import numpy as np

from pointfield.clouds.cloud import PointCloud, Records
from pointfield.clouds.formats.ascii import TableError, read_table, single_spaced, write_rows
from pointfield.clouds.formats.binary import check_size, map_file, read_records, record_dtype
from pointfield.clouds.formats.columns import PCD_NAMES, cloud_to_columns, columns_to_cloud_parts
from pointfield.clouds.formats.registry import Format, register
from pointfield.errors import FormatError

ENCODINGS = ("binary", "binary_compressed", "ascii")

# A header longer than this is not a header: real ones are a few hundred bytes.
MAX_HEADER_BYTES = 1 << 20
MAX_FIELDS = 10_000
MAX_POINT_BYTES = 1 << 30

# The largest LZF token, a 3-byte back-reference, expands to 264 bytes: a block of C compressed
# bytes can never produce more than 88 * C, so a bigger declared size is a lie.
LZF_MAX_EXPANSION = 88

# Identity pose: origin (0, 0, 0), quaternion (w, x, y, z) = (1, 0, 0, 0).
DEFAULT_VIEWPOINT = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)

BANNER = "# .PCD v0.7 - Point Cloud Data file format"

DTYPES: dict[tuple[str, int], np.dtype] = {
    ("I", 1): np.dtype("i1"),
    ("I", 2): np.dtype("<i2"),
    ("I", 4): np.dtype("<i4"),
    ("I", 8): np.dtype("<i8"),
    ("U", 1): np.dtype("u1"),
    ("U", 2): np.dtype("<u2"),
    ("U", 4): np.dtype("<u4"),
    ("U", 8): np.dtype("<u8"),
    ("F", 2): np.dtype("<f2"),
    ("F", 4): np.dtype("<f4"),
    ("F", 8): np.dtype("<f8"),
}
_TYPE_OF_KIND = {"i": "I", "u": "U", "f": "F"}

PACKED_COLOR_NAMES = ("rgb", "rgba")

HEADER_KEYWORDS = (
    "VERSION", "FIELDS", "COLUMNS", "SIZE", "TYPE", "COUNT",
    "WIDTH", "HEIGHT", "VIEWPOINT", "POINTS", "DATA",
)  # fmt: skip

_DIGITS = re.compile(r"[0-9]+")


@dataclass(frozen=True)
class PcdField:
    """One ``FIELDS`` entry: its TYPE letter, SIZE in bytes and COUNT of components."""

    name: str
    type: str
    size: int
    count: int

    @property
    def dtype(self) -> np.dtype:
        return DTYPES[self.type, self.size]

    @property
    def nbytes(self) -> int:
        """Bytes this field takes in one point."""
        return self.size * self.count

    @property
    def is_padding(self) -> bool:
        return self.name == "_"

    @property
    def is_packed_color(self) -> bool:
        """True for an ``rgb`` / ``rgba`` field that holds one 0xAARRGGBB word per point."""
        return (
            self.name.lower() in PACKED_COLOR_NAMES
            and self.size == 4
            and self.count == 1
            and self.type in "FU"
        )


@dataclass(frozen=True)
class PcdHeader:
    """Everything the header says, checked for consistency; ``data_offset`` is where data starts."""

    fields: tuple[PcdField, ...]
    width: int
    height: int
    points: int
    viewpoint: tuple[float, ...]
    encoding: str
    version: str | None
    comments: tuple[str, ...]
    data_offset: int

    @property
    def point_size(self) -> int:
        return sum(f.nbytes for f in self.fields)

    @property
    def packed_color(self) -> PcdField | None:
        """The field decoded to ``colors``: the first packed rgb / rgba field, if any.

        None when the file already has a field named ``colors``, which keeps its name.
        """
        if any(f.name == "colors" for f in self.fields):
            return None
        return next((f for f in self.fields if f.is_packed_color), None)


# ----------------------------------------------------------------------------------------------
# Reading


def looks_like_pcd(head: bytes) -> bool:
    """True when the first bytes are PCL's banner or a PCD header's first keyword.

    Comment lines are skipped; the first other line must start with VERSION, FIELDS or COLUMNS
    and a space, which no other point-cloud format's first line does.
    """
    if head.startswith(b"# .PCD"):
        return True
    for line in head.split(b"\n")[:-1]:
        line = line.strip()
        if not line or line.startswith(b"#"):
            continue
        return re.match(rb"(VERSION|FIELDS|COLUMNS)[ \t]", line) is not None
    return False


def read_pcd(path: Path) -> PointCloud | Records:
    """Read a PCD file: a :class:`PointCloud`, or :class:`Records` when it has no x/y/z.

    See the module docstring for how fields, colours, organised clouds and metadata map.
    Raises FormatError naming the file for anything malformed, truncated or inconsistent; every
    declared size is checked against the bytes the file really has before anything is allocated.
    """
    with open(path, "rb") as file:
        header = parse_header(file.read(MAX_HEADER_BYTES), path)
        available = os.fstat(file.fileno()).st_size - header.data_offset
        file.seek(header.data_offset)
        if header.encoding == "binary":
            columns = _read_binary(file, header, available, path)
        elif header.encoding == "binary_compressed":
            columns = _read_compressed(file, header, available, path)
        else:
            columns = _read_ascii(file.read(), header, path)
    return _assemble(columns, header, path)


def parse_header(head: bytes, path: Path) -> PcdHeader:
    """Parse and check the header at the start of ``head`` (the file's first bytes)."""
    values: dict[str, list[str]] = {}
    comments: list[str] = []
    position = 0
    line_number = 0
    while "DATA" not in values:
        if position >= len(head):
            if not head:
                raise FormatError(path, "file is empty; expected a PCD header")
            raise FormatError(path, "header has no DATA line (expected DATA ascii|binary|...)")
        end = head.find(b"\n", position)
        if end < 0:
            if len(head) >= MAX_HEADER_BYTES:
                raise FormatError(
                    path, f"no DATA line in the first {MAX_HEADER_BYTES} bytes; not a PCD header"
                )
            end = len(head)
        raw, position = head[position:end], end + 1
        line_number += 1
        try:
            line = raw.decode("utf-8").strip()
        except UnicodeDecodeError:
            raise FormatError(path, f"header line {line_number} is not UTF-8 text") from None
        if not line:
            continue
        if line.startswith("#"):
            comment = line[1:].strip()
            if not comment.startswith(".PCD"):
                comments.append(comment)
            continue
        keyword, *tokens = line.split()
        if keyword not in HEADER_KEYWORDS:
            raise FormatError(
                path,
                f"header line {line_number} starts with {keyword[:40]!r}; expected one of "
                f"{' '.join(HEADER_KEYWORDS)}",
            )
        if keyword == "COLUMNS":  # the pre-0.6 spelling of FIELDS
            keyword = "FIELDS"
        if keyword in values:
            raise FormatError(path, f"header has two {keyword} lines")
        values[keyword] = tokens
    return _check_header(values, comments, min(position, len(head)), path)


def _check_header(
    values: dict[str, list[str]], comments: list[str], data_offset: int, path: Path
) -> PcdHeader:
    names = values.get("FIELDS")
    if not names:
        raise FormatError(path, "header has no FIELDS line naming the fields")
    if len(names) > MAX_FIELDS:
        raise FormatError(path, f"header declares {len(names)} fields; at most {MAX_FIELDS}")
    n = len(names)

    def per_field(keyword: str, default: str) -> list[str]:
        tokens = values.get(keyword, [default] * n)
        if len(tokens) != n:
            raise FormatError(
                path, f"{keyword} has {len(tokens)} entries but FIELDS names {n} fields"
            )
        return tokens

    sizes = [_count(token, "SIZE", path) for token in per_field("SIZE", "4")]
    counts = [_count(token, "COUNT", path) for token in per_field("COUNT", "1")]
    types = [token.upper() for token in per_field("TYPE", "F")]
    fields = []
    for name, type_, size, count in zip(names, types, sizes, counts):
        if (type_, size) not in DTYPES:
            raise FormatError(
                path,
                f"field {name!r} has TYPE {type_[:8]!r} SIZE {size}; expected I or U with "
                f"SIZE 1, 2, 4 or 8, or F with SIZE 2, 4 or 8",
            )
        if count < 1:
            raise FormatError(path, f"field {name!r} has COUNT {count}; expected at least 1")
        fields.append(PcdField(name, type_, size, count))
    named = [f.name for f in fields if not f.is_padding]
    if len(set(named)) != len(named):
        twice = sorted({name for name in named if named.count(name) > 1})
        raise FormatError(path, f"field names appear twice: {' '.join(twice)}")
    if not named:
        raise FormatError(path, "every field is padding ('_'); nothing to read")
    point_size = sum(f.nbytes for f in fields)
    if point_size > MAX_POINT_BYTES:
        raise FormatError(
            path, f"one point would take {point_size} bytes; at most {MAX_POINT_BYTES}"
        )

    width = _single_count(values, "WIDTH", path)
    height = _single_count(values, "HEIGHT", path)
    points = _single_count(values, "POINTS", path)
    if points is None:
        if width is None:
            raise FormatError(path, "header has neither POINTS nor WIDTH; cannot count points")
        points = width * (1 if height is None else height)
    if not width and not height:  # absent or 0 in old files: an unorganised row of points
        width, height = points, 1
    elif height is None:
        height = 1
    elif width is None:
        raise FormatError(path, f"header gives HEIGHT {height} but no WIDTH")
    if width * height != points:
        raise FormatError(
            path, f"WIDTH {width} x HEIGHT {height} = {width * height} but POINTS says {points}"
        )

    viewpoint = DEFAULT_VIEWPOINT
    if "VIEWPOINT" in values:
        tokens = values["VIEWPOINT"]
        if len(tokens) != 7:
            raise FormatError(
                path, f"VIEWPOINT has {len(tokens)} numbers; expected 7 (tx ty tz qw qx qy qz)"
            )
        try:
            viewpoint = tuple(float(token) for token in tokens)
        except ValueError:
            raise FormatError(
                path, f"VIEWPOINT {' '.join(tokens)[:80]!r} is not 7 numbers"
            ) from None

    encoding_tokens = values["DATA"]
    encoding = encoding_tokens[0].lower() if len(encoding_tokens) == 1 else ""
    if encoding not in ENCODINGS:
        raise FormatError(
            path,
            f"DATA {' '.join(encoding_tokens)[:40]!r}; expected ascii, binary or binary_compressed",
        )
    version = values.get("VERSION")
    return PcdHeader(
        fields=tuple(fields),
        width=width,
        height=height,
        points=points,
        viewpoint=viewpoint,
        encoding=encoding,
        version=" ".join(version) if version else None,
        comments=tuple(comments),
        data_offset=data_offset,
    )


def _count(token: str, keyword: str, path: Path) -> int:
    if not _DIGITS.fullmatch(token):
        raise FormatError(path, f"{keyword} value {token[:40]!r} is not a non-negative integer")
    return int(token)


def _single_count(values: dict[str, list[str]], keyword: str, path: Path) -> int | None:
    if keyword not in values:
        return None
    tokens = values[keyword]
    if len(tokens) != 1:
        raise FormatError(path, f"{keyword} has {len(tokens)} values; expected one integer")
    return _count(tokens[0], keyword, path)


def _read_binary(
    file: BinaryIO, header: PcdHeader, available: int, path: Path
) -> dict[str, np.ndarray]:
    """Columns of ``DATA binary``: views into the points' records, mapped from the file."""
    check_size(path, "header", header.points, header.point_size, available, unit="points")
    fields, offsets = [], []
    offset = 0
    for f in header.fields:
        if not f.is_padding:
            if f.is_packed_color:  # the word's 4 bytes, B G R A, ready for decoding
                fields.append((f.name, np.dtype("u1"), (4,)))
            else:
                fields.append((f.name, f.dtype, () if f.count == 1 else (f.count,)))
            offsets.append(offset)
        offset += f.nbytes
    layout = record_dtype(fields, "<", offsets, header.point_size)
    records = read_records(map_file(file), layout, header.points, header.data_offset)
    return {name: records[name] for name, *_ in fields}


def _read_compressed(
    file: BinaryIO, header: PcdHeader, available: int, path: Path
) -> dict[str, np.ndarray]:
    """Columns of ``DATA binary_compressed``: views into the decompressed column-major buffer."""
    expected = header.points * header.point_size
    if available < 8:
        if expected == 0 and available == 0:
            return _columns_of(b"", header)
        raise FormatError(
            path, f"DATA binary_compressed needs an 8-byte size prefix; {available} bytes follow"
        )
    compressed_size, uncompressed_size = struct.unpack("<II", file.read(8))
    if uncompressed_size != expected:
        raise FormatError(
            path,
            f"binary_compressed block expands to {uncompressed_size} bytes but {header.points} "
            f"points x {header.point_size} bytes need {expected}",
        )
    if compressed_size > available - 8:
        raise FormatError(
            path,
            f"binary_compressed block claims {compressed_size} bytes but only {available - 8} "
            f"follow",
        )
    if expected == 0:
        return _columns_of(b"", header)
    if expected > LZF_MAX_EXPANSION * compressed_size:
        raise FormatError(
            path,
            f"{compressed_size} LZF bytes cannot expand to {expected} bytes (LZF expands at "
            f"most {LZF_MAX_EXPANSION}x)",
        )
    block = file.read(compressed_size)
    try:
        data = lzf.decompress(block, expected)
    except ValueError:
        raise FormatError(path, "binary_compressed block is corrupt (LZF error)") from None
    if data is None or len(data) != expected:
        got = "more than" if data is None else f"only {len(data)} of"
        raise FormatError(
            path, f"binary_compressed block expands to {got} the {expected} bytes it declares"
        )
    return _columns_of(data, header)


def _columns_of(data: bytes, header: PcdHeader) -> dict[str, np.ndarray]:
    """Read-only views of each field's column in a column-major buffer of ``header.points``."""
    n = header.points
    columns = {}
    offset = 0
    for f in header.fields:
        if not f.is_padding:
            if f.is_packed_color:
                column = np.frombuffer(data, np.uint8, 4 * n, offset).reshape(n, 4)
            else:
                column = np.frombuffer(data, f.dtype, n * f.count, offset)
                column = column if f.count == 1 else column.reshape(n, f.count)
            columns[f.name] = column
        offset += n * f.nbytes
    return columns


def _read_ascii(data: bytes, header: PcdHeader, path: Path) -> dict[str, np.ndarray]:
    """Columns of ``DATA ascii``, one line per point, values one space apart.

    Files with tabs, repeated or trailing spaces are made single-spaced and parsed again.
    ``nan``, ``inf`` and ``-inf`` are accepted for floats.
    """
    n = header.points
    values_per_point = sum(f.count for f in header.fields)
    if n == 0:
        return _columns_of(b"", header)
    # Each value takes at least one character and one separator (the last may lack its newline).
    if 2 * n * values_per_point - 1 > len(data):
        raise FormatError(
            path,
            f"DATA ascii has {len(data)} bytes, too few for {n} points of {values_per_point} "
            f"values",
        )
    column_types = [_text_dtype(f) for f in header.fields for _ in range(f.count)]
    try:
        parsed = read_table(data, column_types)
    except TableError:
        try:
            parsed = read_table(single_spaced(data), column_types)
        except TableError as error:
            raise FormatError(path, f"DATA ascii: {error}") from None
    rows = len(parsed[0]) if parsed else 0
    if rows != n:
        raise FormatError(path, f"DATA ascii has {rows} rows but POINTS says {n}")
    columns = {}
    index = 0
    for f in header.fields:
        first, index = index, index + f.count
        if f.is_padding:
            continue
        parts = parsed[first:index]
        if f.is_packed_color:
            columns[f.name] = _packed_word_from_text(parts[0], f).view(np.uint8).reshape(n, 4)
        elif f.count == 1:
            columns[f.name] = parts[0]
        else:
            columns[f.name] = np.stack(parts, axis=1)
    return columns


def _text_dtype(f: PcdField) -> np.dtype | None:
    """The dtype a field's text is parsed as; None leaves padding unparsed."""
    if f.is_padding:
        return None
    if f.is_packed_color:
        return np.dtype(np.uint32) if f.type == "U" else np.dtype(np.float64)
    return f.dtype


def _packed_word_from_text(values: np.ndarray, f: PcdField) -> np.ndarray:
    """The uint32 0xAARRGGBB words of an ascii packed-colour column (see the module docstring)."""
    if f.type == "U":
        return values.astype("<u4", copy=False)
    whole = (
        np.isfinite(values).all()
        and (values == np.floor(values)).all()
        and values.min() >= 0
        and values.max() < 2**32
    )
    if whole:
        return values.astype("<u4")
    return values.astype("<f4").view("<u4")


def _assemble(
    columns: dict[str, np.ndarray], header: PcdHeader, path: Path
) -> PointCloud | Records:
    """Turn raw file columns into a PointCloud (or Records) with canonical fields."""
    packed = header.packed_color
    if packed is not None:
        alpha = packed.name.lower() == "rgba"
        columns = dict(
            ("colors", _unpack_colors(values, alpha)) if name == packed.name else (name, values)
            for name, values in columns.items()
        )
    points, fields = columns_to_cloud_parts(columns, path)
    # Every array handed out is the caller's own: contiguous, writable, not a view of a buffer.
    fields = {
        name: values if values.flags.c_contiguous and values.flags.writeable else values.copy()
        for name, values in fields.items()
    }
    metadata = {"encoding": header.encoding}
    if header.version is not None:
        metadata["version"] = header.version
    metadata["viewpoint"] = header.viewpoint
    metadata["comments"] = list(header.comments)
    if points is None:
        return Records(fields, metadata)
    shape = (header.height, header.width) if header.height > 1 else None
    return PointCloud(points, fields, shape, metadata)


def _unpack_colors(words: np.ndarray, alpha: bool) -> np.ndarray:
    """``(N, 4)`` packed-word bytes B G R A -> uint8 colours R G B, or R G B A when ``alpha``."""
    colors = np.empty((len(words), 4 if alpha else 3), np.uint8)
    colors[:, :3] = words[:, 2::-1]
    if alpha:
        colors[:, 3] = words[:, 3]
    return colors


# ----------------------------------------------------------------------------------------------
# Writing


def write_pcd(path: Path, cloud: PointCloud | Records, encoding: str | None = None) -> None:
    """Write ``cloud`` (a PointCloud, Mesh vertices, or Records) as PCD in ``encoding``.

    ``encoding`` is ``binary`` (default), ``binary_compressed`` or ``ascii``. See the module
    docstring for how fields are spelled and which ones PCD cannot hold.
    """
    encoding = encoding or ENCODINGS[0]
    if encoding not in ENCODINGS:
        raise FormatError(path, f"PCD has no encoding {encoding!r}; expected one of {ENCODINGS}")
    columns = _columns_to_write(cloud, ascii_text=encoding == "ascii")
    if not columns:
        raise FormatError(path, "nothing to write: the records have no field PCD can hold")
    n = len(cloud)
    fields = [_field_for(name, values) for name, values in columns.items()]
    shape = getattr(cloud, "shape", None) or (1, n)
    viewpoint = _viewpoint_to_write(cloud.metadata.get("viewpoint"), path)
    comments = cloud.metadata.get("comments", ())
    comments = [comments] if isinstance(comments, str) else comments
    lines = [BANNER]
    lines += [f"# {line}" for comment in comments for line in str(comment).splitlines()]
    lines += [
        "VERSION 0.7",
        "FIELDS " + " ".join(f.name for f in fields),
        "SIZE " + " ".join(str(f.size) for f in fields),
        "TYPE " + " ".join(f.type for f in fields),
        "COUNT " + " ".join(str(f.count) for f in fields),
        f"WIDTH {shape[1]}",
        f"HEIGHT {shape[0]}",
        "VIEWPOINT " + " ".join(_number_text(v) for v in viewpoint),
        f"POINTS {n}",
        f"DATA {encoding}",
    ]
    with open(path, "wb") as file:
        file.write(("\n".join(lines) + "\n").encode("utf-8"))
        if encoding == "binary":
            _write_binary(file, columns, fields, n)
        elif encoding == "binary_compressed":
            _write_compressed(file, columns, fields, n, path)
        else:
            _write_ascii(file, columns)


def _columns_to_write(cloud: PointCloud | Records, ascii_text: bool) -> dict[str, np.ndarray]:
    """The file's columns in order, each ``(N,)`` or ``(N, K)`` little-endian numeric."""
    points = getattr(cloud, "points", None)
    columns = cloud_to_columns(points, {}, PCD_NAMES)
    skipped = []
    for name, values in cloud.fields.items():
        if name == "colors" and values.dtype == np.uint8 and values.shape[1:] in ((3,), (4,)):
            new = {"rgb" if values.shape[1] == 3 else "rgba": _pack_colors(values, ascii_text)}
        else:
            new = cloud_to_columns(None, {name: values}, PCD_NAMES)
        if columns.keys() & new.keys() or any(_unwritable(n, v) for n, v in new.items()):
            skipped.append(name)
            continue
        for column_name, column in new.items():
            if column.dtype == bool:
                warnings.warn(
                    f"PCD has no boolean type; field {name!r} is written as U1 (uint8)",
                    stacklevel=4,
                )
                column = column.view(np.uint8)
            columns[column_name] = column.astype(column.dtype.newbyteorder("<"), copy=False)
    if skipped:
        warnings.warn(
            f"PCD cannot hold field(s) {', '.join(map(repr, skipped))} (PCD fields are numeric, "
            f"(N,) or (N, K), with unique names without spaces); they were not written",
            stacklevel=4,
        )
    return columns


def _unwritable(name: str, values: np.ndarray) -> bool:
    if not name or name == "_" or any(c.isspace() for c in name):
        return True
    if values.ndim not in (1, 2) or (values.ndim == 2 and values.shape[1] == 0):
        return True
    pcd_type = (_TYPE_OF_KIND.get(values.dtype.kind), values.dtype.itemsize)
    return values.dtype != bool and pcd_type not in DTYPES


def _pack_colors(colors: np.ndarray, ascii_text: bool) -> np.ndarray:
    """uint8 ``(N, 3|4)`` colours as the 0xAARRGGBB word PCL packs: little-endian bytes B G R A.

    ``(N, 3)`` gives a float32 ``rgb`` whose alpha byte is 0 (so the float is finite); in ascii
    text it stays a uint32, whose integer value survives printing. ``(N, 4)`` gives a uint32.
    """
    words = np.zeros((len(colors), 4), np.uint8)
    words[:, :3] = colors[:, 2::-1]
    if colors.shape[1] == 4:
        words[:, 3] = colors[:, 3]
    words = words.view("<u4").reshape(-1)
    return words if ascii_text or colors.shape[1] == 4 else words.view("<f4")


def _field_for(name: str, values: np.ndarray) -> PcdField:
    return PcdField(
        name,
        _TYPE_OF_KIND[values.dtype.kind],
        values.dtype.itemsize,
        1 if values.ndim == 1 else values.shape[1],
    )


def _viewpoint_to_write(viewpoint: object, path: Path) -> tuple[float, ...]:
    if viewpoint is None:
        return DEFAULT_VIEWPOINT
    try:
        values = tuple(float(v) for v in viewpoint)  # type: ignore[attr-defined]
    except (TypeError, ValueError):
        values = ()
    if len(values) != 7:
        raise FormatError(
            path,
            f"metadata['viewpoint'] is {viewpoint!r}; expected 7 numbers tx ty tz qw qx qy qz",
        )
    return values


def _number_text(value: float) -> str:
    """Shortest text that reads back as the same float, without a needless ``.0``."""
    return repr(float(value)).removesuffix(".0")


def _write_binary(
    file: BinaryIO, columns: Mapping[str, np.ndarray], fields: list[PcdField], n: int
) -> None:
    """The points one after another, each its fields packed in order (np.dtype packs them)."""
    layout = record_dtype([(f.name, f.dtype, () if f.count == 1 else (f.count,)) for f in fields], "<")
    records = np.empty(n, layout)
    for f in fields:
        records[f.name] = columns[f.name]
    file.write(records.view(np.uint8))


def _write_compressed(
    file: BinaryIO, columns: Mapping[str, np.ndarray], fields: list[PcdField], n: int, path: Path
) -> None:
    """Size prefix, then one LZF block of the columns one after another (see the docstring)."""
    size = n * sum(f.nbytes for f in fields)
    if size >= 2**32:
        raise FormatError(
            path, f"binary_compressed holds at most 4 GiB of points; this cloud is {size} bytes"
        )
    if size == 0:
        file.write(struct.pack("<II", 0, 0))
        return
    buffer = np.empty(size, np.uint8)
    offset = 0
    for f in fields:
        column = np.ascontiguousarray(columns[f.name])
        buffer[offset : offset + column.nbytes] = column.reshape(-1).view(np.uint8)
        offset += column.nbytes
    buffer.flags.writeable = False  # python-lzf takes read-only buffers only
    # LZF's worst case adds one control byte per 32 literal bytes.
    compressed = lzf.compress(buffer, size + size // 32 + 16)
    if compressed is None:
        raise FormatError(path, "LZF could not compress the points into its worst-case bound")
    file.write(struct.pack("<II", len(compressed), size))
    file.write(compressed)


def _write_ascii(file: BinaryIO, columns: Mapping[str, np.ndarray]) -> None:
    """One line per point; floats in their shortest round-trip text for their own dtype."""
    components = [
        component
        for values in columns.values()
        for component in (values.T if values.ndim == 2 else [values])
    ]
    write_rows(file, components)


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
    )
)
