"""Reading PLY: the data section decoded element by element, then mapped onto a cloud.

Binary data is read through a read-only map of the file (:mod:`..binary`): elements without
lists, and elements whose lists all have the length of the first record's (triangle meshes), are
one packed structured array; lists of varying length are walked record by record to find where
each value lies, then gathered with vectorised indexing. Ascii data is located line by line and
parsed by :mod:`..ascii`: pyarrow for large elements whose lines share one shape, numpy's
tokenizer for the rest.
"""

from __future__ import annotations

import math
import struct
from array import array
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from pointfield.clouds.cloud import PointCloud, Records
from pointfield.clouds.formats.ascii import (
    TableError,
    parse_numbers,
    read_table,
    skip_lines,
)
from pointfield.clouds.formats.binary import (
    check_size,
    gather,
    item_positions,
    map_file,
    read_records,
    record_dtype,
)
from pointfield.clouds.formats.columns import columns_to_cloud_parts
from pointfield.clouds.formats.ply.header import (
    BYTE_ORDERS,
    HEADER_LIMIT,
    TYPE_NAMES,
    Element,
    Header,
    Property,
    parse_header,
)
from pointfield.clouds.mesh import Mesh
from pointfield.errors import FormatError

# Ascii elements of at least this many records are parsed by pyarrow, smaller ones by numpy:
# pyarrow's fixed cost per call and per column (about 0.1 ms) pays off only over many records.
PYARROW_MIN_RECORDS = 4096

FACE_INDEX_NAMES = ("vertex_indices", "vertex_index")


def read_ply(path: Path) -> PointCloud | Mesh | Records:
    """Read a PLY file (any encoding) into a PointCloud, a Mesh (faces) or Records (no x y z).

    See the package docstring for how elements map onto fields. A binary file is mapped, not
    read, and each property copied once out of it, so peak memory is about the returned arrays
    (twice that for a byte order other than the machine's, which takes one native copy).
    """
    path = Path(path)
    with open(path, "rb") as file:
        head = file.read(HEADER_LIMIT)
        header = parse_header(path, head)
        if header.encoding == "ascii":
            file.seek(header.data_offset)
            data = file.read()
        else:
            # A small file's head is the whole file, which is then not read a second time.
            data = map_file(file, head)
        del head  # else up to a megabyte, not to be held while the data is decoded
    for element in header.elements:
        if element.count and not element.properties:
            raise FormatError(
                path, f"element {element.name!r} declares {element.count} records but no properties"
            )
    if header.encoding == "ascii":
        decoder: _TextData | _BinaryData = _TextData(path, data, header)
    else:
        decoder = _BinaryData(path, data, header.data_offset, BYTE_ORDERS[header.encoding])
    columns = {element.name: decoder.read(element) for element in header.elements}
    return _assemble(path, header, columns)


