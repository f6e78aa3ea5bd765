"""Reading COLMAP's binary model files: ``cameras.bin``, ``images.bin``, ``points3D.bin``.

Layout (little-endian), as COLMAP's ``read_write_model.py`` documents it:

- cameras.bin: u64 count; per camera i32 id, i32 model id, u64 width, u64 height, f64 params[].
- images.bin: u64 count; per image i32 id, f64 qw qx qy qz, f64 tx ty tz, i32 camera id,
  NUL-terminated name, u64 n, then n x (f64 x, f64 y, i64 point3D id).
- points3D.bin: u64 count; per point u64 id, f64 x y z, u8 r g b, f64 error, u64 track length,
  then that many (i32 image id, i32 point2D index).

Every count is checked against the bytes present before anything is allocated.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from pointfield.errors import FormatError
from pointfield.scenes.formats.colmap.model import (
    COLMAP_MODELS,
    MAX_ID,
    ColmapCamera,
    ColmapImage,
    add_camera,
    add_image,
)


class _Buffer:
    """Bounds-checked little-endian reads from a file's bytes."""

    def __init__(self, path: Path):
        self.path = path
        try:
            self.data = path.read_bytes()
        except FileNotFoundError:
            raise FormatError(path, "file not found") from None
        self.offset = 0

    @property
    def remaining(self) -> int:
        return len(self.data) - self.offset

    def take(self, layout: str, what: str) -> tuple:
        size = struct.calcsize(layout)
        if size > self.remaining:
            raise FormatError(
                self.path,
                f"truncated: {what} needs {size} bytes at offset {self.offset}, {self.remaining} left",
            )
        values = struct.unpack_from(layout, self.data, self.offset)
        self.offset += size
        return values

    def count(self, minimum_record: int, what: str) -> int:
        (count,) = self.take("<Q", f"number of {what}")
        if count * minimum_record > self.remaining:
            raise FormatError(
                self.path,
                f"declares {count} {what} of at least {minimum_record} bytes but only {self.remaining} bytes follow",
            )
        return count

    def array(self, dtype: np.dtype, count: int, what: str) -> np.ndarray:
        size = count * dtype.itemsize
        if size > self.remaining:
            raise FormatError(
                self.path,
                f"truncated: {what} needs {size} bytes at offset {self.offset}, {self.remaining} left",
            )
        values = np.frombuffer(self.data, dtype=dtype, count=count, offset=self.offset)
        self.offset += size
        return values

    def name(self, what: str) -> str:
        end = self.data.find(b"\x00", self.offset)
        if end < 0:
            raise FormatError(self.path, f"truncated: {what} has no terminating NUL byte")
        raw = self.data[self.offset : end]
        self.offset = end + 1
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            raise FormatError(self.path, f"{what} is not UTF-8: {raw[:40]!r}") from None


_POINT2D = np.dtype([("xy", "<f8", 2), ("point3d_id", "<i8")])


def read_cameras_binary(path: Path) -> dict[int, ColmapCamera]:
    buffer = _Buffer(path)
    cameras = {}
    for index in range(buffer.count(24, "cameras")):
        camera_id, model_id, width, height = buffer.take("<iiQQ", f"camera {index}")
        if model_id not in COLMAP_MODELS:
            raise FormatError(path, f"camera {camera_id}: unknown camera model id {model_id}")
        model, parameter_count = COLMAP_MODELS[model_id]
        params = buffer.array(np.dtype("<f8"), parameter_count, f"camera {camera_id} parameters").astype(
            np.float64
        )
        add_camera(cameras, ColmapCamera(camera_id, model, width, height, params), path)
    return cameras


def read_images_binary(path: Path) -> dict[int, ColmapImage]:
    buffer = _Buffer(path)
    images = {}
    for index in range(buffer.count(73, "images")):
        image_id, qw, qx, qy, qz, tx, ty, tz, camera_id = buffer.take("<i7di", f"image {index}")
        name = buffer.name(f"image {image_id} name")
        (point_count,) = buffer.take("<Q", f"image {image_id} number of 2D points")
        if point_count * _POINT2D.itemsize > buffer.remaining:
            raise FormatError(
                path,
                f"image {image_id} ({name}): declares {point_count} 2D points but only {buffer.remaining} bytes follow",
            )
        keypoints = buffer.array(_POINT2D, point_count, f"image {image_id} 2D points")
        image = ColmapImage(
            image_id,
            np.array([qw, qx, qy, qz]),
            np.array([tx, ty, tz]),
            camera_id,
            name,
            keypoints["xy"].astype(np.float64),
            keypoints["point3d_id"].astype(np.int64),
        )
        add_image(images, image, path)
    return images


def read_points_binary(path: Path) -> tuple[np.ndarray, ...]:
    buffer = _Buffer(path)
    count = buffer.count(51, "points")
    ids = np.empty(count, np.int64)
    xyz = np.empty((count, 3), np.float64)
    colors = np.empty((count, 3), np.uint8)
    errors = np.empty(count, np.float64)
    for index in range(count):
        point_id, x, y, z, r, g, b, error, track_length = buffer.take("<Q3d3BdQ", f"point {index}")
        if point_id > MAX_ID:
            raise FormatError(path, f"point {index}: id {point_id} is out of range")
        if track_length * 8 > buffer.remaining:
            raise FormatError(
                path,
                f"point {point_id}: declares a track of {track_length} but only {buffer.remaining} bytes follow",
            )
        buffer.offset += track_length * 8
        ids[index], xyz[index], colors[index], errors[index] = point_id, (x, y, z), (r, g, b), error
    return ids, xyz, colors, errors
