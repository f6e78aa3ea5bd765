"""Leica PTX: terrestrial laser scans, several per file, each an organised grid of returns.

A PTX file is one or more scans, each a ten-line header followed by one row per cell of the
scanner's grid (Leica Cyclone writes it; PDAL and CloudCompare read it)::

    1024                           <- columns: the scanner's horizontal steps
    512                            <- rows: the points of one column
    10.0 20.0 1.5                  <- scanner position
    1 0 0                          <- scanner axes X, Y and Z, one per line
    0 1 0
    0 0 1
    1 0 0 0                        <- the scan's 4x4 transform T, as written: the rotation in
    0 1 0 0                           the first three rows and columns, the translation in the
    0 0 1 0                           fourth row
    10.0 20.0 1.5 1
    0.25 -1.5 2.0 0.5 [r g b]      <- columns x rows rows, column by column: x y z intensity,
    ...                               and red green blue (0..255) when the rows have 7 values

Reading
    Every scan is read. Its points are transformed into the file's one frame,
    ``[x' y' z'] = [x y z 1] @ T[:, :3]`` (PDAL's and CloudCompare's reading of the matrix); the
    fourth column of T is not used. A row ``0 0 0`` is a cell with no return: a NaN point,
    whose intensity and colour are kept. ``points`` are float64, ``intensity`` float64 (as text
    gives it), ``colors`` ``(N, 3)`` uint8, and ``scan_index`` (uint8, uint16 or uint32 as the
    number of scans needs) says which scan each point came from. Each scan's points are in the
    row-major order of its grid, ``rows x columns`` (the file lists them column by column), so
    scan k's points reshape to ``(rows_k, columns_k)``; a file of one scan with more than one
    row reads as an organised cloud of that shape. ``metadata["ptx_scans"]`` records, per scan,
    ``columns``, ``rows``, ``points``, ``scanner_position``, ``scanner_axes`` and the
    ``transform`` as the file gives them (the transform already applied to the points).
    Every row of a file has the same number of values, 4 or 7, as PDAL and CloudCompare expect.

Writing (encoding ``"text"``)
    One scan per ``scan_index`` value, in ascending order (renumbered 0, 1, ...), or one scan.
    The points are already in one frame, so every scan is written with the identity transform;
    its scanner position and axes are those of ``metadata["ptx_scans"]`` when that describes the
    same scans, else the origin and the identity. A scan's grid is the cloud's organised shape,
    or the grid its metadata records when the point count matches, else one row of N columns
    (which reads back unorganised). NaN points are written as ``0 0 0``; a point really at the
    origin would read back as NaN, so a warning says how many there are. ``intensity`` is
    written as is (float64 digits); a cloud without one gets 0 with a warning. ``colors`` are
    written as 0..255 integers (uint16 / 257, floats in [0, 1] x 255, rounded, with a warning);
    every other field is left out with a warning naming it.
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.formats.ascii import (
    TableError,
    read_table,
    rows_of_numbers,
    skip_lines,
    write_rows,
)
from pointfield.clouds.formats.registry import Format, register
from pointfield.errors import FormatError

HEADER_LINES = 10
# A header line holds at most four numbers; anything much longer is not a PTX header.
MAX_HEADER_LINE_BYTES = 1024
# The shortest row, "0 0 0 0" and its newline: a declared grid needs this many bytes per cell.
MIN_ROW_BYTES = 8
ROW_WIDTHS = (4, 7)

_COUNT = re.compile(rb"[0-9]+")
_NOT_SPACE = re.compile(rb"\S")
_IDENTITY = np.eye(4)


@dataclass(frozen=True)
class _ScanHeader:
    """The ten-line header of one scan, as the file gives it."""

    columns: int
    rows: int
    position: np.ndarray  # (3,)
    axes: np.ndarray  # (3, 3), one axis per row as written
    transform: np.ndarray  # (4, 4), as written

    @property
    def points(self) -> int:
        return self.columns * self.rows

    def as_metadata(self) -> dict[str, Any]:
        return {
            "columns": self.columns,
            "rows": self.rows,
            "points": self.points,
            "scanner_position": self.position.tolist(),
            "scanner_axes": self.axes.tolist(),
            "transform": self.transform.tolist(),
        }


def looks_like_ptx(head: bytes) -> bool:
    """True when the first lines are two counts (columns, rows) and then three numbers.

    No other point-cloud format starts so: a PTS count line is followed by a row of at least
    three values, never by a second lone integer.
    """
    lines = head.split(b"\n")
    complete, partial = lines[:-1], lines[-1]
    if len(complete) < 2 or not all(_COUNT.fullmatch(line.strip()) for line in complete[:2]):
        return False
    if len(complete) >= 3:
        tokens = complete[2].split()
        return len(tokens) == 3 and _floats(tokens) is not None
    tokens = partial.split()[:-1]  # the last token may be cut short
    return bool(partial.strip()) and len(tokens) <= 3 and _floats(tokens) is not None


def _floats(tokens: Sequence[bytes]) -> list[float] | None:
    """The tokens as floats; None when one is not a number."""
    try:
        return [float(token) for token in tokens]
    except ValueError:
        return None


# ----------------------------------------------------------------------------------------------
# Reading


def read_ptx(path: Path) -> PointCloud:
    """Read every scan of a PTX file into one PointCloud (see the module docstring)."""
    data = Path(path).read_bytes()
    position = 3 if data.startswith(b"\xef\xbb\xbf") else 0  # a UTF-8 byte-order mark
    line = 1
    width = None
    scans: list[tuple[_ScanHeader, list[np.ndarray]]] = []
    while True:
        start = _NOT_SPACE.search(data, position)
        if start is None:
            break
        line += data.count(b"\n", position, start.start())
        position = start.start()
        index = len(scans)
        header, position = _read_header(data, position, line, index, path)
        line += HEADER_LINES
        count = header.points
        if count * MIN_ROW_BYTES - 1 > len(data) - position:
            raise FormatError(
                path,
                f"scan {index} (line {line - HEADER_LINES}) declares {header.columns} x "
                f"{header.rows} points; {len(data) - position} bytes cannot hold them",
            )
        end, found = skip_lines(data, position, count)
        if found < count:
            raise FormatError(
                path,
                f"scan {index} declares {header.columns} x {header.rows} = {count} points but "
                f"only {found} rows follow",
            )
        if count:
            width = width or _row_width(data, position, line, path)
            columns = _parse_rows(memoryview(data)[position:end], width, count, index, line, path)
            scans.append((header, columns))
        else:
            scans.append((header, []))
        line += count
        position = end
    if not scans:
        raise FormatError(path, "empty file: no PTX scan header")
    return _assemble(scans, width or 4)


def _read_header(
    data: bytes, position: int, line: int, index: int, path: Path
) -> tuple[_ScanHeader, int]:
    """The ten header lines of scan ``index`` starting at byte ``position`` (line ``line``)."""
    values = []
    for offset, expected in enumerate((1, 1, 3, 3, 3, 3, 4, 4, 4, 4)):
        end = data.find(b"\n", position)
        end = len(data) if end < 0 else end
        text = data[position:end]
        where = f"scan {index} header, line {line + offset}"
        if position >= len(data):
            raise FormatError(path, f"{where}: the file ends inside the ten-line scan header")
        if len(text) > MAX_HEADER_LINE_BYTES:
            raise FormatError(path, f"{where} is {len(text)} bytes long; not a PTX header")
        tokens = text.split()
        if expected == 1:
            if len(tokens) != 1 or not _COUNT.fullmatch(tokens[0]):
                raise FormatError(
                    path,
                    f"{where}: expected the number of {'columns' if offset == 0 else 'rows'}, "
                    f"found {text.strip()[:40]!r}",
                )
            values.append(int(tokens[0]))
        else:
            numbers = _floats(tokens)
            if numbers is None or len(numbers) != expected or not np.isfinite(numbers).all():
                raise FormatError(
                    path, f"{where}: expected {expected} numbers, found {text.strip()[:60]!r}"
                )
            values.append(numbers)
        position = end + 1
    header = _ScanHeader(
        columns=values[0],
        rows=values[1],
        position=np.array(values[2]),
        axes=np.array(values[3:6]),
        transform=np.array(values[6:10]),
    )
    return header, min(position, len(data))


def _row_width(data: bytes, position: int, line: int, path: Path) -> int:
    """The number of values in the first row: 4 (x y z intensity) or 7 (and red green blue)."""
    end = data.find(b"\n", position)
    first = data[position : end if end >= 0 else len(data)]
    width = len(first.split())
    if width not in ROW_WIDTHS:
        raise FormatError(
            path,
            f"line {line}: a row has {width} values; PTX rows are x y z intensity [red green blue]",
        )
    return width


def _parse_rows(
    body: memoryview, width: int, count: int, index: int, line: int, path: Path
) -> list[np.ndarray]:
    """The columns of the ``count`` rows of scan ``index``: x y z intensity float64, and red
    green blue uint8 when ``width`` is 7.

    pyarrow's CSV reader is the fast path (values one space apart, colours integers 0..255);
    anything else goes to :func:`rows_of_numbers`, which names the line of any error.
    """
    types = [np.dtype(np.float64)] * 4 + [np.dtype(np.uint8)] * (width - 4)
    try:
        columns = read_table(body, types, " ")
    except TableError:
        table, line_numbers = rows_of_numbers(bytes(body), width, path, line)
        columns = list(table[:, :4].T)
        if width == 7:
            colors = table[:, 4:]
            bad = np.flatnonzero(~((colors == np.round(colors)) & (colors >= 0) & (colors <= 255)))
            if len(bad):
                raise FormatError(
                    path,
                    f"line {line_numbers[bad[0] // 3]}: colour {colors.flat[bad[0]]!r} is not an "
                    f"integer from 0 to 255",
                ) from None  # the fast reader's refusal is not the cause; the named line is
            columns += list(colors.astype(np.uint8).T)
    if len(columns[0]) != count:
        raise FormatError(
            path,
            f"scan {index} declares {count} points but only {len(columns[0])} of its {count} "
            f"lines hold a row (blank lines?)",
        )
    return columns


def _assemble(scans: list[tuple[_ScanHeader, list[np.ndarray]]], width: int) -> PointCloud:
    """One cloud from the scans' columns: transformed, NaN for no return, row-major grids."""
    total = sum(header.points for header, _ in scans)
    points = np.empty((total, 3), np.float64)
    intensity = np.empty(total, np.float64)
    colors = np.empty((total, 3), np.uint8) if width == 7 else None
    scan_index = np.empty(total, _index_dtype(len(scans)))
    start = 0
    for k, (header, columns) in enumerate(scans):
        stop = start + header.points
        scan_index[start:stop] = k
        if header.points:
            grid = (header.rows, header.columns)
            scan_points = points[start:stop].reshape(*grid, 3)
            for axis in range(3):
                scan_points[:, :, axis] = _row_major(columns[axis], header)
            no_return = ~scan_points.any(axis=2)
            _transform(scan_points.reshape(-1, 3), header.transform)
            scan_points[no_return] = np.nan
            intensity[start:stop].reshape(grid)[:] = _row_major(columns[3], header)
            if colors is not None:
                scan_colors = colors[start:stop].reshape(*grid, 3)
                for channel in range(3):
                    scan_colors[:, :, channel] = _row_major(columns[4 + channel], header)
        start = stop
    fields = {"intensity": intensity}
    if colors is not None:
        fields["colors"] = colors
    fields["scan_index"] = scan_index
    first = scans[0][0]
    shape = (first.rows, first.columns) if len(scans) == 1 and first.rows > 1 else None
    metadata = {"encoding": "text", "ptx_scans": [header.as_metadata() for header, _ in scans]}
    return PointCloud(points, fields, shape, metadata)


