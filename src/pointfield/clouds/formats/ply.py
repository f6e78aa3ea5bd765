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
uchar, float16 -> float, int64 / uint64 -> int or uint when every value fits in 32 bits) and
refused with a FormatError otherwise. ``(N, K)`` fields other than colours and normals are written
as lists of K items. Ascii floats are written in the shortest form that reads back to the same
float32 / float64 value.
"""

from __future__ import annotations

import math
import os
import struct
import sys
import warnings
from array import array
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np

from pointfield.clouds.cloud import PointCloud, Records
from pointfield.clouds.formats.columns import PLY_NAMES, cloud_to_columns, columns_to_cloud_parts
from pointfield.clouds.formats.registry import Format, register
from pointfield.clouds.mesh import Mesh
from pointfield.errors import FormatError

ENCODINGS = ("binary_little_endian", "ascii", "binary_big_endian")
BYTE_ORDERS = {"binary_little_endian": "<", "binary_big_endian": ">"}
NATIVE_ORDER = "<" if sys.byteorder == "little" else ">"

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
# Ascii data is scanned for line ends with bytes.count in windows of up to this size (a
# per-byte array of the whole file would cost far more).
LINE_SCAN_CHUNK = 1 << 22
# Ascii elements of at least this many records are parsed by pyarrow, smaller ones by numpy:
# pyarrow's fixed cost per call and per column (about 0.1 ms) pays off only over many records.
PYARROW_MIN_RECORDS = 4096
# Ascii is written this many records at a time, bounding the memory of the formatted text.
TEXT_WRITE_BATCH = 1 << 18

FACE_INDEX_NAMES = ("vertex_indices", "vertex_index")


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


def is_ply(head: bytes) -> bool:
    """True when the first bytes of a file are a PLY magic line."""
    return head.startswith((b"ply\n", b"ply\r\n"))


# ---------------------------------------------------------------------------------------------
# Header


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
    return Header(encoding, elements, comments, obj_info, position)


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


# ---------------------------------------------------------------------------------------------
# Reading


def read_ply(path: Path) -> PointCloud | Mesh | Records:
    """Read a PLY file (any encoding) into a PointCloud, a Mesh (faces) or Records (no x y z).

    See the module docstring for how elements map onto fields. Peak memory for a binary file is
    about the file's data plus the returned arrays (the records are viewed in place, then copied
    once into their columns).
    """
    path = Path(path)
    with open(path, "rb") as file:
        header = parse_header(path, file.read(HEADER_LIMIT))
        size = os.fstat(file.fileno()).st_size
        data = bytearray(max(size - header.data_offset, 0))
        file.seek(header.data_offset)
        file.readinto(data)
    for element in header.elements:
        if element.count and not element.properties:
            raise FormatError(
                path, f"element {element.name!r} declares {element.count} records but no properties"
            )
    if header.encoding == "ascii":
        decoder: _TextData | _BinaryData = _TextData(path, data, header.elements)
    else:
        decoder = _BinaryData(path, data, BYTE_ORDERS[header.encoding])
    columns = {element.name: decoder.read(element) for element in header.elements}
    return _assemble(path, header, columns, np.frombuffer(data, np.uint8))


def _assemble(
    path: Path, header: Header, columns: dict[str, dict[str, np.ndarray]], buffer: np.ndarray
) -> PointCloud | Mesh | Records:
    """Turn decoded element columns into a PointCloud, Mesh or Records (module docstring)."""
    elements = {element.name: element for element in header.elements}
    if "vertex" not in elements:
        raise FormatError(
            path, "no 'vertex' element; a PLY cloud or mesh declares 'element vertex N'"
        )
    for prop in elements["vertex"].properties:
        if prop.name.lower() in ("x", "y", "z") and prop.is_list:
            raise FormatError(
                path, f"vertex property {prop.name!r} is a list; coordinates are scalars"
            )
    points, fields = columns_to_cloud_parts(columns.pop("vertex"), path)

    faces, face_fields = None, {}
    face_index = _face_index_property(elements.get("face"))
    if points is not None and face_index is not None:
        face_columns = columns.pop("face")
        if elements["face"].count:
            indices = face_columns.pop(face_index.name)
            faces = _check_faces(path, face_index, indices, len(points))
            face_fields = _face_fields(path, face_columns)

    # Copy out every array that still views the file's bytes, so that they can be freed.
    def owned(values: np.ndarray) -> np.ndarray:
        if values.dtype != object and (
            not values.flags.writeable or np.may_share_memory(values, buffer)
        ):
            return values.copy()
        return values

    fields = {name: owned(values) for name, values in fields.items()}
    metadata: dict[str, Any] = {"encoding": header.encoding}
    if header.comments:
        metadata["comments"] = header.comments
    if header.obj_info:
        metadata["obj_info"] = header.obj_info
    if columns:
        metadata["ply_elements"] = {
            name: {prop: owned(values) for prop, values in element_columns.items()}
            for name, element_columns in columns.items()
        }
    if points is None:
        return Records(fields, metadata)
    if faces is None:
        return PointCloud(points, fields, None, metadata)
    face_fields = {name: owned(values) for name, values in face_fields.items()}
    return Mesh(points, fields, None, metadata, owned(faces), face_fields)


def _face_index_property(face: Element | None) -> Property | None:
    """The face element's list of vertex indices, if it has one."""
    if face is None:
        return None
    return next((p for p in face.properties if p.name in FACE_INDEX_NAMES and p.is_list), None)


