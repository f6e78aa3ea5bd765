"""A COLMAP model folder: finding it, and reading its files in either encoding into a model.

The model is looked for in the given folder, ``sparse/0``, ``sparse`` or a subfolder; binary
files are preferred when both encodings are present. Points are ordered by id, and every
image's camera id is checked against the cameras read.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pointfield.errors import FormatError
from pointfield.scenes.formats.colmap.binary import (
    read_cameras_binary,
    read_images_binary,
    read_points_binary,
)
from pointfield.scenes.formats.colmap.model import ColmapModel, no_points
from pointfield.scenes.formats.colmap.text import (
    read_cameras_text,
    read_images_text,
    read_points_text,
)


def find_model_folder(path: Path) -> Path | None:
    """The folder holding a COLMAP model: ``path`` itself, ``path/sparse/0``, ``path/sparse``, or a subfolder."""
    candidates = [path, path / "sparse" / "0", path / "sparse"]
    if path.is_dir():
        candidates += sorted(p for p in path.iterdir() if p.is_dir() and not p.name.startswith("."))
    for folder in candidates:
        if model_encoding(folder) is not None:
            return folder
    return None


def model_encoding(folder: Path) -> str | None:
    """``"binary"`` or ``"text"``: the encoding of the model in ``folder``, None when there is none."""
    if (folder / "cameras.bin").is_file() and (folder / "images.bin").is_file():
        return "binary"
    if (folder / "cameras.txt").is_file() and (folder / "images.txt").is_file():
        return "text"
    return None


def read_colmap_model(folder: Path, encoding: str | None = None) -> ColmapModel:
    """Read the model in ``folder`` (binary preferred when both are present, or ``encoding``)."""
    encoding = encoding or model_encoding(folder)
    if encoding is None:
        raise FormatError(folder, "no COLMAP model here: expected cameras and images as .bin or .txt")
    suffix = ".bin" if encoding == "binary" else ".txt"
    cameras_path, images_path, points_path = (
        folder / f"{name}{suffix}" for name in ("cameras", "images", "points3D")
    )
    if encoding == "binary":
        cameras = read_cameras_binary(cameras_path)
        images = read_images_binary(images_path)
        points = read_points_binary(points_path) if points_path.is_file() else no_points()
    else:
        cameras = read_cameras_text(cameras_path)
        images = read_images_text(images_path)
        points = read_points_text(points_path) if points_path.is_file() else no_points()
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