def _row_major(column: np.ndarray, header: _ScanHeader) -> np.ndarray:
    """A column in the file's order (column by column) as the ``(rows, columns)`` grid."""
    return column.reshape(header.columns, header.rows).T


def _transform(points: np.ndarray, transform: np.ndarray) -> None:
    """``points`` (N, 3) <- ``[points 1] @ transform[:, :3]``, in place; exact for the identity."""
    if np.array_equal(transform, _IDENTITY):
        return
    moved = points @ transform[:3, :3]
    moved += transform[3, :3]
    points[:] = moved


def _index_dtype(scans: int) -> np.dtype:
    for dtype in (np.uint8, np.uint16):
        if scans - 1 <= np.iinfo(dtype).max:
            return np.dtype(dtype)
    return np.dtype(np.uint32)


# ----------------------------------------------------------------------------------------------
# Writing


def write_ptx(path: Path, cloud: PointCloud, encoding: str | None = None) -> None:
    """Write ``cloud`` as PTX, one scan per ``scan_index`` value (see the module docstring)."""
    notes: list[str] = []
    columns = _columns_to_write(cloud, notes)
    points = cloud.points
    no_return = ~np.isfinite(points).all(axis=1)
    at_origin = int(np.count_nonzero(~no_return & ~points.any(axis=1)))
    if at_origin:
        notes.append(
            f"{at_origin} points at exactly 0 0 0 will read back as cells without a return (NaN)"
        )
    xyz = np.where(no_return[:, None], 0.0, points)
    with open(path, "wb") as file:
        for header, rows in _scans_to_write(cloud):
            _write_header(file, header)
            # The file lists each scan column by column: the transpose of its row-major grid.
            order = rows.reshape(header.rows, header.columns).T.ravel()
            write_rows(
                file,
                [xyz[order, 0], xyz[order, 1], xyz[order, 2]] + [c[order] for c in columns],
                floats_as=np.float64,
            )
    if notes:
        warnings.warn(f"PTX changes the cloud: {'; '.join(notes)}", stacklevel=3)


