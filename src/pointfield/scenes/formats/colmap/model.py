"""What a COLMAP sparse model holds, as pointfield reads it: cameras, registered images, points.

:func:`add_camera` and :func:`add_image` are the checks both encodings make on each record.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pointfield.errors import FormatError

# COLMAP model id -> (name, number of parameters); every model COLMAP defines, so that binary
# files with models pointfield does not use can still be walked (and rejected by name).
COLMAP_MODELS = {
    0: ("SIMPLE_PINHOLE", 3),
    1: ("PINHOLE", 4),
    2: ("SIMPLE_RADIAL", 4),
    3: ("RADIAL", 5),
    4: ("OPENCV", 8),
    5: ("OPENCV_FISHEYE", 8),
    6: ("FULL_OPENCV", 12),
    7: ("FOV", 5),
    8: ("SIMPLE_RADIAL_FISHEYE", 4),
    9: ("RADIAL_FISHEYE", 5),
    10: ("THIN_PRISM_FISHEYE", 12),
    11: ("RAD_TAN_THIN_PRISM_FISHEYE", 16),
}
PARAMETER_COUNT = {name: count for name, count in COLMAP_MODELS.values()}
# Point ids are stored as u64 but used as int64 (images.bin keeps them as i64).
MAX_ID = (1 << 63) - 1


@dataclass
class ColmapCamera:
    """A camera: its COLMAP ``model`` name, image size in pixels, ``params`` in that model's order."""

    id: int
    model: str
    width: int
    height: int
    params: np.ndarray


@dataclass
class ColmapImage:
    """A registered image: world-to-camera ``quaternion`` (w, x, y, z) and ``translation``, and its
    2D keypoints ``points2d`` ``(K, 2)`` (pixel centres at +0.5) with ``point3d_ids`` ``(K,)`` (-1 = none)."""

    id: int
    quaternion: np.ndarray
    translation: np.ndarray
    camera_id: int
    name: str
    points2d: np.ndarray
    point3d_ids: np.ndarray


@dataclass
class ColmapModel:
    """A COLMAP sparse model as stored; ``points`` ``(P, 3)``, ``colors`` uint8 ``(P, 3)``, ``errors`` ``(P,)``."""

    folder: Path
    encoding: str
    cameras: dict[int, ColmapCamera]
    images: dict[int, ColmapImage]
    point_ids: np.ndarray
    points: np.ndarray
    colors: np.ndarray
    errors: np.ndarray


def no_points() -> tuple[np.ndarray, ...]:
    """The ``(ids, xyz, colors, errors)`` columns of a model without ``points3D``."""
    return np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3), np.uint8), np.zeros(0)


def add_camera(cameras: dict[int, ColmapCamera], camera: ColmapCamera, path: Path) -> None:
    if camera.id in cameras:
        raise FormatError(path, f"camera id {camera.id} appears twice")
    if not 1 <= camera.width <= 1 << 16 or not 1 <= camera.height <= 1 << 16:
        raise FormatError(
            path, f"camera {camera.id}: image size {camera.width}x{camera.height} is out of range"
        )
    if not np.all(np.isfinite(camera.params)):
        raise FormatError(path, f"camera {camera.id}: parameters contain NaN or infinity")
    cameras[camera.id] = camera


def add_image(images: dict[int, ColmapImage], image: ColmapImage, path: Path) -> None:
    if image.id in images:
        raise FormatError(path, f"image id {image.id} appears twice")
    images[image.id] = image
