"""LLFF datasets: ``poses_bounds.npy`` beside an ``images/`` folder.

``poses_bounds.npy`` is ``(N, 17)`` float: each row is a 3x5 matrix flattened row by row, then
the frame's near and far depth bounds. In the 3x5 matrix, columns 0-2 are the camera's axes in
world coordinates in LLFF's order **(down, right, backwards)**, column 3 is the camera centre
and column 4 is (height, width, focal) in pixels. Our OpenCV axes (right, down, forwards) are
therefore ``[column 1, column 0, -column 2]``.

Row order: LLFF's ``imgs2poses`` writes one row per image sorted by file name, and its loader
pairs row i with the i-th entry of ``sorted(os.listdir("images"))`` -- lexicographic order, so
``1.jpg, 10.jpg, 11.jpg, ..., 19.jpg, 2.jpg, 20.jpg``. This reader does the same.

Near and far are depths along the optical axis (percentiles of the COLMAP points seen by the
view), in the dataset's world units; NeRF's loader rescales the world so that the smallest near
is 1/0.75 -- a training choice, not applied here. When the images are smaller than the
(height, width) the file states by one common factor (LLFF's ``images_4`` folders), the focal
length is scaled by it too; the principal point is the image centre.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from pointfield.errors import FormatError
from pointfield.scenes.cameras import Cameras
from pointfield.scenes.formats.registry import SceneFormat, register
from pointfield.scenes.formats.validation import (
    MissingImage,
    image_size,
    keep_frames,
    rigid_rotation,
)
from pointfield.scenes.scene import Frame, Scene, load_npy

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")


def detect_llff(path: Path) -> bool:
    if path.is_dir():
        return (path / "poses_bounds.npy").is_file()
    return path.name == "poses_bounds.npy"


def read_llff(path: Path, missing_images: str = "skip", images: str | Path = "images") -> Scene:
    """Read an LLFF dataset folder (or its ``poses_bounds.npy``); ``images`` names the image folder."""
    npy_path = path / "poses_bounds.npy" if path.is_dir() else path
    folder = npy_path.parent
    table = load_npy(npy_path, "poses_bounds")
    if table.ndim != 2 or table.shape[1] not in (15, 17) or not np.issubdtype(table.dtype, np.floating):
        raise FormatError(
            npy_path,
            f"expected an (N, 17) float array of poses and bounds, found {table.shape} {table.dtype}",
        )
    table = table.astype(np.float64)
    count = len(table)
    matrices = table[:, :15].reshape(count, 3, 5)
    for index, matrix in enumerate(matrices):
        where = f"frame {index} (row {index})"
        if not np.all(np.isfinite(table[index])):
            raise FormatError(npy_path, f"{where}: contains NaN or infinity")
        matrix[:, :3] = rigid_rotation(matrix[:, :3], npy_path, where)
        if np.any(matrix[:, 4] <= 0):
            raise FormatError(
                npy_path, f"{where}: height, width, focal {matrix[:, 4].tolist()} must be positive"
            )
        if table.shape[1] == 17 and not 0 <= table[index, 15] < table[index, 16]:
            raise FormatError(
                npy_path,
                f"{where}: near {table[index, 15]} and far {table[index, 16]} must satisfy 0 <= near < far",
            )
    down, right, back = matrices[:, :, 0], matrices[:, :, 1], matrices[:, :, 2]
    poses = np.stack([right, down, -back, matrices[:, :, 3]], axis=-1)
    height, width, focal = matrices[:, 0, 4], matrices[:, 1, 4], matrices[:, 2, 4]

    image_folder = folder / images
    names = _llff_image_names(image_folder)
    if names and len(names) != count:
        raise FormatError(
            npy_path,
            f"has {count} rows but {image_folder} holds {len(names)} images; LLFF pairs them one to one",
        )
    paths = [image_folder / name for name in names] if names else [None] * count
    sizes = [image_size(p, f"frame {i} ({p.name})") if p is not None else None for i, p in enumerate(paths)]
    scale = _image_scale(npy_path, sizes, width, height, names)
    missing = [MissingImage(npy_path, i, f"row {i}", image_folder) for i, s in enumerate(sizes) if s is None]
    keep = keep_frames([s is not None for s in sizes], missing, missing_images, npy_path)

    image_width = np.array([s[0] if s else round(w * scale) for s, w in zip(sizes, width)])
    image_height = np.array([s[1] if s else round(h * scale) for s, h in zip(sizes, height)])
    cameras = Cameras(
        torch.from_numpy(poses),
        torch.from_numpy(focal * scale),
        torch.from_numpy(focal * scale),
        torch.from_numpy(image_width / 2.0),
        torch.from_numpy(image_height / 2.0),
        torch.from_numpy(image_width),
        torch.from_numpy(image_height),
    )
    frames = [Frame(names[i] if names else f"row {i}", paths[i] if sizes[i] else None) for i in range(count)]
    near_far = table[:, 15:17] if table.shape[1] == 17 else None
    metadata = {"path": str(npy_path), "root": str(folder), "frames_listed": count, "image_scale": scale}
    scene = Scene(cameras, frames, {}, None, near_far, metadata=metadata)
    return scene.subset(np.flatnonzero(keep))


def _llff_image_names(folder: Path) -> list[str]:
    """Image file names in LLFF's order: ``sorted(os.listdir(folder))`` filtered by suffix."""
    if not folder.is_dir():
        return []
    return sorted(p.name for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)


def _image_scale(npy_path: Path, sizes, width: np.ndarray, height: np.ndarray, names: list[str]) -> float:
    """The one factor image sizes differ from the stated (height, width) by (1 for full size)."""
    scale = None
    for index, size in enumerate(sizes):
        if size is None:
            continue
        frame_scale = size[0] / width[index]
        consistent = abs(size[1] - height[index] * frame_scale) <= 1 and (
            scale is None or abs(frame_scale - scale) <= 1e-3 * scale
        )
        if not consistent:
            expected = f"{width[index]:g}x{height[index]:g}" + (f" scaled by {scale:g}" if scale else "")
            raise FormatError(
                npy_path,
                f"frame {index} ({names[index]}): image is {size[0]}x{size[1]} but row {index} says {expected}",
            )
        scale = frame_scale if scale is None else scale
    return 1.0 if scale is None else float(scale)


register(
    SceneFormat(
        name="llff",
        description="LLFF poses_bounds.npy (N x 17, (down, right, back) axes) with images/ in sorted-name order",
        detect=detect_llff,
        read=read_llff,
        priority=30,
    )
)