def _columns_to_write(cloud: PointCloud, notes: list[str]) -> list[np.ndarray]:
    """intensity, and red green blue 0..255 when the cloud has colours; notes what changed."""
    fields = cloud.fields
    written = {"scan_index"}
    intensity = fields.get("intensity")
    if intensity is not None and intensity.ndim == 1 and intensity.dtype.kind in "biuf":
        columns = [intensity]
        written.add("intensity")
    else:
        columns = [np.zeros(len(cloud))]
        notes.append("PTX rows need an intensity; written as 0")
    colors = fields.get("colors")
    if colors is not None and colors.ndim == 2 and colors.shape[1] in (3, 4):
        converted = _colors_0_to_255(colors[:, :3], notes)
        if converted is not None:
            columns += list(converted.T)
            written.add("colors")
            if colors.shape[1] == 4:
                notes.append("colors: PTX holds no alpha; it was not written")
    dropped = [name for name in fields if name not in written]
    if dropped:
        notes.append(
            f"PTX holds x y z, intensity and red green blue only; field(s) "
            f"{', '.join(map(repr, dropped))} were not written"
        )
    return columns


def _colors_0_to_255(colors: np.ndarray, notes: list[str]) -> np.ndarray | None:
    if colors.dtype == np.uint8:
        return colors
    if colors.dtype.kind not in "biuf":
        return None
    finite = colors[np.isfinite(colors)] if colors.dtype.kind == "f" else colors
    low = finite.min(initial=0)
    high = finite.max(initial=0)
    if colors.dtype.kind in "biu" and low >= 0 and high <= 255:
        return colors.astype(np.uint8)
    if colors.dtype.kind == "f" and low >= 0 and high <= 1:
        notes.append(f"colors {colors.dtype} in [0, 1] -> 0..255 (x255, rounded)")
        scaled = np.nan_to_num(colors.astype(np.float64)) * 255
    elif colors.dtype == np.uint16 or (low >= 0 and high <= 65535):
        notes.append(f"colors {colors.dtype} -> 0..255 (/257, rounded)")
        scaled = np.nan_to_num(colors.astype(np.float64)) / 257
    else:
        notes.append(f"colors {colors.dtype} from {low} to {high} clipped to 0..255")
        scaled = np.nan_to_num(colors.astype(np.float64))
    return np.clip(np.round(scaled), 0, 255).astype(np.uint8)


