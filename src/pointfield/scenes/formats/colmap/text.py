"""Reading COLMAP's text model files: ``cameras.txt``, ``images.txt``, ``points3D.txt``.

One camera per line (``CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]``), two lines per image (``IMAGE_ID
QW QX QY QZ TX TY TZ CAMERA_ID NAME``, then its ``X Y POINT3D_ID`` triples, possibly empty), one
point per line (``POINT3D_ID X Y Z R G B ERROR TRACK[]``); lines starting with ``#`` are
comments. Errors name the file and the line.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pointfield.errors import FormatError
from pointfield.scenes.formats.colmap.model import (
    MAX_ID,
    PARAMETER_COUNT,
    ColmapCamera,
    ColmapImage,
    add_camera,
    add_image,
)


def _data_lines(path: Path):
    """``(line number, text)`` of every line, comments and blank lines included (images.txt needs them)."""
    try:
        text = path.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise FormatError(path, "file not found") from None
    except UnicodeDecodeError as error:
        raise FormatError(path, f"not UTF-8 text (byte {error.start})") from None
    return list(enumerate(text.splitlines(), start=1))


def _parse(path: Path, line_number: int, convert, token: str, what: str):
    try:
        return convert(token)
    except (ValueError, OverflowError):
        raise FormatError(
            path, f"line {line_number}: {what} {token[:30]!r} is not a valid {convert.__name__}"
        ) from None


def read_cameras_text(path: Path) -> dict[int, ColmapCamera]:
    cameras = {}
    for number, line in _data_lines(path):
        tokens = line.split()
        if not tokens or tokens[0].startswith("#"):
            continue
        if len(tokens) < 4:
            raise FormatError(
                path,
                f"line {number}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[], found {len(tokens)} fields",
            )
        camera_id = _parse(path, number, int, tokens[0], "camera id")
        model = tokens[1]
        if model not in PARAMETER_COUNT:
            raise FormatError(path, f"line {number}: unknown camera model {model[:30]!r}")
        width = _parse(path, number, int, tokens[2], "width")
        height = _parse(path, number, int, tokens[3], "height")
        if len(tokens) - 4 != PARAMETER_COUNT[model]:
            raise FormatError(
                path,
                f"line {number}: {model} has {PARAMETER_COUNT[model]} parameters, found {len(tokens) - 4}",
            )
        params = np.array([_parse(path, number, float, t, "parameter") for t in tokens[4:]])
        add_camera(cameras, ColmapCamera(camera_id, model, width, height, params), path)
    return cameras


def read_images_text(path: Path) -> dict[int, ColmapImage]:
    images = {}
    lines = iter(_data_lines(path))
    for number, line in lines:
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        tokens = stripped.split(maxsplit=9)
        if len(tokens) < 10:
            raise FormatError(
                path,
                f"line {number}: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, found {len(tokens)} fields",
            )
        image_id = _parse(path, number, int, tokens[0], "image id")
        values = [_parse(path, number, float, t, "pose value") for t in tokens[1:8]]
        camera_id = _parse(path, number, int, tokens[8], "camera id")
        # The keypoint line always follows its image line, even when empty.
        keypoint_number, keypoint_line = next(lines, (number + 1, ""))
        fields = keypoint_line.split()
        if len(fields) % 3:
            raise FormatError(
                path,
                f"line {keypoint_number}: 2D points come as X Y POINT3D_ID triples, found {len(fields)} values",
            )
        try:
            table = np.array(fields, dtype=np.float64).reshape(-1, 3)
        except ValueError:
            raise FormatError(path, f"line {keypoint_number}: 2D points must be numbers") from None
        if not np.all(np.isfinite(table)) or np.any(table[:, 2] != np.round(table[:, 2])):
            raise FormatError(
                path, f"line {keypoint_number}: 2D points must be finite with whole-number point ids"
            )
        image = ColmapImage(
            image_id,
            np.array(values[:4]),
            np.array(values[4:]),
            camera_id,
            tokens[9],
            table[:, :2],
            table[:, 2].astype(np.int64),
        )
        add_image(images, image, path)
    return images


def read_points_text(path: Path) -> tuple[np.ndarray, ...]:
    ids, xyz, colors, errors = [], [], [], []
    for number, line in _data_lines(path):
        tokens = line.split(maxsplit=8)
        if not tokens or tokens[0].startswith("#"):
            continue
        if len(tokens) < 8:
            raise FormatError(
                path,
                f"line {number}: expected POINT3D_ID X Y Z R G B ERROR TRACK[], found {len(tokens)} fields",
            )
        ids.append(_parse(path, number, int, tokens[0], "point id"))
        if not 0 <= ids[-1] <= MAX_ID:
            raise FormatError(path, f"line {number}: point id {ids[-1]} is out of range")
        xyz.append([_parse(path, number, float, t, "coordinate") for t in tokens[1:4]])
        rgb = [_parse(path, number, int, t, "colour") for t in tokens[4:7]]
        if not all(0 <= c <= 255 for c in rgb):
            raise FormatError(path, f"line {number}: colour {rgb} is outside 0..255")
        colors.append(rgb)
        errors.append(_parse(path, number, float, tokens[7], "error"))
    return (
        np.array(ids, dtype=np.int64),
        np.array(xyz, dtype=np.float64).reshape(-1, 3),
        np.array(colors, dtype=np.uint8).reshape(-1, 3),
        np.array(errors, dtype=np.float64),
    )
