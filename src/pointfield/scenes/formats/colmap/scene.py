"""A COLMAP model as a pointfield :class:`Scene`: poses inverted, cameras converted, images found.

COLMAP already uses pointfield's camera convention (x right, y down, looking down +z; pixel
centres at +0.5), but stores each image's pose **world-to-camera** as a unit quaternion
``(qw, qx, qy, qz)`` and a translation t: ``X_camera = R(q) X_world + t``. The reader inverts
it, ``R_c2w = R(q)^T`` and camera centre ``C = -R(q)^T t``.

Camera models read: SIMPLE_PINHOLE (f, cx, cy), PINHOLE (fx, fy, cx, cy), SIMPLE_RADIAL
(f, cx, cy, k), RADIAL (f, cx, cy, k1, k2), OPENCV (fx, fy, cx, cy, k1, k2, p1, p2) and
OPENCV_FISHEYE (fx, fy, cx, cy, k1, k2, k3, k4); radial ones become OPENCV with the missing
coefficients zero. A scene holds one model family, so perspective and fisheye cameras cannot mix.

Frames are ordered by image name. Images are looked for in ``images=`` if given, else in
``images/`` or any sibling folder holding them, up to two folders above the model
(``sparse/0`` -> dataset root). Near and far per frame: the 0.1 and 99.9 percentiles of the
depths of the points that project into that image (as LLFF computes its bounds).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from pointfield.clouds.cloud import PointCloud
from pointfield.errors import FormatError
from pointfield.scenes.cameras import Cameras
from pointfield.scenes.formats.colmap.folder import (
    find_model_folder,
    model_encoding,
    read_colmap_model,
)
from pointfield.scenes.formats.colmap.model import ColmapCamera, ColmapImage
from pointfield.scenes.formats.validation import (
    ROTATION_TOLERANCE,
    MissingImage,
    image_size,
    keep_frames,
    rigid_rotation,
)
from pointfield.scenes.scene import Frame, Scene

# The camera models a scene can be made of (see above); COLMAP defines others.
SUPPORTED_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "OPENCV_FISHEYE")


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
        model_encoding(folder) for folder in (path, path / "sparse" / "0", path / "sparse")
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