def _scans_to_write(cloud: PointCloud) -> list[tuple[_ScanHeader, np.ndarray]]:
    """Each scan's header and the indices of its points in row-major grid order."""
    scan_index = cloud.fields.get("scan_index")
    groups = [np.arange(len(cloud))]
    if scan_index is not None and scan_index.ndim == 1 and scan_index.dtype.kind in "biu":
        order = np.argsort(scan_index, kind="stable")
        _, counts = np.unique(scan_index, return_counts=True)
        groups = np.split(order, np.cumsum(counts)[:-1]) if len(order) else groups
    recorded = cloud.metadata.get("ptx_scans")
    recorded = recorded if isinstance(recorded, list) and len(recorded) == len(groups) else None
    scans = []
    for k, rows in enumerate(groups):
        grid = None
        if len(groups) == 1 and cloud.shape is not None:
            grid = cloud.shape
        scan = _recorded_scan(recorded[k] if recorded else None, len(rows))
        if grid is None and scan is not None:
            grid = (scan["rows"], scan["columns"])
        grid = grid or (1, len(rows))
        position, axes = np.zeros(3), np.eye(3)
        if scan is not None:
            position = np.array(scan["scanner_position"], np.float64)
            axes = np.array(scan["scanner_axes"], np.float64)
        header = _ScanHeader(grid[1], grid[0], position, axes, _IDENTITY)
        scans.append((header, rows))
    return scans