def _assemble(
    path: Path, header: Header, columns: dict[str, dict[str, np.ndarray]]
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

    # Copy out every array that views the file's map (read-only) or a block of records (not
    # contiguous), so that each field is compact and owns its memory.
    def owned(values: np.ndarray) -> np.ndarray:
        if values.dtype != object and not (
            values.flags.writeable and values.flags.c_contiguous
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
    """Decodes the binary data section one element after another (see the module docstring)."""

    def __init__(self, path: Path, data: Any, start: int, byte_order: str):
        self.path = path
        self.data = data  # the mapped file
        self.bytes = np.frombuffer(data, np.uint8)
        self.byte_order = byte_order
        self.position = start

    def read(self, element: Element) -> dict[str, np.ndarray]:
        if element.count == 0:
            return _empty_columns(element)
        has_lists = any(p.is_list for p in element.properties)
        smallest = sum(
            p.dtype.itemsize if p.count_dtype is None else p.count_dtype.itemsize
            for p in element.properties
        )
        check_size(
            self.path,
            f"element {element.name!r}",
            element.count,
            smallest,
            len(self.data) - self.position,
            at_least=has_lists,
        )
        if not has_lists:
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
        """The records as a structured array whose lists have ``lengths``; None when the data
        disagrees with those lengths (or is too short for them)."""
        layout: list[tuple[Any, ...]] = []
        for prop in element.properties:
            if prop.count_dtype is None:
                layout.append((prop.name, prop.dtype))
            else:
                layout.append((f"{prop.name} length", prop.count_dtype))
                layout.append((prop.name, prop.dtype, (lengths[prop.name],)))
        dtype = record_dtype(layout, self.byte_order)
        if element.count * dtype.itemsize > len(self.data) - self.position:
            return None
        records = read_records(self.data, dtype, element.count, self.position)
        for name, length in lengths.items():
            if not np.all(records[f"{name} length"] == length):
                return None
        self.position += element.count * dtype.itemsize
        return {prop.name: records[prop.name] for prop in element.properties}

    def _read_ragged(self, element: Element) -> dict[str, np.ndarray]:
        located, self.position = self._walk(element, element.count)
        columns = {}
        for prop, (positions, counts) in zip(element.properties, located, strict=True):
            dtype = prop.dtype.newbyteorder(self.byte_order)
            if prop.is_list:
                items = gather(self.bytes, item_positions(positions, counts, dtype.itemsize), dtype)
                columns[prop.name] = _split_lists(items, counts)
            else:
                columns[prop.name] = gather(self.bytes, positions, dtype)
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


class _TextData:
    """Decodes the ascii data section one element after another, one record per line.

    Each element's lines are located first, so a declared count is checked against the lines
    really present before anything is allocated. Large elements whose lines share one shape are
    parsed by pyarrow (:func:`read_table`); everything else (small elements, tabs, repeated
    spaces, lists of varying length) by numpy's tokenizer and a record walk.
    """

    def __init__(self, path: Path, data: bytes, header: Header):
        self.path = path
        self.data = data  # the data section, from the line after end_header
        self.first_line = header.data_line
        self.position = 0
        self.last_with_records = next((e for e in reversed(header.elements) if e.count), None)

    def read(self, element: Element) -> dict[str, np.ndarray]:
        if element.count == 0:
            return _empty_columns(element)
        start = self.position
        use_pyarrow = element.count >= PYARROW_MIN_RECORDS
        if use_pyarrow and element is self.last_with_records:
            # The last element runs to the end of the data, so pyarrow can take the rest whole,
            # its row count standing in for the line count (its memory follows the data's size,
            # not the declared count). Lines after the records send it the long way round.
            columns = self._parse_uniform(start, len(self.data), element)
            if columns is not None:
                self.position = len(self.data)
                return columns
        end, found = skip_lines(self.data, start, element.count)
        if found < element.count:
            raise FormatError(
                self.path,
                f"element {element.name!r} declares {element.count} records (one per line) "
                f"but only {found} lines of data follow",
            )
        self.position = end
        columns = self._parse_uniform(start, end, element) if use_pyarrow else None
        if columns is None:
            columns = self._parse_tokens(start, end, element)
        return columns

    def _parse_uniform(
        self, start: int, end: int, element: Element
    ) -> dict[str, np.ndarray] | None:
        """Lines of one shape (single spaces, the same list lengths as the first line) parsed
        by pyarrow; None when the block is not like that."""
        first_end = self.data.find(b"\n", start, end)
        first_line = self.data[start : end if first_end < 0 else first_end].rstrip(b"\r")
        tokens = first_line.rstrip(b" ").split(b" ")
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
        try:
            arrays = read_table(memoryview(self.data)[start:end], column_types)
        except TableError:
            return None
        if len(arrays[0]) != element.count:
            return None
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

    def _parse_tokens(self, start: int, end: int, element: Element) -> dict[str, np.ndarray]:
        """The general, slower parse: every number of the block, then a walk over the records."""
        first_line = self.first_line + self.data.count(b"\n", 0, start)
        values = parse_numbers(self.data[start:end], self.path, first_line)
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
                items = self._cast(values[item_positions(positions, counts, 1)], element, prop)
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



def _split_lists(items: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """``(n, K)`` when every list has length K, else a 1-D object array of item arrays."""
    if len(lengths) == 0 or np.all(lengths == lengths[0]):
        return items.reshape(len(lengths), int(lengths[0]) if len(lengths) else 0)
    ragged = np.empty(len(lengths), object)
    ends = np.cumsum(lengths)
    for i, (first, end) in enumerate(zip((ends - lengths).tolist(), ends.tolist(), strict=True)):
        ragged[i] = items[first:end]
    return ragged


