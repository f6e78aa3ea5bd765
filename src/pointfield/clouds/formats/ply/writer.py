"""Writing PLY: a cloud, mesh or records as elements, in any of the three encodings.

See the package docstring for what is written and which fields PLY cannot hold.
"""

from __future__ import annotations

import warnings
from collections.abc import Collection, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from pointfield.clouds.cloud import PointCloud, Records
from pointfield.clouds.formats.binary import item_positions, record_dtype, scatter
from pointfield.clouds.formats.columns import PLY_NAMES, cloud_to_columns
from pointfield.clouds.formats.ply.header import BYTE_ORDERS, ENCODINGS, TYPE_NAMES
from pointfield.clouds.mesh import Mesh
from pointfield.errors import FormatError

# Ascii is written this many records at a time, bounding the memory of the formatted text.
TEXT_WRITE_BATCH = 1 << 18


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
        elements.append(_out_element(path, "face", face_columns, indices=("vertex_indices",)))
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


def _out_element(
    path: Path, name: str, columns: Mapping[str, np.ndarray], indices: Collection[str] = ()
) -> _OutElement:
    """The element's columns ready to write; ``indices`` names those holding vertex indices."""
    _check_name(path, "element", name)
    prepared = [
        _column_to_write(path, name, column, values, index=column in indices)
        for column, values in columns.items()
    ]
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


def _column_to_write(
    path: Path, element: str, name: str, values: np.ndarray, *, index: bool = False
) -> _Column:
    _check_name(path, "property", name)
    label = f"{element} property {name!r}"
    if values.dtype == object:
        items = [np.asarray(item) for item in values]
        if all(item.ndim == 0 for item in items):
            scalars = np.array([i.item() for i in items])
            return _Column(name, _storable(path, label, scalars, index=index))
        if not all(item.ndim == 1 for item in items):
            raise FormatError(
                path, f"{label} mixes arrays of several dimensions; PLY lists are 1-D"
            )
        lengths = np.array([len(item) for item in items], np.int64)
        flat = np.concatenate(items) if items else np.zeros(0, np.int32)
        return _Column(name, _storable(path, label, flat, index=index), lengths)
    if values.ndim == 0 or values.ndim > 2:
        raise FormatError(
            path, f"{label} has shape {values.shape}; PLY holds (N,) scalars or (N, K) lists"
        )
    return _Column(name, _storable(path, label, values, index=index))


def _storable(path: Path, label: str, values: np.ndarray, *, index: bool = False) -> np.ndarray:
    """``values`` in a native-order dtype PLY has a type name for, converted only when no value
    changes; FormatError otherwise. ``index``: the values are vertex indices."""
    dtype = values.dtype
    if dtype.kind == "b":
        return values.astype(np.uint8)
    if dtype.kind in "iu" and dtype.itemsize > 4:
        return _without_64_bit_integers(path, label, values, index)
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


def _without_64_bit_integers(
    path: Path, label: str, values: np.ndarray, index: bool
) -> np.ndarray:
    """int64 / uint64 values as a type PLY has, with a warning: PLY has no 64-bit integers.

    Values that fit 32 bits are written as int / uint (the source's signedness first); values
    beyond that but exact in a double (|v| <= 2**53) as double, which reads back as float64;
    anything larger is refused. Vertex indices (``index``) that fit PLY's usual ``int`` (every
    mesh under 2**31 vertices) are written as int without a warning: an index is an index,
    whatever dtype it was kept in.
    """
    dtype = values.dtype
    low = int(values.min()) if values.size else 0
    high = int(values.max()) if values.size else 0
    signed_first = index or dtype.kind == "i"
    targets = (np.int32, np.uint32) if signed_first else (np.uint32, np.int32)
    for target in targets:
        info = np.iinfo(target)
        if info.min <= low and high <= info.max:
            if index and target is np.int32:
                return values.astype(target)
            warnings.warn(
                f"PLY has no 64-bit integers; {label} ({dtype}) is written as "
                f"{np.dtype(target)}, which holds every value, and reads back as that",
                stacklevel=9,
            )
            return values.astype(target)
    if -(2**53) <= low and high <= 2**53:
        warnings.warn(
            f"PLY has no 64-bit integers; {label} ({dtype}, values up to {high}) is "
            "written as double, exact for these values, and reads back as float64",
            stacklevel=9,
        )
        return values.astype(np.float64)
    raise FormatError(
        path,
        f"{label} holds {dtype} values from {low} to {high}: PLY has no 64-bit integers, and "
        "a double holds integers exactly only up to 2**53",
    )


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
            if column.is_list:
                layout.append((f"{column.name} length", column.count_dtype))
                layout.append((column.name, column.values.dtype, (column.values.shape[1],)))
            else:
                layout.append((column.name, column.values.dtype))
        records = np.empty(element.count, record_dtype(layout, byte_order))
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
            scatter(out, offsets, lengths.astype(count_dtype))
            offsets = offsets + count_dtype.itemsize
            items = column.values.reshape(-1)
            scatter(out, item_positions(offsets, lengths, dtype.itemsize), items.astype(dtype))
            offsets = offsets + lengths * dtype.itemsize
        else:
            scatter(out, offsets, column.values.astype(dtype))
            offsets = offsets + dtype.itemsize
    return out


def _write_text_element(file: IO[bytes], element: _OutElement) -> None:
    """One line per record, values separated by single spaces.

    Formatting runs in pyarrow (numbers to strings, strings joined per line), which writes each
    float in the shortest form that reads back to the same float32 / float64.
    """
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
    return pc.cast(pa.array(np.ascontiguousarray(values)), pa.string())


def _ragged_text(values: np.ndarray, lengths: np.ndarray) -> Any:
    """Lists of ``lengths`` (n,) whose items are ``values`` (flat) as strings
    ``"<length> <item> <item> ..."``, one per list."""
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
