"""The PLY header: the elements and properties it declares, and the types it may name.

See the package docstring for the layout of a header. :func:`parse_header` checks every line and
raises a FormatError naming the line for anything but a well-formed header.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pointfield.errors import FormatError

SPLAT_PROPERTIES = ("f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
                    "rot_0", "rot_1", "rot_2", "rot_3")
"""The vertex properties every 3D Gaussian-splat ``.ply`` has (besides x y z and ``f_rest_*``):
what tells a splat file from a point cloud (the layout is in :mod:`pointfield.splats.ply`)."""

ENCODINGS = ("binary_little_endian", "ascii", "binary_big_endian")
BYTE_ORDERS = {"binary_little_endian": "<", "binary_big_endian": ">"}

# Every type name the PLY specification and its later sized spellings allow.
TYPES: dict[str, np.dtype] = {
    name: np.dtype(code)
    for names, code in (
        (("char", "int8"), "i1"),
        (("uchar", "uint8"), "u1"),
        (("short", "int16"), "i2"),
        (("ushort", "uint16"), "u2"),
        (("int", "int32"), "i4"),
        (("uint", "uint32"), "u4"),
        (("float", "float32"), "f4"),
        (("double", "float64"), "f8"),
    )
    for name in names
}
# The classic names, which every PLY reader knows, for writing.
TYPE_NAMES: dict[np.dtype, str] = {
    np.dtype(code): name
    for code, name in (
        ("i1", "char"),
        ("u1", "uchar"),
        ("i2", "short"),
        ("u2", "ushort"),
        ("i4", "int"),
        ("u4", "uint"),
        ("f4", "float"),
        ("f8", "double"),
    )
}

# A real header is a few hundred bytes; past this it is not a PLY header.
HEADER_LIMIT = 1 << 20


@dataclass(frozen=True)
class Property:
    """One declared property: a scalar of ``dtype``, or a list of ``dtype`` items whose length
    is stored as ``count_dtype``."""

    name: str
    dtype: np.dtype
    count_dtype: np.dtype | None = None

    @property
    def is_list(self) -> bool:
        return self.count_dtype is not None


@dataclass
class Element:
    """One declared element: ``count`` records of ``properties``."""

    name: str
    count: int
    properties: list[Property] = field(default_factory=list)


@dataclass
class Header:
    """What the header says, and where the data begins."""

    encoding: str
    elements: list[Element]
    comments: list[str]
    obj_info: list[str]
    data_offset: int
    data_line: int  # the line number of the first line after end_header, from 1


def is_ply(head: bytes) -> bool:
    """True when the first bytes of a file are a PLY magic line."""
    return head.startswith((b"ply\n", b"ply\r\n"))



def parse_header(path: Path, head: bytes) -> Header:
    """Parse the header at the start of ``head`` (the first bytes of the file, up to 1 MiB).

    Raises FormatError naming the line for anything but a well-formed header ending in
    ``end_header``.
    """
    if not head:
        raise FormatError(path, "file is empty; expected a PLY header starting with 'ply'")
    encoding: str | None = None
    elements: list[Element] = []
    comments: list[str] = []
    obj_info: list[str] = []
    position = 0
    line_number = 0
    while True:
        end = head.find(b"\n", position)
        if end < 0:
            if len(head) >= HEADER_LIMIT:
                raise FormatError(
                    path, f"no end_header line in the first {HEADER_LIMIT} bytes of the header"
                )
            raise FormatError(path, "file ends inside the header; expected an end_header line")
        raw, position = head[position:end], end + 1
        line_number += 1
        text = raw.decode("utf-8", errors="replace").rstrip("\r")
        words = text.split()
        where = f"header line {line_number}"
        if line_number == 1:
            if text.strip() != "ply":
                raise FormatError(
                    path, f"first line is {text[:40]!r}; a PLY file starts with 'ply'"
                )
            continue
        if not words:
            continue
        keyword = words[0]
        if keyword in ("comment", "obj_info"):
            rest = text.lstrip()[len(keyword) :]
            (comments if keyword == "comment" else obj_info).append(rest[1:] if rest else rest)
        elif keyword == "format":
            if encoding is not None:
                raise FormatError(path, f"{where}: a second format line")
            if len(words) != 3 or words[1] not in ENCODINGS:
                raise FormatError(
                    path,
                    f"{where}: {text[:80]!r}; expected 'format <encoding> 1.0' with an "
                    f"encoding in {list(ENCODINGS)}",
                )
            encoding = words[1]
        elif keyword == "element":
            elements.append(_parse_element(path, where, words))
        elif keyword == "property":
            if not elements:
                raise FormatError(path, f"{where}: property before any element line")
            _add_property(path, where, words, elements[-1])
        elif keyword == "end_header":
            break
        else:
            raise FormatError(
                path,
                f"{where}: unknown keyword {keyword[:40]!r}; expected format, comment, "
                "obj_info, element, property or end_header",
            )
    if encoding is None:
        raise FormatError(path, "header has no format line")
    _check_unique(path, "element", [element.name for element in elements])
    for element in elements:
        _check_unique(
            path, f"element {element.name!r} property", [p.name for p in element.properties]
        )
    return Header(encoding, elements, comments, obj_info, position, line_number + 1)


def _parse_element(path: Path, where: str, words: list[str]) -> Element:
    if len(words) != 3:
        raise FormatError(path, f"{where}: expected 'element <name> <count>', got {words[:5]}")
    name, count_text = words[1], words[2]
    try:
        count = int(count_text)
    except ValueError:
        raise FormatError(
            path, f"{where}: element count {count_text[:40]!r} is not an integer"
        ) from None
    if count < 0:
        raise FormatError(path, f"{where}: element {name!r} has a negative count {count}")
    return Element(name, count)


def _add_property(path: Path, where: str, words: list[str], element: Element) -> None:
    if len(words) == 5 and words[1] == "list":
        count_dtype, dtype, name = (
            _type(path, where, words[2]),
            _type(path, where, words[3]),
            words[4],
        )
        if count_dtype.kind not in "iu":
            raise FormatError(
                path, f"{where}: list count type {words[2]!r} must be an integer type"
            )
    elif len(words) == 3 and words[1] != "list":
        count_dtype, dtype, name = None, _type(path, where, words[1]), words[2]
    else:
        raise FormatError(
            path,
            f"{where}: expected 'property <type> <name>' or "
            f"'property list <count type> <item type> <name>', got {words[:6]}",
        )
    element.properties.append(Property(name, dtype, count_dtype))


def _check_unique(path: Path, kind: str, names: list[str]) -> None:
    seen: set[str] = set()
    for name in names:
        if name in seen:
            raise FormatError(path, f"{kind} {name!r} is declared twice")
        seen.add(name)


def _type(path: Path, where: str, name: str) -> np.dtype:
    try:
        return TYPES[name]
    except KeyError:
        raise FormatError(
            path, f"{where}: unknown type {name[:40]!r}; expected one of {sorted(TYPES)}"
        ) from None

