"""The PCD header: its keywords, field types and counts, checked for consistency.

See the package docstring for the layout of a header and what old headers may leave out.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

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
TYPE_OF_KIND = {"i": "I", "u": "U", "f": "F"}

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
