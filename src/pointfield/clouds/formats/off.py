"""OFF (Object File Format) meshes, the format of ModelNet: OFF, COFF, NOFF and CNOFF.

An OFF file is text::

    OFF                      <- keyword: OFF, COFF (vertex colours), NOFF (normals), CNOFF (both)
    # comments run from '#' to the end of the line
    4 4 0                    <- vertex count, face count, edge count (ignored)
    0 0 0                    <- one vertex per line: x y z [nx ny nz] [r g b [a]]
    1 0 0
    0 1 0
    0 0 1
    3 0 1 2                  <- one face per line: k, then k vertex indices (from 0),
    3 0 1 3 255 0 0          <-   optionally followed by a colour r g b [a]
    3 0 2 3
    3 1 2 3

Real ModelNet files often glue the counts onto the keyword (``OFF3514 3546 0``); that reads too,
as does ``OFF 4 4 0`` on one line. Values may be separated by any spaces, tabs and line ends
(CRLF included), and blank lines may appear anywhere.

How a file maps onto a :class:`Mesh`: vertices are ``points`` in float64 (text carries no dtype);
``normals`` and ``colors`` per vertex; ``faces`` is ``(F, K)`` int32 when every face has K
corners (``(F, 3)`` for ModelNet's triangles), else a 1-D object array of index arrays; per-face
colours are ``face_fields["colors"]``. Colours written as integers (no ``.`` or exponent in the
first line's colour values) read as uint8 when in 0..255 (uint16 up to 65535), float colours
stay float64. A file with no faces reads as a plain :class:`PointCloud`.

Checks: the declared vertex and face counts against the lines present (a header claiming 10**12
vertices in a small file is a FormatError before anything is allocated for them), every line's
number of values, and every face index against the vertex count.

Writing: the keyword follows the fields (``COFF`` with ``colors``, ``NOFF`` with ``normals``,
``CNOFF`` with both), vertices and faces as above with floats in their shortest round-trip text
(reading back gives ``float64(value)``), face ``colors`` appended to the face lines. A plain
PointCloud is written as vertices with 0 faces. Fields OFF cannot hold are left out with a
warning.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.formats.ascii import numbers_by_line, write_rows
from pointfield.clouds.formats.registry import Format, register
from pointfield.clouds.mesh import Mesh
from pointfield.errors import FormatError

# Values per vertex line each keyword allows: x y z, then normals (N), then colours (C) as
# r g b or r g b a.
VERTEX_WIDTHS = {"OFF": (3,), "COFF": (6, 7), "NOFF": (6,), "CNOFF": (9, 10)}

# Lines before the keyword and counts (blank lines, comments); more than this is not an OFF file.
MAX_HEADER_LINES = 1000

_KEYWORD = re.compile(rb"(CNOFF|NOFF|COFF|OFF)(?=[\s0-9]|$)")
_COMMENT = re.compile(rb"#[^\n]*")
_COUNT = re.compile(rb"[0-9]+")


def looks_like_off(head: bytes) -> bool:
    """The file starts with an OFF keyword followed by whitespace or a digit (``OFF3514 ...``)."""
    return _KEYWORD.match(head) is not None


def read_off(path: Path) -> Mesh | PointCloud:
    """Read an OFF / COFF / NOFF / CNOFF file (see the module docstring)."""
    data = path.read_bytes()
    keyword, vertex_count, face_count, body_start, body_line = _read_header(data, path)
    body = data[body_start:]
    if b"#" in body:
        body = _COMMENT.sub(b"", body)
    values, counts, line_numbers, line_starts = numbers_by_line(body, path, body_line)
    if len(counts) < vertex_count + face_count:
        raise FormatError(
            path,
            f"the header declares {vertex_count} vertices and {face_count} faces but only "
            f"{len(counts)} line(s) of numbers follow",
        )
    if len(counts) > vertex_count + face_count:
        warnings.warn(
            f"{path}: {len(counts) - vertex_count - face_count} line(s) after the last face "
            f"were ignored",
            stacklevel=3,
        )

    vertex_counts = counts[:vertex_count]
    width = int(vertex_counts[0]) if vertex_count else VERTEX_WIDTHS[keyword][0]
    wrong = np.flatnonzero(vertex_counts != width)
    if width not in VERTEX_WIDTHS[keyword] or len(wrong):
        line = line_numbers[wrong[0]] if len(wrong) else line_numbers[0]
        found = vertex_counts[wrong[0]] if len(wrong) else width
        allowed = " or ".join(map(str, VERTEX_WIDTHS[keyword]))
        raise FormatError(
            path, f"line {line}: {keyword} vertices have {allowed} values; this one has {found}"
        )
    vertex_values = values[: vertex_count * width].reshape(vertex_count, width)
    points = np.ascontiguousarray(vertex_values[:, :3])
    fields = {}
    color_start = 3
    if "N" in keyword:
        fields["normals"] = np.ascontiguousarray(vertex_values[:, 3:6])
        color_start = 6
    if "C" in keyword:
        first_tokens = _line_tokens(body, line_starts[0]) if vertex_count else []
        fields["colors"] = _colors(vertex_values[:, color_start:], first_tokens[color_start:])

    if face_count == 0:
        return PointCloud(points, fields, None, {"encoding": "ascii", "keyword": keyword})
    face_lines = slice(vertex_count, vertex_count + face_count)
    faces, face_colors = _faces(
        values[vertex_count * width :],
        counts[face_lines],
        line_numbers[face_lines],
        vertex_count,
        path,
    )
    face_fields = {}
    if face_colors is not None:
        first_tokens = _line_tokens(body, line_starts[vertex_count])
        face_fields["colors"] = _colors(face_colors, first_tokens[-face_colors.shape[1] :])
    return Mesh(
        points,
        fields,
        None,
        {"encoding": "ascii", "keyword": keyword},
        faces=faces,
        face_fields=face_fields,
    )


def _read_header(data: bytes, path: Path) -> tuple[str, int, int, int, int]:
    """``(keyword, vertex count, face count, byte offset of the body, its line number)``."""
    keyword = None
    counts: list[bytes] = []
    position, line_number = 0, 0
    while position < len(data) and len(counts) == 0:
        end = data.find(b"\n", position)
        end = len(data) if end < 0 else end
        line = data[position:end].split(b"#", 1)[0].strip()
        line_number += 1
        position = end + 1
        if line_number > MAX_HEADER_LINES:
            raise FormatError(path, f"no OFF header in the first {MAX_HEADER_LINES} lines")
        if not line:
            continue
        if keyword is None:
            match = _KEYWORD.match(line)
            if match is None:
                raise FormatError(
                    path,
                    f"line {line_number}: expected the keyword OFF, COFF, NOFF or CNOFF, found "
                    f"{line[:40]!r}",
                )
            keyword = match.group(1).decode()
            line = line[match.end() :].strip()  # ModelNet's "OFF3514 3546 0"
            if not line:
                continue
        counts = line.split()
    if keyword is None:
        raise FormatError(path, "empty file: no OFF keyword")
    if not counts:
        raise FormatError(path, "the header ends before the vertex and face counts")
    if counts[0].upper() == b"BINARY":
        raise FormatError(path, "binary OFF is not supported; pointfield reads text OFF")
    if len(counts) not in (2, 3) or not all(_COUNT.fullmatch(c) for c in counts):
        raise FormatError(
            path,
            f"line {line_number}: expected the counts 'vertices faces edges' as non-negative "
            f"integers, found {b' '.join(counts)[:60]!r}",
        )
    return keyword, int(counts[0]), int(counts[1]), min(position, len(data)), line_number + 1


def _faces(
    values: np.ndarray, counts: np.ndarray, line_numbers: np.ndarray, vertex_count: int, path: Path
) -> tuple[np.ndarray, np.ndarray | None]:
    """Faces from their lines' values: ``(faces, colours or None)``.

    Each line is ``k i_1 ... i_k [r g b [a]]``. When every face has the same k the faces are an
    ``(F, k)`` array (the fast path, all of ModelNet); otherwise a 1-D object array.
    """
    offsets = np.concatenate(([0], np.cumsum(counts)[:-1]))
    values = values[: int(counts.sum())]
    corners = values[offsets]
    extra = counts - 1 - corners  # colour values after the indices
    bad = np.flatnonzero(
        (corners != np.floor(corners)) | (corners < 3) | ~np.isin(extra, (0, 3, 4))
    )
    if len(bad):
        i = bad[0]
        raise FormatError(
            path,
            f"line {line_numbers[i]}: a face is 'k i_1 ... i_k [r g b [a]]' with k >= 3; this "
            f"line has {counts[i]} values starting with {values[offsets[i]]:g}",
        )
    if not (extra == extra[0]).all():
        i = np.flatnonzero(extra != extra[0])[0]
        raise FormatError(
            path,
            f"line {line_numbers[i]}: this face has {int(extra[i])} colour values, the first "
            f"face {int(extra[0])}",
        )
    colors_per_face = int(extra[0])
    is_index = np.ones(len(values), bool)
    is_index[offsets] = False
    if colors_per_face:
        color_positions = (offsets + 1 + corners.astype(np.int64))[:, None] + np.arange(
            colors_per_face
        )
        is_index[color_positions] = False
        face_colors = values[color_positions]
    else:
        face_colors = None
    indices = values[is_index]
    outside = np.flatnonzero(
        (indices != np.floor(indices)) | (indices < 0) | (indices >= vertex_count)
    )
    if len(outside):
        face = np.searchsorted(np.cumsum(corners), outside[0], side="right")
        raise FormatError(
            path,
            f"line {line_numbers[face]}: vertex index {indices[outside[0]]:g} is not one of the "
            f"{vertex_count} vertices (0..{vertex_count - 1})",
        )
    index_dtype = np.int32 if vertex_count <= np.iinfo(np.int32).max else np.int64
    indices = indices.astype(index_dtype)
    if (corners == corners[0]).all():
        return indices.reshape(len(counts), int(corners[0])), face_colors
    ragged = np.empty(len(counts), object)
    ragged[:] = np.split(indices, np.cumsum(corners.astype(np.int64))[:-1])
    return ragged, face_colors


def _line_tokens(body: bytes, start: int) -> list[bytes]:
    end = body.find(b"\n", start)
    return body[start : len(body) if end < 0 else end].split()


def _colors(values: np.ndarray, first_tokens: list[bytes]) -> np.ndarray:
    """Colour values as uint8 / uint16 when written as integers in range, else float64."""
    integer_text = first_tokens and not any(re.search(rb"[.eEnNiI]", t) for t in first_tokens)
    if integer_text and np.array_equal(values, np.floor(values)) and (values >= 0).all():
        high = values.max(initial=0)
        if high <= 255:
            return values.astype(np.uint8)
        if high <= 65535:
            return values.astype(np.uint16)
    return np.ascontiguousarray(values)


# ----------------------------------------------------------------------------------------------
# Writing


def write_off(path: Path, cloud: PointCloud, encoding: str | None = None) -> None:
    """Write a Mesh (or a PointCloud, as vertices with no faces) as OFF text."""
    columns = list(cloud.points.T)
    written = set()
    for name, widths in (("normals", (3,)), ("colors", (3, 4))):
        values = cloud.fields.get(name)
        if _is_numeric_matrix(values, widths):
            columns.extend(values.T)
            written.add(name)
    keyword = ("C" if "colors" in written else "") + ("N" if "normals" in written else "") + "OFF"
    _warn_dropped([name for name in cloud.fields if name not in written], "vertex")
    faces = getattr(cloud, "faces", np.zeros((0, 3), np.int64))
    face_fields = getattr(cloud, "face_fields", {})
    face_colors = face_fields.get("colors")
    if not _is_numeric_matrix(face_colors, (3, 4)):
        face_colors = None
    _warn_dropped(
        [n for n in face_fields if not (n == "colors" and face_colors is not None)], "face"
    )
    with open(path, "wb") as file:
        file.write(f"{keyword}\n{len(cloud)} {len(faces)} 0\n".encode())
        write_rows(file, columns, floats_as=np.float64)
        if faces.dtype != object:
            face_columns = [np.full(len(faces), faces.shape[1], np.int64), *faces.T]
            if face_colors is not None:
                face_columns.extend(face_colors.T)
            write_rows(file, face_columns, floats_as=np.float64)
        else:
            file.write(_ragged_face_lines(faces, face_colors))


def _is_numeric_matrix(values: np.ndarray | None, widths: tuple[int, ...]) -> bool:
    return (
        values is not None
        and values.ndim == 2
        and values.shape[1] in widths
        and values.dtype.kind in "biuf"
    )


def _warn_dropped(names: list[str], kind: str) -> None:
    if names:
        warnings.warn(
            f"OFF holds {kind} normals and colours only; {kind} field(s) "
            f"{', '.join(map(repr, names))} were not written",
            stacklevel=4,
        )


def _ragged_face_lines(faces: np.ndarray, colors: np.ndarray | None) -> bytes:
    """Face lines for polygons of different sizes (the rare case: a Python loop is fine)."""
    lines = []
    for i, face in enumerate(faces):
        numbers = [len(face), *(int(v) for v in face)]
        if colors is not None:
            numbers.extend(_number_text(v) for v in colors[i])
        lines.append(" ".join(map(str, numbers)))
    return ("\n".join(lines) + "\n").encode() if lines else b""


def _number_text(value: np.generic) -> str:
    return str(int(value)) if value.dtype.kind in "biu" else repr(float(value))


register(
    Format(
        name="off",
        description="OFF / COFF / NOFF / CNOFF text meshes (ModelNet)",
        suffixes=(".off",),
        read=read_off,
        write=write_off,
        encodings=("ascii",),
        signature=looks_like_off,
        holds_faces=True,
    )
)