def _check_faces(path: Path, prop: Property, faces: np.ndarray, vertex_count: int) -> np.ndarray:
    if prop.dtype.kind not in "iu":
        raise FormatError(
            path, f"face property {prop.name!r} holds {prop.dtype}; expected integers"
        )
    flat = np.concatenate(list(faces)) if faces.dtype == object and len(faces) else faces
    if flat.size and (flat.min() < 0 or flat.max() >= vertex_count):
        raise FormatError(
            path,
            f"face {prop.name} hold indices from {flat.min()} to {flat.max()}, but the "
            f"vertex element has {vertex_count} vertices (valid indices 0..{vertex_count - 1})",
        )
    return faces


def _face_fields(path: Path, columns: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Per-face properties grouped like vertex fields; ``x y z`` on faces (rare) stay as named
    fields rather than being taken for coordinates."""
    coordinates = {
        name: values for name, values in columns.items() if name.lower() in ("x", "y", "z")
    }
    _, grouped = columns_to_cloud_parts(
        {name: values for name, values in columns.items() if name not in coordinates}, path
    )
    return {**grouped, **coordinates}


def _empty_columns(element: Element) -> dict[str, np.ndarray]:
    return {
        prop.name: np.empty((0, 0) if prop.is_list else (0,), prop.dtype)
        for prop in element.properties
    }


class _BinaryData:
    """Decodes the binary data section one element after another.

    Elements without lists, and elements whose lists all have the length of the first record's
    (triangle meshes), are a packed structured array: viewed in place with ``np.frombuffer``.
    Lists of varying length are walked record by record to find where each value lies, then
    gathered with vectorised indexing.
    """

    def __init__(self, path: Path, data: bytearray, byte_order: str):
        self.path = path
        self.data = data
        self.bytes = np.frombuffer(data, np.uint8)
        self.byte_order = byte_order
        self.position = 0

    def read(self, element: Element) -> dict[str, np.ndarray]:
        if element.count == 0:
            return _empty_columns(element)
        remaining = len(self.data) - self.position
        smallest = sum(
            p.dtype.itemsize if p.count_dtype is None else p.count_dtype.itemsize
            for p in element.properties
        )
        if element.count * smallest > remaining:
            raise FormatError(
                self.path,
                f"element {element.name!r} declares {element.count} records of at "
                f"least {smallest} bytes, but only {remaining} bytes of data remain",
            )
        if not any(p.is_list for p in element.properties):
            return self._read_packed(element, {})
        first_record, _ = self._walk(element, 1)
        lengths = {
            prop.name: int(counts[0])
            for prop, (_, counts) in zip(element.properties, first_record, strict=True)
            if prop.is_list
        }
        columns = self._read_packed(element, lengths)
        return columns if columns is not None else self._read_ragged(element)

    def _read_packed(
        self, element: Element, lengths: dict[str, int]
    ) -> dict[str, np.ndarray] | None:
        """View the records as a structured array whose lists have ``lengths``; None when the
        data disagrees with those lengths (or is too short for them)."""
        order = self.byte_order
        layout: list[tuple[Any, ...]] = []
        for prop in element.properties:
            if prop.count_dtype is None:
                layout.append((prop.name, prop.dtype.newbyteorder(order)))
            else:
                layout.append((f"{prop.name} length", prop.count_dtype.newbyteorder(order)))
                layout.append((prop.name, prop.dtype.newbyteorder(order), (lengths[prop.name],)))
        dtype = np.dtype(layout)
        if element.count * dtype.itemsize > len(self.data) - self.position:
            return None
        records = np.frombuffer(self.data, dtype, count=element.count, offset=self.position)
        for name, length in lengths.items():
            if not np.all(records[f"{name} length"] == length):
                return None
        if self.byte_order != NATIVE_ORDER:
            # In place, so the file's bytes are the only copy (dtype.isnative cannot tell: it
            # does not look inside list fields).
            records.byteswap(inplace=True)
        records = records.view(dtype.newbyteorder("="))
        self.position += element.count * dtype.itemsize
        return {prop.name: records[prop.name] for prop in element.properties}

    def _read_ragged(self, element: Element) -> dict[str, np.ndarray]:
        located, self.position = self._walk(element, element.count)
        columns = {}
        for prop, (positions, counts) in zip(element.properties, located, strict=True):
            dtype = prop.dtype.newbyteorder(self.byte_order)
            if prop.is_list:
                item_positions = _item_positions(positions, counts, prop.dtype.itemsize)
                columns[prop.name] = _split_lists(self._gather(item_positions, dtype), counts)
            else:
                columns[prop.name] = self._gather(positions, dtype)
        return columns

    def _walk(
        self, element: Element, count: int
    ) -> tuple[list[tuple[np.ndarray, np.ndarray]], int]:
        readers: list[Callable[[int], int] | None] = []
        sizes = []
        for prop in element.properties:
            if prop.count_dtype is None:
                readers.append(None)
                sizes.append((0, prop.dtype.itemsize))
                continue
            if prop.count_dtype == np.uint8:
                readers.append(self.data.__getitem__)
            else:
                unpack = struct.Struct(self.byte_order + prop.count_dtype.char).unpack_from
                readers.append(lambda at, unpack=unpack: unpack(self.data, at)[0])
            sizes.append((prop.count_dtype.itemsize, prop.dtype.itemsize))
        return _walk_records(
            self.path, element, count, self.position, len(self.data), sizes, readers
        )

    def _gather(self, positions: np.ndarray, dtype: np.dtype) -> np.ndarray:
        """Values of ``dtype`` starting at the byte ``positions``, in native byte order."""
        size = dtype.itemsize
        raw = (
            self.bytes[positions[:, None] + np.arange(size)] if size > 1 else self.bytes[positions]
        )
        values = np.ascontiguousarray(raw).view(dtype).reshape(len(positions))
        return values.astype(dtype.newbyteorder("="))


class _TextData:
    """Decodes the ascii data section one element after another, one record per line.

    Each element's lines are located first (counting newlines in large chunks), so a declared
    count is checked against the lines really present before anything is allocated. Large
    elements whose lines share one shape are parsed by pyarrow's CSV reader; everything else
    (small elements, tabs, repeated spaces, lists of varying length) by numpy's whitespace
    tokenizer and a record walk.
    """

    def __init__(self, path: Path, data: bytearray, elements: list[Element]):
        self.path = path
        self.data = data
        self.position = 0
        self.last_with_records = next((e for e in reversed(elements) if e.count), None)

    def read(self, element: Element) -> dict[str, np.ndarray]:
        if element.count == 0:
            return _empty_columns(element)
        start = self.position
        use_pyarrow = element.count >= PYARROW_MIN_RECORDS
        if use_pyarrow and element is self.last_with_records:
            # The last element runs to the end of the data, so pyarrow can take the rest whole,
            # its row count standing in for the line count (its memory follows the data's size,
            # not the declared count). Lines after the records send it the long way round.
            columns = _parse_text_uniform(self.data, start, len(self.data), element)
            if columns is not None:
                self.position = len(self.data)
                return columns
        end = self._end_of_lines(element)
        self.position = end
        columns = _parse_text_uniform(self.data, start, end, element) if use_pyarrow else None
        if columns is None:
            columns = self._parse_text_tokens(start, end, element)
        return columns

    def _end_of_lines(self, element: Element) -> int:
        """Offset just past the element's ``count`` lines starting at the current position."""
        data, needed = self.data, element.count
        position, size = self.position, len(data)
        # Windows start near the element's likely size and double, so a small element costs
        # little and a large one is counted in big strides.
        window = max(4096, min(needed * 16, LINE_SCAN_CHUNK))
        while position < size:
            stop = min(position + window, size)
            found = data.count(b"\n", position, stop)
            if found >= needed:
                return _nth_line_end(data, position, stop, needed)
            needed -= found
            position = stop
            window = min(window * 2, LINE_SCAN_CHUNK)
        # A last line without a newline still counts when it holds something.
        last_line_start = max(data.rfind(b"\n", self.position) + 1, self.position)
        if needed == 1 and data[last_line_start:].strip():
            return size
        raise FormatError(
            self.path,
            f"element {element.name!r} declares {element.count} records (one per line) "
            f"but only {element.count - needed} lines of data follow",
        )

    def _parse_text_tokens(self, start: int, end: int, element: Element) -> dict[str, np.ndarray]:
        """The general, slower parse: every number of the block, then a walk over the records."""
        text = bytes(self.data[start:end])
        with warnings.catch_warnings():
            # numpy stops at the first token that is not a number and only warns; make it fail.
            warnings.simplefilter("error", DeprecationWarning)
            try:
                # (numpy reads whitespace alone as [-1.0], hence the test.)
                values = np.fromstring(text, sep=" ") if not text.isspace() else np.zeros(0)
            except (DeprecationWarning, ValueError):
                raise FormatError(
                    self.path, f"element {element.name!r} holds a value that is not a number"
                ) from None
        if not any(p.is_list for p in element.properties):
            width = len(element.properties)
            if values.size != element.count * width:
                raise FormatError(
                    self.path,
                    f"element {element.name!r} should have {width} values on each of "
                    f"its {element.count} lines, but its lines hold {values.size} values",
                )
            table = values.reshape(element.count, width)
            return {
                prop.name: self._cast(table[:, i], element, prop)
                for i, prop in enumerate(element.properties)
            }
        numbers = values.tolist()

        def read_count(at: int) -> int:
            length = numbers[at]
            if not (math.isfinite(length) and length == int(length)):
                raise FormatError(
                    self.path,
                    f"element {element.name!r} has a list length {length!r} that is not an integer",
                )
            return int(length)

        sizes = [((1 if p.is_list else 0), 1) for p in element.properties]
        readers = [read_count if p.is_list else None for p in element.properties]
        located, consumed = _walk_records(
            self.path, element, element.count, 0, values.size, sizes, readers
        )
        if consumed != values.size:
            raise FormatError(
                self.path,
                f"element {element.name!r}: its lines hold {values.size} values but its "
                f"declared properties account for {consumed}",
            )
        columns = {}
        for prop, (positions, counts) in zip(element.properties, located, strict=True):
            if prop.is_list:
                items = self._cast(values[_item_positions(positions, counts, 1)], element, prop)
                columns[prop.name] = _split_lists(items, counts)
            else:
                columns[prop.name] = self._cast(values[positions], element, prop)
        return columns

    def _cast(self, values: np.ndarray, element: Element, prop: Property) -> np.ndarray:
        """Parsed float64 values as the property's type, refusing values the type cannot hold."""
        if prop.dtype.kind == "f":
            with np.errstate(over="ignore"):  # beyond float32's range reads as inf, as strtof does
                return values.astype(prop.dtype)
        info = np.iinfo(prop.dtype)
        fits = (values == np.floor(values)) & (values >= info.min) & (values <= info.max)
        if not fits.all():
            bad = values[~fits][0]
            raise FormatError(
                self.path,
                f"element {element.name!r} property {prop.name!r}: {bad!r} is not a "
                f"{TYPE_NAMES[prop.dtype]} value",
            )
        return values.astype(prop.dtype)


def _nth_line_end(data: bytearray, low: int, high: int, needed: int) -> int:
    """Offset just past the ``needed``-th newline in ``data[low:high]``, which holds at least
    that many: bisection while the span is long, then a step per line."""
    while high - low > 256:
        middle = (low + high) // 2
        found = data.count(b"\n", low, middle)
        if found >= needed:
            high = middle
        else:
            needed -= found
            low = middle
    end = low
    for _ in range(needed):
        end = data.index(b"\n", end) + 1
    return end


def _parse_text_uniform(
    data: bytearray, start: int, end: int, element: Element
) -> dict[str, np.ndarray] | None:
    """Parse lines of one shape (single spaces, the same list lengths as the first line, an
    optional trailing space) with pyarrow's CSV reader; None when the block is not like that."""
    # pyarrow is imported on first use so that `import pointfield` stays quick.
    import pyarrow as pa
    import pyarrow.csv as pa_csv

    first_end = data.find(b"\n", start, end)
    first_line = bytes(data[start : end if first_end < 0 else first_end]).rstrip(b"\r")
    tokens = first_line.split(b" ")
    trailing_space = len(tokens) > 1 and tokens[-1] == b""
    if trailing_space:
        tokens.pop()
    if b"" in tokens or b"\t" in first_line:
        return None
    column_types: list[np.dtype] = []
    lengths: dict[str, int] = {}
    for prop in element.properties:
        if prop.count_dtype is not None:
            at = len(column_types)
            try:
                length = int(tokens[at]) if at < len(tokens) else -1
            except ValueError:
                return None
            if not 0 <= length < len(tokens):
                return None
            lengths[prop.name] = length
            column_types += [prop.count_dtype] + [prop.dtype] * length
        else:
            column_types.append(prop.dtype)
    if len(column_types) != len(tokens):
        return None
    names = [str(i) for i in range(len(column_types))]
    try:
        table = pa_csv.read_csv(
            pa.py_buffer(memoryview(data)[start:end]),
            read_options=pa_csv.ReadOptions(
                column_names=names + (["trailing"] if trailing_space else [])
            ),
            parse_options=pa_csv.ParseOptions(delimiter=" ", quote_char=False, double_quote=False),
            convert_options=pa_csv.ConvertOptions(
                column_types={
                    n: pa.from_numpy_dtype(t) for n, t in zip(names, column_types, strict=True)
                },
                include_columns=names,
                null_values=[],
                strings_can_be_null=False,
            ),
        )
    except pa.ArrowException:
        return None
    if table.num_rows != element.count:
        return None
    arrays = [column.to_numpy() for column in table.columns]
    columns: dict[str, np.ndarray] = {}
    at = 0
    for prop in element.properties:
        if prop.is_list:
            length = lengths[prop.name]
            if not np.all(arrays[at] == length):
                return None
            items = arrays[at + 1 : at + 1 + length]
            columns[prop.name] = (
                np.stack(items, axis=1) if items else np.empty((element.count, 0), prop.dtype)
            )
            at += 1 + length
        else:
            columns[prop.name] = arrays[at]
            at += 1
    return columns


def _walk_records(
    path: Path,
    element: Element,
    count: int,
    start: int,
    end: int,
    sizes: list[tuple[int, int]],
    read_counts: list[Callable[[int], int] | None],
) -> tuple[list[tuple[np.ndarray, np.ndarray]], int]:
    """Where every value of the first ``count`` records lies, for lists of varying length.

    Positions are in units of the data (bytes for binary, numbers for ascii); ``sizes`` gives
    per property ``(count size, item size)`` (count size 0 for scalars) and ``read_counts`` a
    function reading a list length at a position (None for scalars). A record's start depends
    on the lengths of the lists before it, so this is a loop over records, one step per list;
    it stops with a FormatError at the first record that would run past ``end``. Scalars
    between lists are then placed with vectorised arithmetic.

    Returns, per property, ``(positions, counts)`` — for scalars the position of each value and
    an empty ``counts``; for lists the position of each first item and each list's length — and
    the position just past the last record.
    """
    # A record is a run of scalars, a list, a run of scalars, a list, ..., a run of scalars.
    steps = []  # per list: (size of the scalars before it, count size, item size, reader, index)
    run = 0
    for index, (count_size, item_size) in enumerate(sizes):
        read_count = read_counts[index]
        if read_count is None:
            run += item_size
        else:
            steps.append((run, count_size, item_size, read_count, index))
            run = 0
    trailing_run = run

    def past_end(record: int) -> FormatError:
        return FormatError(
            path,
            f"element {element.name!r} record {record} runs past the end of the data "
            f"(declared {element.count} records: the data is truncated or a list length is wrong)",
        )

    record_starts = array("q")
    item_starts = [array("q") for _ in steps]
    lengths = [array("q") for _ in steps]
    plan = list(zip(steps, item_starts, lengths, strict=True))
    at = start
    for record in range(count):
        record_starts.append(at)
        for (before, count_size, item_size, read_count, index), firsts, sizes_of in plan:
            at += before
            if at + count_size > end:
                raise past_end(record)
            length = read_count(at)
            if length < 0:
                raise FormatError(
                    path,
                    f"element {element.name!r} record {record}: list "
                    f"{element.properties[index].name!r} has a negative length {length}",
                )
            at += count_size
            if length * item_size > end - at:
                raise past_end(record)
            firsts.append(at)
            sizes_of.append(length)
            at += length * item_size
        at += trailing_run
        if at > end:
            raise past_end(record)

    def as_array(values: array) -> np.ndarray:
        return np.frombuffer(values, np.int64) if len(values) else np.zeros(0, np.int64)

    located = []
    anchor = as_array(record_starts)  # where the current run of scalars begins
    offset = 0
    step_of = {step[4]: j for j, step in enumerate(steps)}
    for index, (_, item_size) in enumerate(sizes):
        if index in step_of:
            j = step_of[index]
            firsts, list_lengths = as_array(item_starts[j]), as_array(lengths[j])
            located.append((firsts, list_lengths))
            anchor, offset = firsts + list_lengths * item_size, 0
        else:
            located.append((anchor + offset, np.zeros(0, np.int64)))
            offset += item_size
    return located, at


def _item_positions(first: np.ndarray, lengths: np.ndarray, step: int) -> np.ndarray:
    """Positions of every list item, flat: record i contributes ``first[i] + step * j`` for
    ``j < lengths[i]``."""
    total = int(lengths.sum())
    record_of_item = np.repeat(np.arange(len(lengths)), lengths)
    index_in_list = np.arange(total) - np.repeat(np.cumsum(lengths) - lengths, lengths)
    return first[record_of_item] + step * index_in_list


def _split_lists(items: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """``(n, K)`` when every list has length K, else a 1-D object array of item arrays."""
    if len(lengths) == 0 or np.all(lengths == lengths[0]):
        return items.reshape(len(lengths), int(lengths[0]) if len(lengths) else 0)
    ragged = np.empty(len(lengths), object)
    ends = np.cumsum(lengths)
    for i, (first, end) in enumerate(zip((ends - lengths).tolist(), ends.tolist(), strict=True)):
        ragged[i] = items[first:end]
    return ragged


# ---------------------------------------------------------------------------------------------
# Writing


@dataclass
class _Column:
    """One property ready to write: ``values`` is ``(n,)`` for a scalar, ``(n, K)`` for lists of
    one length, or the flat items of lists whose lengths are ``lengths`` (n,)."""

    name: str
    values: np.ndarray
    lengths: np.ndarray | None = None

    @property
    def is_list(self) -> bool:
        return self.values.ndim == 2 or self.lengths is not None

    def list_lengths(self, count: int) -> np.ndarray:
        if self.lengths is not None:
            return self.lengths
        return np.full(count, self.values.shape[1], np.int64)

    @property
    def count_dtype(self) -> np.dtype:
        longest = self.values.shape[1] if self.lengths is None else int(self.lengths.max(initial=0))
        return np.dtype("u1") if longest <= 255 else np.dtype("i4")


@dataclass
class _OutElement:
    name: str
    count: int
    columns: list[_Column]


def write_ply(path: Path, cloud: PointCloud | Records, encoding: str | None = None) -> None:
    """Write ``cloud`` (PointCloud, Mesh or Records) as PLY in ``encoding`` (default
    binary_little_endian).

    Writes ``vertex``, then ``face`` for a Mesh, then the elements of
    ``metadata["ply_elements"]``; ``metadata["comments"]`` and ``metadata["obj_info"]`` become
    header lines. Raises FormatError for fields PLY cannot hold (see the module docstring).
    """
    path = Path(path)
    encoding = encoding or ENCODINGS[0]
    if encoding not in ENCODINGS:
        raise FormatError(
            path, f"unknown PLY encoding {encoding!r}; expected one of {list(ENCODINGS)}"
        )
    shape = getattr(cloud, "shape", None)
    if shape is not None:
        warnings.warn(
            f"{path}: PLY has no organised layout; the cloud's shape {shape} is not stored",
            stacklevel=2,
        )
    elements = _elements_to_write(path, cloud)
    header = _header_text(encoding, elements, cloud.metadata)
    with open(path, "wb") as file:
        file.write(header)
        for element in elements:
            if encoding == "ascii":
                _write_text_element(file, element)
            else:
                _write_binary_element(file, element, BYTE_ORDERS[encoding])


def _elements_to_write(path: Path, cloud: PointCloud | Records) -> list[_OutElement]:
    points = cloud.points if isinstance(cloud, PointCloud) else None
    elements = [_out_element(path, "vertex", _ply_columns(path, "vertex", points, cloud.fields))]
    if isinstance(cloud, Mesh):
        _check_faces_to_write(path, cloud)
        face_columns = _ply_columns(path, "face", None, {"vertex_indices": cloud.faces})
        for name, values in _ply_columns(path, "face", None, cloud.face_fields).items():
            if name in face_columns:
                raise FormatError(
                    path, f"face field {name!r} clashes with the faces' vertex_indices"
                )
            face_columns[name] = values
        elements.append(_out_element(path, "face", face_columns))
    extra = cloud.metadata.get("ply_elements") or {}
    if not isinstance(extra, Mapping):
        raise FormatError(
            path, "metadata['ply_elements'] must map element names to dicts of columns"
        )
    for name, columns in extra.items():
        if any(element.name == name for element in elements):
            raise FormatError(
                path,
                f"metadata['ply_elements'] has an element {name!r}, which the cloud writes itself",
            )
        if not isinstance(columns, Mapping):
            raise FormatError(path, f"metadata['ply_elements'][{name!r}] must be a dict of columns")
        elements.append(
            _out_element(path, str(name), {str(k): np.asarray(v) for k, v in columns.items()})
        )
    return elements


def _check_faces_to_write(path: Path, mesh: Mesh) -> None:
    """Refuse faces that index missing vertices: the file would not read back."""
    faces = mesh.faces
    if faces.dtype == object and len(faces):
        faces = np.concatenate([np.asarray(face).reshape(-1) for face in faces])
    if faces.size and (faces.min() < 0 or faces.max() >= len(mesh.points)):
        raise FormatError(
            path,
            f"faces index vertices {faces.min()} to {faces.max()}, but the mesh has "
            f"{len(mesh.points)} vertices",
        )


def _ply_columns(
    path: Path, element: str, points: np.ndarray | None, fields: Mapping[str, np.ndarray]
) -> dict[str, np.ndarray]:
    """Columns named the PLY way (``colors`` -> ``red green blue``), refusing name clashes that
    would silently drop a field (``colors`` and ``red`` together)."""
    columns: dict[str, np.ndarray] = dict(cloud_to_columns(points, {}, PLY_NAMES))
    for name, values in fields.items():
        for column, part in cloud_to_columns(None, {name: values}, PLY_NAMES).items():
            if column in columns:
                raise FormatError(
                    path,
                    f"{element} field {name!r} would be written as property {column!r}, "
                    "which another field already uses",
                )
            columns[column] = part
    return columns


def _out_element(path: Path, name: str, columns: Mapping[str, np.ndarray]) -> _OutElement:
    _check_name(path, "element", name)
    prepared = [_column_to_write(path, name, column, values) for column, values in columns.items()]
    counts = {len(c.lengths) if c.lengths is not None else len(c.values) for c in prepared}
    if len(counts) > 1:
        raise FormatError(
            path, f"element {name!r} has columns of different lengths {sorted(counts)}"
        )
    return _OutElement(name, counts.pop() if counts else 0, prepared)


def _check_name(path: Path, kind: str, name: str) -> None:
    if not name or name.split() != [name]:
        raise FormatError(
            path, f"{kind} name {name!r} cannot be written: PLY names are words without spaces"
        )


def _column_to_write(path: Path, element: str, name: str, values: np.ndarray) -> _Column:
    _check_name(path, "property", name)
    label = f"{element} property {name!r}"
    if values.dtype == object:
        items = [np.asarray(item) for item in values]
        if all(item.ndim == 0 for item in items):
            return _Column(name, _storable(path, label, np.array([i.item() for i in items])))
        if not all(item.ndim == 1 for item in items):
            raise FormatError(
                path, f"{label} mixes arrays of several dimensions; PLY lists are 1-D"
            )
        lengths = np.array([len(item) for item in items], np.int64)
        flat = np.concatenate(items) if items else np.zeros(0, np.int32)
        return _Column(name, _storable(path, label, flat), lengths)
    if values.ndim == 0 or values.ndim > 2:
        raise FormatError(
            path, f"{label} has shape {values.shape}; PLY holds (N,) scalars or (N, K) lists"
        )
    return _Column(name, _storable(path, label, values))


def _storable(path: Path, label: str, values: np.ndarray) -> np.ndarray:
    """``values`` in a native-order dtype PLY has a type name for, converted only when no value
    changes; FormatError otherwise."""
    dtype = values.dtype
    if dtype.kind == "b":
        return values.astype(np.uint8)
    if dtype.kind in "iu" and dtype.itemsize > 4:
        low = int(values.min()) if values.size else 0
        high = int(values.max()) if values.size else 0
        for target in (np.int32, np.uint32):
            info = np.iinfo(target)
            if info.min <= low and high <= info.max:
                return values.astype(target)
        raise FormatError(
            path,
            f"{label} holds {dtype} values from {low} to {high}, outside the 32-bit "
            "integers PLY can store",
        )
    if dtype.kind == "f" and dtype.itemsize != 4 and dtype.itemsize != 8:
        target = np.float32 if dtype.itemsize < 4 else np.float64
        converted = values.astype(target)
        if not np.array_equal(converted.astype(dtype), values, equal_nan=True):
            raise FormatError(
                path, f"{label} holds {dtype} values that a PLY double cannot hold exactly"
            )
        return converted
    if dtype.kind not in "iuf":
        raise FormatError(
            path, f"{label} has dtype {dtype}; PLY stores integers of up to 32 bits and floats"
        )
    return values.astype(dtype.newbyteorder("="), copy=False)


def _header_text(encoding: str, elements: list[_OutElement], metadata: Mapping[str, Any]) -> bytes:
    lines = ["ply", f"format {encoding} 1.0"]
    for keyword in ("comment", "obj_info"):
        texts = metadata.get("comments" if keyword == "comment" else "obj_info") or []
        if isinstance(texts, str):
            texts = [texts]
        for text in texts:
            lines += [f"{keyword} {part}".rstrip("\r") for part in str(text).split("\n")]
    for element in elements:
        lines.append(f"element {element.name} {element.count}")
        for column in element.columns:
            value_type = TYPE_NAMES[column.values.dtype]
            if column.is_list:
                lines.append(
                    f"property list {TYPE_NAMES[column.count_dtype]} {value_type} {column.name}"
                )
            else:
                lines.append(f"property {value_type} {column.name}")
    lines.append("end_header\n")
    return "\n".join(lines).encode("utf-8")


def _write_binary_element(file: IO[bytes], element: _OutElement, byte_order: str) -> None:
    if element.count == 0:
        return
    if all(column.lengths is None for column in element.columns):
        # Every record has the same layout: one structured array, written in one go.
        layout: list[tuple[Any, ...]] = []
        for column in element.columns:
            dtype = column.values.dtype.newbyteorder(byte_order)
            if column.is_list:
                layout.append(
                    (f"{column.name} length", column.count_dtype.newbyteorder(byte_order))
                )
                layout.append((column.name, dtype, (column.values.shape[1],)))
            else:
                layout.append((column.name, dtype))
        records = np.empty(element.count, np.dtype(layout))
        for column in element.columns:
            if column.is_list:
                records[f"{column.name} length"] = column.values.shape[1]
            records[column.name] = column.values
        records.tofile(file)
        return
    _packed_records(element, byte_order).tofile(file)


def _packed_records(element: _OutElement, byte_order: str) -> np.ndarray:
    """The element's records as bytes when list lengths vary: each value is scattered to its
    byte position, computed from the lengths (the inverse of the reader's gather)."""
    count = element.count
    record_sizes = np.zeros(count, np.int64)
    for column in element.columns:
        if column.is_list:
            lengths = column.list_lengths(count)
            record_sizes += column.count_dtype.itemsize + lengths * column.values.dtype.itemsize
        else:
            record_sizes += column.values.dtype.itemsize
    offsets = np.cumsum(record_sizes) - record_sizes
    out = np.empty(int(record_sizes.sum()), np.uint8)
    for column in element.columns:
        dtype = column.values.dtype.newbyteorder(byte_order)
        if column.is_list:
            lengths = column.list_lengths(count)
            count_dtype = column.count_dtype.newbyteorder(byte_order)
            _scatter(out, offsets, lengths.astype(count_dtype))
            offsets = offsets + count_dtype.itemsize
            items = column.values.reshape(-1)
            _scatter(out, _item_positions(offsets, lengths, dtype.itemsize), items.astype(dtype))
            offsets = offsets + lengths * dtype.itemsize
        else:
            _scatter(out, offsets, column.values.astype(dtype))
            offsets = offsets + dtype.itemsize
    return out


def _scatter(out: np.ndarray, positions: np.ndarray, values: np.ndarray) -> None:
    size = values.dtype.itemsize
    raw = np.ascontiguousarray(values).view(np.uint8).reshape(len(values), size)
    out[positions[:, None] + np.arange(size)] = raw


def _write_text_element(file: IO[bytes], element: _OutElement) -> None:
    """One line per record, values separated by single spaces.

    Formatting runs in pyarrow (numbers to strings, strings joined per line), which writes each
    float in the shortest form that reads back to the same float32 / float64.
    """
    import pyarrow.compute as pc

    list_ends = {c.name: np.cumsum(c.lengths) for c in element.columns if c.lengths is not None}
    for low in range(0, element.count, TEXT_WRITE_BATCH):
        high = min(low + TEXT_WRITE_BATCH, element.count)
        parts: list[Any] = []
        for column in element.columns:
            if column.lengths is not None:
                ends = list_ends[column.name]
                items = column.values[(int(ends[low - 1]) if low else 0) : int(ends[high - 1])]
                parts.append(_ragged_text(items, column.lengths[low:high]))
            elif column.values.ndim == 2:
                length = column.values.shape[1]
                parts.append(_text(np.full(high - low, length, column.count_dtype)))
                parts += [_text(column.values[low:high, k]) for k in range(length)]
            else:
                parts.append(_text(column.values[low:high]))
        records = pc.binary_join_element_wise(*parts, " ")
        lines = pc.binary_join_element_wise(records, "", "\n")
        offsets = np.frombuffer(lines.buffers()[1], np.int32, len(lines) + 1, lines.offset * 4)
        file.write(memoryview(lines.buffers()[2])[offsets[0] : offsets[-1]])


def _text(values: np.ndarray) -> Any:
    import pyarrow as pa
    import pyarrow.compute as pc

    return pc.cast(pa.array(np.ascontiguousarray(values)), pa.string())


def _ragged_text(values: np.ndarray, lengths: np.ndarray) -> Any:
    """Lists of ``lengths`` (n,) whose items are ``values`` (flat) as strings
    ``"<length> <item> <item> ..."``, one per list."""
    import pyarrow as pa
    import pyarrow.compute as pc

    items = _text(values)
    counts = _text(lengths)
    # Interleave each record's length before its items, then join each record's strings.
    record_starts = np.cumsum(lengths + 1) - (lengths + 1)
    order = np.empty(len(lengths) + len(items), np.int64)
    is_count = np.zeros(len(order), bool)
    is_count[record_starts] = True
    order[is_count] = np.arange(len(lengths))
    order[~is_count] = len(lengths) + np.arange(len(items))
    strings = pa.concat_arrays([counts, items]).take(pa.array(order))
    offsets = np.append(record_starts, len(order)).astype(np.int32)
    return pc.binary_join(pa.ListArray.from_arrays(pa.array(offsets), strings), " ")


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
        holds_faces=True,
    )
)
