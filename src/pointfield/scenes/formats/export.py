"""Writing a frame's files (image, depth, mask) into a dataset folder, for the scene writers."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from pointfield.scenes.scene import Scene


def export_frame(
    scene: Scene, index: int, directory: Path, stem: str, copy_suffixes: tuple[str, ...]
) -> dict[str, str]:
    """Write frame ``index``'s files under ``directory`` as ``stem`` + suffix; return their relative paths.

    The image file is copied byte for byte when it needs no change (no downscaling, suffix in
    ``copy_suffixes``), otherwise written as an 8-bit PNG (alpha kept). Depth is written as
    float32 ``.npy`` in world units (``stem_depth.npy``), the object mask as an 8-bit PNG
    (``stem_mask.png``, 255 on objects). Keys of the result: "image", and "depth" / "mask" when
    the frame has them.
    """
    frame = scene.frames[index]
    written: dict[str, str] = {}
    target_folder = (directory / stem).parent
    target_folder.mkdir(parents=True, exist_ok=True)
    if frame.has_image:
        source = frame.image_path
        if source is not None and scene.downscale == 1 and source.suffix.lower() in copy_suffixes:
            relative = stem + source.suffix.lower()
            shutil.copyfile(source, directory / relative)
        else:
            relative = stem + ".png"
            write_png(directory / relative, scene.rgba(index))
        written["image"] = relative
    if frame.has_depth:
        relative = stem + "_depth.npy"
        np.save(directory / relative, scene.depth(index))
        written["depth"] = relative
    if frame.has_mask:
        relative = stem + "_mask.png"
        write_png(directory / relative, scene.mask(index).astype(np.float32))
        written["mask"] = relative
    return written


def write_png(path: Path, pixels: np.ndarray) -> None:
    """Write float pixels in [0, 1] (``(H, W)``, ``(H, W, 3)`` or ``(H, W, 4)``) as an 8-bit PNG."""
    import imageio.v3 as iio

    quantized = np.round(np.clip(pixels, 0, 1) * 255).astype(np.uint8)
    iio.imwrite(path, quantized, extension=".png")


def unique_stem(stem: str, taken: set[str]) -> str:
    """``stem``, or ``stem_2``, ``stem_3``, ... when already taken (case-insensitively); records it."""
    candidate, counter = stem, 1
    while candidate.lower() in taken:
        counter += 1
        candidate = f"{stem}_{counter}"
    taken.add(candidate.lower())
    return candidate
