"""COLMAP sparse models: ``cameras``, ``images``, ``points3D`` in ``.bin`` or ``.txt``.

COLMAP already uses pointfield's camera convention (x right, y down, looking down +z; pixel
centres at +0.5), but stores each image's pose **world-to-camera** as a unit quaternion
``(qw, qx, qy, qz)`` and a translation t: ``X_camera = R(q) X_world + t``. The reader inverts
it, ``R_c2w = R(q)^T`` and camera centre ``C = -R(q)^T t``.

Camera models read: SIMPLE_PINHOLE (f, cx, cy), PINHOLE (fx, fy, cx, cy), SIMPLE_RADIAL
(f, cx, cy, k), RADIAL (f, cx, cy, k1, k2), OPENCV (fx, fy, cx, cy, k1, k2, p1, p2) and
OPENCV_FISHEYE (fx, fy, cx, cy, k1, k2, k3, k4); radial ones become OPENCV with the missing
coefficients zero. A scene holds one model family, so perspective and fisheye cameras cannot mix.

Binary layout (little-endian), as COLMAP's ``read_write_model.py`` documents it:

- cameras.bin: u64 count; per camera i32 id, i32 model id, u64 width, u64 height, f64 params[].
- images.bin: u64 count; per image i32 id, f64 qw qx qy qz, f64 tx ty tz, i32 camera id,
  NUL-terminated name, u64 n, then n x (f64 x, f64 y, i64 point3D id).
- points3D.bin: u64 count; per point u64 id, f64 x y z, u8 r g b, f64 error, u64 track length,
  then that many (i32 image id, i32 point2D index).

Frames are ordered by image name, points by point id. Every count is checked against the bytes present before
anything is allocated. Images are looked for in ``images=`` if given, else in ``images/`` or any
sibling folder holding them, up to two folders above the model (``sparse/0`` -> dataset root).
Near and far per frame: the 0.1 and 99.9 percentiles of the depths of the points that project
into that image (as LLFF computes its bounds).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from pointfield.clouds.cloud import PointCloud
from pointfield.errors import FormatError
from pointfield.scenes.cameras import Cameras
from pointfield.scenes.formats.registry import SceneFormat, register
from pointfield.scenes.formats.validation import (
    ROTATION_TOLERANCE,
    MissingImage,
    image_size,
    keep_frames,
    rigid_rotation,
)
from pointfield.scenes.scene import Frame, Scene

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
MAX_ID = (1 << 63) - 1
SUPPORTED_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "OPENCV_FISHEYE")


@dataclass
class ColmapCamera:
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


def find_model_folder(path: Path) -> Path | None:
    """The folder holding a COLMAP model: ``path`` itself, ``path/sparse/0``, ``path/sparse``, or a subfolder."""
    candidates = [path, path / "sparse" / "0", path / "sparse"]
    if path.is_dir():
        candidates += sorted(p for p in path.iterdir() if p.is_dir() and not p.name.startswith("."))
    for folder in candidates:
        if _model_encoding(folder) is not None:
            return folder
    return None


def _model_encoding(folder: Path) -> str | None:
    if (folder / "cameras.bin").is_file() and (folder / "images.bin").is_file():
        return "binary"
    if (folder / "cameras.txt").is_file() and (folder / "images.txt").is_file():
        return "text"
    return None


def read_colmap_model(folder: Path, encoding: str | None = None) -> ColmapModel:
    """Read the model in ``folder`` (binary preferred when both are present, or ``encoding``)."""
    encoding = encoding or _model_encoding(folder)
    if encoding is None:
        raise FormatError(folder, "no COLMAP model here: expected cameras and images as .bin or .txt")
    suffix = ".bin" if encoding == "binary" else ".txt"
    cameras_path, images_path, points_path = (
        folder / f"{name}{suffix}" for name in ("cameras", "images", "points3D")
    )
    if encoding == "binary":
        cameras = _read_cameras_binary(cameras_path)
        images = _read_images_binary(images_path)
        points = _read_points_binary(points_path) if points_path.is_file() else _no_points()
    else:
        cameras = _read_cameras_text(cameras_path)
        images = _read_images_text(images_path)
        points = _read_points_text(points_path) if points_path.is_file() else _no_points()
    order = np.argsort(points[0], kind="stable")  # files list points in any order; ids give one
    points = tuple(column[order] for column in points)
    repeated = points[0][1:][points[0][1:] == points[0][:-1]]
    if len(repeated):
        raise FormatError(points_path, f"point id {repeated[0]} appears twice")
    if not np.all(np.isfinite(points[1])):
        raise FormatError(points_path, "point coordinates contain NaN or infinity")
    for image in images.values():
        if image.camera_id not in cameras:
            known = ", ".join(str(i) for i in sorted(cameras)[:10]) or "none"
            raise FormatError(
                images_path,
                f"image {image.id} ({image.name}): camera id {image.camera_id} is not in {cameras_path.name} (ids: {known})",
            )
    return ColmapModel(folder, encoding, cameras, images, *points)


# -- binary -------------------------------------------------------------------------------------


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


def _read_cameras_binary(path: Path) -> dict[int, ColmapCamera]:
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
        _add_camera(cameras, ColmapCamera(camera_id, model, width, height, params), path)
    return cameras


def _read_images_binary(path: Path) -> dict[int, ColmapImage]:
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
        _add_image(images, image, path)
    return images


def _read_points_binary(path: Path) -> tuple[np.ndarray, ...]:
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


# -- text ---------------------------------------------------------------------------------------


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


def _read_cameras_text(path: Path) -> dict[int, ColmapCamera]:
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
        _add_camera(cameras, ColmapCamera(camera_id, model, width, height, params), path)
    return cameras


def _read_images_text(path: Path) -> dict[int, ColmapImage]:
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
        _add_image(images, image, path)
    return images


def _read_points_text(path: Path) -> tuple[np.ndarray, ...]:
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


def _no_points() -> tuple[np.ndarray, ...]:
    return np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3), np.uint8), np.zeros(0)


def _add_camera(cameras: dict[int, ColmapCamera], camera: ColmapCamera, path: Path) -> None:
    if camera.id in cameras:
        raise FormatError(path, f"camera id {camera.id} appears twice")
    if not 1 <= camera.width <= 1 << 16 or not 1 <= camera.height <= 1 << 16:
        raise FormatError(
            path, f"camera {camera.id}: image size {camera.width}x{camera.height} is out of range"
        )
    if not np.all(np.isfinite(camera.params)):
        raise FormatError(path, f"camera {camera.id}: parameters contain NaN or infinity")
    cameras[camera.id] = camera


def _add_image(images: dict[int, ColmapImage], image: ColmapImage, path: Path) -> None:
    if image.id in images:
        raise FormatError(path, f"image id {image.id} appears twice")
    images[image.id] = image


# -- model -> scene -----------------------------------------------------------------------------


def quaternion_to_rotation(quaternion: np.ndarray) -> np.ndarray:
    """Rotation matrix ``(3, 3)`` of a unit quaternion ``(w, x, y, z)`` (COLMAP's order)."""
    w, x, y, z = quaternion
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def image_camera_to_world(image: ColmapImage, path: Path) -> np.ndarray:
    """``(3, 4)`` OpenCV camera-to-world pose of a COLMAP image: ``[R^T | -R^T t]``."""
    where = f"image {image.id} ({image.name})"
    if not np.all(np.isfinite(image.quaternion)) or not np.all(np.isfinite(image.translation)):
        raise FormatError(path, f"{where}: pose contains NaN or infinity")
    norm = float(np.linalg.norm(image.quaternion))
    if abs(norm - 1) > ROTATION_TOLERANCE:
        raise FormatError(path, f"{where}: quaternion has norm {norm:.6g}, not 1 (not a rotation)")
    world_to_camera = rigid_rotation(quaternion_to_rotation(image.quaternion / norm), path, where)
    rotation = world_to_camera.T
    return np.concatenate([rotation, (-rotation @ image.translation)[:, None]], axis=1)


def _camera_intrinsics(
    camera: ColmapCamera, path: Path
) -> tuple[float, float, float, float, str, list[float]]:
    """``(fx, fy, cx, cy, family, distortion)`` with family OPENCV or OPENCV_FISHEYE."""
    p = camera.params.tolist()
    if camera.model == "SIMPLE_PINHOLE":
        return p[0], p[0], p[1], p[2], "OPENCV", [0.0] * 5
    if camera.model == "PINHOLE":
        return p[0], p[1], p[2], p[3], "OPENCV", [0.0] * 5
    if camera.model == "SIMPLE_RADIAL":
        return p[0], p[0], p[1], p[2], "OPENCV", [p[3], 0.0, 0.0, 0.0, 0.0]
    if camera.model == "RADIAL":
        return p[0], p[0], p[1], p[2], "OPENCV", [p[3], p[4], 0.0, 0.0, 0.0]
    if camera.model == "OPENCV":
        return p[0], p[1], p[2], p[3], "OPENCV", [p[4], p[5], p[6], p[7], 0.0]
    if camera.model == "OPENCV_FISHEYE":
        return p[0], p[1], p[2], p[3], "OPENCV_FISHEYE", p[4:8]
    raise FormatError(
        path,
        f"camera {camera.id}: model {camera.model} is not supported (supported: {', '.join(SUPPORTED_MODELS)})",
    )


def detect_colmap(path: Path) -> bool:
    return path.is_dir() and any(
        _model_encoding(folder) for folder in (path, path / "sparse" / "0", path / "sparse")
    )


def read_colmap(path: Path, missing_images: str = "skip", images: str | Path | None = None) -> Scene:
    """Read a COLMAP model folder (or a dataset folder holding ``sparse/0``) into a Scene."""
    folder = find_model_folder(path) if path.is_dir() else None
    if folder is None:
        raise FormatError(
            path, "no COLMAP model found (cameras and images .bin or .txt, here or in sparse/0)"
        )
    model = read_colmap_model(folder)
    suffix = ".bin" if model.encoding == "binary" else ".txt"
    images_path, cameras_path = folder / f"images{suffix}", folder / f"cameras{suffix}"
    ordered = sorted(model.images.values(), key=lambda image: image.name)
    if not ordered:
        raise FormatError(images_path, "the model has no registered images")
    poses = np.stack([image_camera_to_world(image, images_path) for image in ordered])
    intrinsics = [_camera_intrinsics(model.cameras[image.camera_id], cameras_path) for image in ordered]
    families = {row[4] for row in intrinsics}
    if len(families) > 1:
        raise FormatError(
            cameras_path, "mixes fisheye and perspective cameras; a scene holds one camera family"
        )
    family = families.pop()
    distortion = np.array([row[5] for row in intrinsics], dtype=np.float64)
    if family == "OPENCV" and not np.any(distortion):
        family, distortion = "PINHOLE", np.zeros((len(ordered), 0))
    cameras = Cameras(
        torch.from_numpy(poses),
        [row[0] for row in intrinsics],
        [row[1] for row in intrinsics],
        [row[2] for row in intrinsics],
        [row[3] for row in intrinsics],
        [model.cameras[image.camera_id].width for image in ordered],
        [model.cameras[image.camera_id].height for image in ordered],
        family,
        torch.from_numpy(distortion),
    )

    image_folder = _find_image_folder(folder, path, images, [image.name for image in ordered])
    paths = [image_folder / image.name if image_folder is not None else None for image in ordered]
    sizes = []
    for index, (image, image_path) in enumerate(zip(ordered, paths)):
        size = image_size(image_path, f"image {image.id} ({image.name})") if image_path is not None else None
        expected = (int(cameras.width[index]), int(cameras.height[index]))
        if size is not None and size != expected:
            raise FormatError(
                image_path,
                f"image {image.id} ({image.name}): file is {size[0]}x{size[1]} but its camera is {expected[0]}x{expected[1]}",
            )
        sizes.append(size)
    missing = [
        MissingImage(images_path, image.id, image.name, image_path or folder / image.name)
        for image, image_path, size in zip(ordered, paths, sizes)
        if size is None
    ]
    keep = keep_frames([s is not None for s in sizes], missing, missing_images, folder)
    frames = [Frame(image.name, p if s is not None else None) for image, p, s in zip(ordered, paths, sizes)]
    points = None
    if len(model.points):
        points = PointCloud(
            model.points, {"colors": model.colors, "error": model.errors, "point_id": model.point_ids}
        )
    root = image_folder.parent if image_folder is not None else folder
    metadata = {
        "path": str(folder),
        "root": str(root),
        "frames_listed": len(ordered),
        "encoding": model.encoding,
        "colmap_models": sorted({model.cameras[image.camera_id].model for image in ordered}),
    }
    scene = Scene(
        cameras, frames, {}, points, _near_far_from_points(cameras, model.points), metadata=metadata
    )
    return scene.subset(np.flatnonzero(keep))


def _find_image_folder(
    model_folder: Path, given_path: Path, images: str | Path | None, names: list[str]
) -> Path | None:
    if images is not None:
        folder = Path(images)
        if not folder.is_absolute() and not folder.is_dir():
            folder = given_path / folder
        return folder
    roots = [model_folder, model_folder.parent, model_folder.parent.parent]
    for root in roots:
        if not root.is_dir():
            continue
        candidates = [root / "images"] + sorted(
            p for p in root.iterdir() if p.is_dir() and not p.name.startswith(".")
        )
        for candidate in candidates:
            if any((candidate / name).is_file() for name in names[:3]):
                return candidate
    return None


def _near_far_from_points(cameras: Cameras, points: np.ndarray) -> np.ndarray | None:
    """Per-camera (0.1, 99.9) percentiles of the depths of the points that land inside the image."""
    if len(points) == 0:
        return None
    pixels, depth = cameras.project(torch.from_numpy(points))
    inside = (
        (depth > 0)
        & (pixels[..., 0] >= 0)
        & (pixels[..., 0] < cameras.width[:, None])
        & (pixels[..., 1] >= 0)
        & (pixels[..., 1] < cameras.height[:, None])
    )
    bounds = np.zeros((len(cameras), 2))
    depth = depth.numpy()
    visible_anywhere = depth[inside.numpy()]
    for index in range(len(cameras)):
        seen = depth[index][inside[index].numpy()]
        seen = seen if len(seen) else visible_anywhere
        if len(seen) == 0:
            return None
        bounds[index] = np.percentile(seen, [0.1, 99.9])
    return bounds


register(
    SceneFormat(
        name="colmap",
        description="COLMAP sparse model (cameras/images/points3D .bin or .txt; world-to-camera quaternions)",
        detect=detect_colmap,
        read=read_colmap,
        priority=40,
    )
)