def _recorded_scan(scan: Any, count: int) -> dict[str, Any] | None:
    """A scan of ``metadata["ptx_scans"]`` if it is well formed and holds ``count`` points."""
    try:
        columns, rows = int(scan["columns"]), int(scan["rows"])
        position = np.asarray(scan["scanner_position"], np.float64)
        axes = np.asarray(scan["scanner_axes"], np.float64)
    except (TypeError, KeyError, ValueError):
        return None
    if columns * rows != count or position.shape != (3,) or axes.shape != (3, 3):
        return None
    if not (np.isfinite(position).all() and np.isfinite(axes).all()):
        return None
    return scan


def _write_header(file: BinaryIO, header: _ScanHeader) -> None:
    lines = [str(header.columns), str(header.rows), _numbers(header.position)]
    lines += [_numbers(axis) for axis in header.axes]
    lines += [_numbers(row) for row in header.transform]
    file.write(("\n".join(lines) + "\n").encode("ascii"))


def _numbers(values: np.ndarray) -> str:
    """Numbers as the shortest text that reads back as the same float64; whole ones as integers."""
    return " ".join(str(int(v)) if v == int(v) and abs(v) < 2**53 else repr(float(v)) for v in values)


register(
    Format(
        name="ptx",
        description="Leica PTX terrestrial scans: several organised scans, each with its transform",
        suffixes=(".ptx",),
        read=read_ptx,
        write=write_ptx,
        encodings=("text",),
        aliases={"ascii": "text"},
        signature=looks_like_ptx,
    )
)
