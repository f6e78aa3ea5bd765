"""PCD a window of points at a time: the chunk reader and writer that :mod:`pointfield.streaming` uses.

Reading streams ``binary`` files (fixed-size records, read with ``pread`` and turned into clouds
by the reader's own code); ``ascii`` and ``binary_compressed`` return None: they are read whole.
Writing streams ``binary`` and ``ascii``: the records go to a body file and the header, which
states the point count, is written at the end by the writer's own header code, for an
unorganised cloud of all the points. ``binary_compressed`` (one LZF block of the columns) is
written whole.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from pointfield.clouds.cloud import PointCloud, Records
from pointfield.clouds.formats.chunked import BodyFirstWriter, RecordSource
from pointfield.clouds.formats.pcd.header import MAX_HEADER_BYTES, parse_header
from pointfield.clouds.formats.pcd.reader import _assemble, _binary_records
from pointfield.clouds.formats.pcd.writer import (
    _columns_to_write,
    _field_for,
    _header_text,
    _viewpoint_to_write,
    _write_ascii,
    _write_binary,
)
from pointfield.errors import FormatError


def open_pcd_chunks(path: Path) -> RecordSource | None:
    """The records of a ``binary`` PCD as a :class:`RecordSource`; None to read other encodings whole."""
    with open(path, "rb") as file:
        header = parse_header(file.read(MAX_HEADER_BYTES), path)
    if header.encoding != "binary":
        return None
    dtype = _binary_records(header)

    def convert(records: np.ndarray) -> PointCloud | Records:
        window = replace(header, width=len(records), height=1, points=len(records))
        return _assemble({name: records[name] for name in dtype.names}, window, path)

    return RecordSource(path, dtype, header.data_offset, header.points, convert, "pcd")


class PcdChunkWriter(BodyFirstWriter):
    """PCD ``binary`` and ``ascii``, by the PCD writer's own column, record and header code."""

    def _begin(self, cloud: PointCloud) -> None:
        super()._begin(cloud)
        self.columns = _columns_to_write(cloud, ascii_text=self.encoding == "ascii")
        if not self.columns:
            raise FormatError(self.path, "nothing to write: the records have no field PCD can hold")
        self.fields = [_field_for(name, values) for name, values in self.columns.items()]
        self.viewpoint = _viewpoint_to_write(cloud.metadata.get("viewpoint"), self.path)

    def _write(self, cloud: PointCloud) -> None:
        columns = _columns_to_write(cloud, ascii_text=self.encoding == "ascii")
        if [_field_for(n, v) for n, v in columns.items()] != self.fields:
            raise FormatError(self.path, "a later chunk's PCD fields differ from the first chunk's")
        if self.encoding == "ascii":
            _write_ascii(self.body, columns)
        else:
            _write_binary(self.body, columns, self.fields, len(cloud))

    def _header(self) -> bytes:
        return _header_text(self.fields, (1, self.count), self.count, self.viewpoint, self.encoding,
                            self.template.metadata)


def pcd_chunk_writer(encoding: str | None) -> type[PcdChunkWriter] | None:
    """``binary`` and ``ascii`` stream; ``binary_compressed`` is one LZF block, written whole."""
    return PcdChunkWriter if encoding in ("binary", "ascii") else None
