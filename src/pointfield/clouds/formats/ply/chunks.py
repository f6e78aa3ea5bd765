"""PLY a window of points at a time: the chunk reader and writer that :mod:`pointfield.streaming` uses.

Reading streams a binary file whose only non-empty element is ``vertex`` (no list properties):
its records are fixed-size, read with ``pread`` and turned into clouds by the reader's own
code. An ascii file or a mesh returns None: it is read whole. Writing streams every encoding:
the vertex records go to a body file, and the header (which states the vertex count) and the
template's other elements are written at the end, by the writer's own code.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from pointfield.clouds.cloud import PointCloud, Records
from pointfield.clouds.formats.binary import record_dtype
from pointfield.clouds.formats.chunked import BodyFirstWriter, RecordSource
from pointfield.clouds.formats.ply.header import BYTE_ORDERS, ENCODINGS, HEADER_LIMIT, parse_header
from pointfield.clouds.formats.ply.reader import _assemble, _empty_columns
from pointfield.clouds.formats.ply.writer import (
    _column_to_write,
    _header_text,
    _out_element,
    _OutElement,
    _ply_columns,
    _write_binary_element,
    _write_text_element,
)
from pointfield.errors import FormatError


def open_ply_chunks(path: Path) -> RecordSource | None:
    """The vertex records of a binary point-cloud PLY as a :class:`RecordSource`; None to read it whole."""
    with open(path, "rb") as file:
        header = parse_header(path, file.read(HEADER_LIMIT))
    if header.encoding == "ascii":
        return None
    offset = header.data_offset
    vertex = None
    for element in header.elements:
        if any(prop.is_list for prop in element.properties) and element.count:
            return None
        if element.name == "vertex":
            vertex = element
        elif element.count:
            # Faces or other elements: a mesh; read whole so that nothing is lost.
            return None
        if vertex is None:
            offset += element.count * sum(p.dtype.itemsize for p in element.properties)
    if vertex is None or any(prop.is_list for prop in vertex.properties):
        return None
    dtype = record_dtype([(p.name, p.dtype) for p in vertex.properties], BYTE_ORDERS[header.encoding])
    native = dtype.newbyteorder("=")
    # The other elements are all empty: read_ply's columns for them.
    empty = {element.name: _empty_columns(element) for element in header.elements if element.name != "vertex"}

    def convert(records: np.ndarray) -> PointCloud | Records:
        records = records if records.dtype == native else records.astype(native)
        return _assemble(path, header, {"vertex": {name: records[name] for name in native.names}, **empty})

    return RecordSource(path, dtype, offset, vertex.count, convert, "ply", "vertex")


class PlyChunkWriter(BodyFirstWriter):
    """PLY in any encoding, by the PLY writer's own column and record code."""

    def _begin(self, cloud: PointCloud) -> None:
        super()._begin(cloud)
        self.columns = self._columns(cloud)
        self.extra = [
            _out_element(self.path, str(name), {str(k): np.asarray(v) for k, v in columns.items()})
            for name, columns in (cloud.metadata.get("ply_elements") or {}).items()
        ]

    def _columns(self, cloud: PointCloud) -> list[Any]:
        columns = [
            _column_to_write(self.path, "vertex", name, values)
            for name, values in _ply_columns(self.path, "vertex", cloud.points, cloud.fields).items()
        ]
        for column in columns:
            if column.lengths is not None:
                raise FormatError(
                    self.path,
                    f"vertex property {column.name!r} holds lists of varying length, which "
                    "cannot be written in chunks",
                )
        return columns

    def _write(self, cloud: PointCloud) -> None:
        columns = self._columns(cloud) if cloud is not self.template else self.columns
        for column, first in zip(columns, self.columns, strict=True):
            if column.values.dtype != first.values.dtype:
                raise FormatError(
                    self.path,
                    f"vertex property {column.name!r} is {column.values.dtype} in a later chunk "
                    f"but {first.values.dtype} in the first",
                )
        element = _OutElement("vertex", len(cloud), columns)
        if self.encoding == "ascii":
            _write_text_element(self.body, element)
        else:
            _write_binary_element(self.body, element, BYTE_ORDERS[self.encoding])

    def _header(self) -> bytes:
        vertex = _OutElement("vertex", self.count, self.columns)
        return _header_text(self.encoding, [vertex, *self.extra], self.template.metadata)

    def _trailer(self, out: BinaryIO) -> None:
        for element in self.extra:
            if self.encoding == "ascii":
                _write_text_element(out, element)
            else:
                _write_binary_element(out, element, BYTE_ORDERS[self.encoding])


def ply_chunk_writer(encoding: str | None) -> type[PlyChunkWriter] | None:
    """Every PLY encoding streams."""
    return PlyChunkWriter if encoding in ENCODINGS else None
