"""Checks every scene reader shares: JSON, numbers, rigid poses, image headers, .npy headers, missing images.

Each check raises :class:`~pointfield.errors.FormatError` naming the file and, where there is one,
the frame, so a bad dataset is reported as "transforms.json: frame 12 (./train/r_12): ..." and
never as a numpy or json traceback.
"""

from __future__ import annotations

import json
import math
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pointfield.errors import FormatError

ROTATION_TOLERANCE = 1e-3
"""Largest ``|R^T R - I|`` entry accepted as a rotation: datasets print poses as float32 (1e-7) or
with a few digits; a scaled or sheared matrix is off by far more."""

MAX_IMAGE_SIDE = 1 << 16
"""Largest width or height a camera may declare (PNG's limit is larger, no real camera's is)."""


def load_json(path: Path) -> dict[str, Any]:
    """The JSON object in ``path``; malformed, non-UTF-8 or non-object files raise FormatError."""
    try:
        text = Path(path).read_bytes().decode("utf-8-sig")
        document = json.loads(text)
    except FileNotFoundError:
        raise FormatError(path, "file not found") from None
    except UnicodeDecodeError as error:
        raise FormatError(path, f"not UTF-8 text ({error.reason} at byte {error.start})") from None
    except json.JSONDecodeError as error:
        raise FormatError(
            path, f"malformed JSON at line {error.lineno} column {error.colno}: {error.msg}"
        ) from None
    except RecursionError:
        raise FormatError(path, "malformed JSON: nested too deeply") from None
    if not isinstance(document, dict):
        raise FormatError(path, f"expected a JSON object at the top level, found {type(document).__name__}")
    return document


def number(value: Any, path: Path, where: str, *, positive: bool = False) -> float:
    """``value`` as a finite float (JSON numbers only: no strings, no booleans)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise FormatError(path, f"{where}: expected a number, found {_shown(value)}")
    result = float(value)
    if not math.isfinite(result):
        raise FormatError(path, f"{where}: {result} is not a finite number")
    if positive and result <= 0:
        raise FormatError(path, f"{where}: must be positive, found {result}")
    return result


def image_side(value: Any, path: Path, where: str) -> int:
    """A declared image width or height: a whole number in [1, MAX_IMAGE_SIDE]."""
    side = number(value, path, where, positive=True)
    if side != int(side) or side > MAX_IMAGE_SIDE:
        raise FormatError(
            path, f"{where}: image size must be a whole number of pixels up to {MAX_IMAGE_SIDE}, found {side}"
        )
    return int(side)


def pose_matrix(value: Any, path: Path, where: str) -> np.ndarray:
    """A JSON 4x4 (or 3x4) camera-to-world matrix -> float64 ``(3, 4)``, checked and snapped rigid."""
    if (
        not isinstance(value, list)
        or len(value) not in (3, 4)
        or not all(isinstance(row, list) and len(row) == 4 for row in value)
    ):
        raise FormatError(path, f"{where}: transform_matrix must be 4 rows (or 3) of 4 numbers")
    matrix = np.array([[number(x, path, where) for x in row] for row in value], dtype=np.float64)
    if len(matrix) == 4 and not np.allclose(matrix[3], [0, 0, 0, 1], atol=1e-6):
        raise FormatError(
            path, f"{where}: last row of transform_matrix is {matrix[3].tolist()}, expected [0, 0, 0, 1]"
        )
    matrix[:3, :3] = rigid_rotation(matrix[:3, :3], path, where)
    return matrix[:3]


def rigid_rotation(rotation: np.ndarray, path: Path, where: str) -> np.ndarray:
    """The exact rotation nearest ``rotation`` ``(3, 3)``, after checking it is one within tolerance.

    Raises unless the matrix is finite, orthonormal within :data:`ROTATION_TOLERANCE` and not a
    reflection. Files print poses to float32 or a few digits, so ``R^T R`` is only about
    ``I + 1e-6``; snapping to ``U V^T`` of the SVD (a change at the file's own precision) makes
    ``R^T`` the exact inverse that projection, view matrices and rays rely on.
    """
    if not np.all(np.isfinite(rotation)):
        raise FormatError(path, f"{where}: pose contains NaN or infinity")
    error = np.abs(rotation.T @ rotation - np.eye(3)).max()
    if error > ROTATION_TOLERANCE:
        raise FormatError(
            path, f"{where}: pose rotation is not rigid (|R^T R - I| = {error:.3g}; scaled or sheared?)"
        )
    if np.linalg.det(rotation) < 0:
        raise FormatError(path, f"{where}: pose rotation has determinant -1 (a reflection, not a rotation)")
    u, _, vt = np.linalg.svd(rotation)
    return u @ vt


def image_size(path: Path, where: str) -> tuple[int, int] | None:
    """``(width, height)`` read from the image file's header only, or None if the file is missing."""
    from PIL import Image

    if not path.is_file():
        return None
    try:
        with Image.open(path) as image:
            return image.size
    except Exception as error:  # noqa: BLE001 - re-raised as FormatError; Pillow raises many types (OSError, SyntaxError, ValueError, ...)
        raise FormatError(path, f"{where}: not a readable image ({type(error).__name__}: {error})") from None


@dataclass(frozen=True)
class MissingImage:
    """A frame whose image file does not exist: which file lists it, as which frame, and where it was sought."""

    source: Path
    frame: int
    name: str
    expected: Path


MISSING_IMAGE_POLICIES = ("skip", "error", "keep")


def keep_frames(has_image: list[bool], missing: list[MissingImage], policy: str, source: Path) -> np.ndarray:
    """Frames to keep under the missing-image ``policy``, as a boolean mask.

    ``"skip"`` (default) drops frames without an image with ONE warning that counts them, and
    raises if no frame has one; ``"error"`` raises on the first missing image; ``"keep"`` keeps
    every frame (a poses-only scene, e.g. to render new views at a dataset's test cameras).
    """
    if policy not in MISSING_IMAGE_POLICIES:
        raise ValueError(f"missing_images must be one of {MISSING_IMAGE_POLICIES}, got {policy!r}")
    keep = np.asarray(has_image, dtype=bool)
    if policy == "keep" or not missing:
        return np.ones(len(keep), dtype=bool)
    first = missing[0]
    if policy == "error" or not keep.any():
        lead = "no frame has its image; " if policy == "skip" else ""
        raise FormatError(
            first.source, f"{lead}frame {first.frame} ({first.name}): image {first.expected} not found"
        )
    warnings.warn(
        f"{source}: {len(missing)} of {len(keep)} frames have no image file and were skipped "
        f"(first: frame {first.frame}, {first.expected})",
        stacklevel=4,
    )
    return keep


def _shown(value: Any) -> str:
    text = json.dumps(value) if isinstance(value, (str, bool, type(None))) else type(value).__name__
    return text if len(text) <= 40 else text[:37] + "..."
