"""The classic ``tiny_nerf_data.npz``: ``images``, ``poses`` and ``focal`` in one NumPy archive.

- ``images``: ``(N, H, W, 3)`` (or 4 with alpha) float in [0, 1] or uint8;
- ``poses``: ``(N, 4, 4)`` (or ``(N, 3, 4)``) camera-to-world in the **OpenGL** convention, as
  the NeRF authors' tiny-NeRF notebook uses them; converted with ``c2w @ diag(1, -1, -1, 1)``;
- ``focal``: one focal length in pixels (or one per image); principal point at the image centre.

The archive has no split; ``holdout_every`` makes one (the notebook held out view 101 by hand).
Every member's declared shape is checked against its stored size, and the stored size against
what its compressed bytes can hold (deflate expands at most ~1032x), before anything is read.
"""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import numpy as np
import torch

from pointfield.clouds.formats.binary import check_size
from pointfield.clouds.formats.npy import read_array_header
from pointfield.errors import FormatError
from pointfield.scenes.cameras import Cameras, opengl_to_opencv
from pointfield.scenes.formats.registry import SceneFormat, register
from pointfield.scenes.formats.validation import rigid_rotation
from pointfield.scenes.scene import Frame, Scene

DEFLATE_MAX_RATIO = 1032


def detect_npz(path: Path) -> bool:
    return path.is_file() and path.suffix.lower() == ".npz"


def read_npz_scene(path: Path, missing_images: str = "skip") -> Scene:
    """Read an ``.npz`` of images, OpenGL poses and focal length (``missing_images`` has no effect: images are inside)."""
    try:
        with zipfile.ZipFile(path) as archive:
            members = {info.filename.removesuffix(".npy"): info for info in archive.infolist()}
            for key in ("images", "poses", "focal"):
                if key not in members:
                    raise FormatError(
                        path,
                        f"no {key!r} array (found {', '.join(sorted(members)) or 'nothing'}); expected images, poses, focal",
                    )
            images, poses, focal = (
                _read_member(archive, members[key], path) for key in ("images", "poses", "focal")
            )
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, NotImplementedError, OSError) as error:
        raise FormatError(path, f"not a readable .npz archive ({type(error).__name__}: {error})") from None
    if (
        images.ndim != 4
        or images.shape[3] not in (3, 4)
        or not (images.dtype == np.uint8 or images.dtype.kind == "f")
    ):
        raise FormatError(
            path, f"images must be (N, H, W, 3 or 4) float or uint8, found {images.shape} {images.dtype}"
        )
    count, height, width = images.shape[:3]
    if (
        poses.ndim != 3
        or poses.shape[0] != count
        or poses.shape[1:] not in ((4, 4), (3, 4))
        or poses.dtype.kind != "f"
    ):
        raise FormatError(
            path,
            f"poses must be ({count}, 4, 4) floats to match {count} images, found {poses.shape} {poses.dtype}",
        )
    focal = np.array(focal, dtype=np.float64).reshape(-1)
    if len(focal) not in (1, count) or not np.all(np.isfinite(focal)) or np.any(focal <= 0):
        raise FormatError(
            path, f"focal must be one positive number or one per image, found {focal[:5].tolist()}"
        )
    poses = poses.astype(np.float64)
    for index in range(count):
        if not np.all(np.isfinite(poses[index])):
            raise FormatError(path, f"frame {index}: pose contains NaN or infinity")
        poses[index, :3, :3] = rigid_rotation(poses[index, :3, :3], path, f"frame {index}")
    cameras = Cameras(
        torch.from_numpy(opengl_to_opencv(poses)[:, :3]),
        torch.from_numpy(focal),
        torch.from_numpy(focal),
        width / 2,
        height / 2,
        width,
        height,
    )
    frames = [Frame(f"image_{index}", image=images[index]) for index in range(count)]
    metadata = {"path": str(path), "root": str(path.parent), "frames_listed": count}
    return Scene(cameras, frames, metadata=metadata)


def _read_member(archive: zipfile.ZipFile, info: zipfile.ZipInfo, path: Path) -> np.ndarray:
    where = info.filename
    if info.file_size > DEFLATE_MAX_RATIO * info.compress_size + 1024:
        raise FormatError(
            path,
            f"{where}: claims {info.file_size} bytes from {info.compress_size} compressed bytes, "
            "more than deflate can produce",
        )
    data = archive.read(info)
    header = read_array_header(io.BytesIO(data), path, member=info.filename)
    if header.dtype.kind not in "biuf":
        raise FormatError(path, f"{where}: array has dtype {header.dtype}; expected numbers")
    check_size(path, f"{where}: {header.declared}", header.count, header.dtype.itemsize, len(data) - header.size,
               unit="values")
    values = np.frombuffer(data, dtype=header.dtype, count=header.count, offset=header.size)
    return values.reshape(header.shape, order="F" if header.fortran_order else "C")


register(
    SceneFormat(
        name="npz",
        description="tiny_nerf_data.npz: images, OpenGL poses and focal in one NumPy archive",
        detect=detect_npz,
        read=read_npz_scene,
        priority=50,
    )
)
