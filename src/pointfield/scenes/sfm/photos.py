"""The photos to pose: found, fully decoded once, and checked before COLMAP sees them.

COLMAP skips an unreadable image with a line in its log, or stops on a truncated one; a user
then learns that "only 37 of 40 images registered" without knowing why. So every photo is
decoded here first, and the first bad one is named with what to do about it.

Decisions (docs/photos.md):

- Images of different sizes are allowed: the pipeline gives each image size its own camera.
- Images under :data:`MIN_SIDE` pixels on a side are refused: too small for features.
- EXIF orientation is not applied (COLMAP ignores it too, so poses are for the pixels as
  stored); photos that carry a rotation are flagged (``Photo.exif_rotated``) for the report.
"""

from __future__ import annotations

import os
import re
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from pointfield.scenes.sfm.errors import PosingError

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp", ".webp")
MIN_PHOTOS = 3
MIN_SIDE = 64
EXIF_ORIENTATION = 0x0112


@dataclass(frozen=True)
class Photo:
    """One checked photo: its file, pixel size, and whether EXIF asks for it to be rotated."""

    path: Path
    width: int
    height: int
    exif_rotated: bool = False

    @property
    def size(self) -> tuple[int, int]:
        return self.width, self.height


def gather_photos(source: str | os.PathLike[str] | Sequence[str | os.PathLike[str]]) -> list[Photo]:
    """The photos of a folder (its image files, in natural order: 2.jpg before 10.jpg) or of a list.

    In a folder, files without an image suffix (:data:`IMAGE_SUFFIXES`) are skipped with one
    warning; a listed file must be an image. Raises :class:`PosingError` naming the first bad
    file (and how many more there are) or saying how many images were found.
    """
    if isinstance(source, (str, os.PathLike)):
        folder = Path(source)
        if not folder.exists():
            raise PosingError(f"{folder}: no such folder or file")
        if folder.is_dir():
            files = sorted((p for p in folder.iterdir() if p.is_file()), key=lambda p: natural_key(p.name))
            images = [p for p in files if p.suffix.lower() in IMAGE_SUFFIXES]
            skipped = [p for p in files if p.suffix.lower() not in IMAGE_SUFFIXES and not p.name.startswith(".")]
            if skipped:
                warnings.warn(
                    f"{folder}: skipped {len(skipped)} file{'s' if len(skipped) > 1 else ''} that "
                    f"{'are' if len(skipped) > 1 else 'is'} not an image (first: {skipped[0].name})",
                    stacklevel=2,
                )
            where = folder
        else:
            images, where = [folder], folder
    else:
        images = [Path(p) for p in source]
        where = Path(os.path.commonpath([str(p.resolve()) for p in images])) if images else Path(".")
        for path in images:
            if not path.is_file():
                raise PosingError(f"{path}: no such file")
    if len(images) < MIN_PHOTOS:
        raise PosingError(
            f"{where}: found {len(images)} image{'s' if len(images) != 1 else ''} "
            f"({', '.join(IMAGE_SUFFIXES)}); structure from motion needs at least {MIN_PHOTOS} overlapping photos"
        )
    photos, problems = [], []
    for path in images:
        checked = _check(path)
        if isinstance(checked, str):
            problems.append(checked)
        else:
            photos.append(checked)
    if problems:
        more = f" (and {len(problems) - 1} more bad file{'s' if len(problems) > 2 else ''})" if len(problems) > 1 else ""
        raise PosingError(problems[0] + more)
    return photos


def _check(path: Path) -> Photo | str:
    """Decode ``path`` fully; its Photo, or the message saying what is wrong with it."""
    from PIL import Image, UnidentifiedImageError

    if path.suffix.lower() not in IMAGE_SUFFIXES:
        return f"{path}: not an image (suffix {path.suffix or 'none'}); pass only photos ({', '.join(IMAGE_SUFFIXES)})"
    try:
        with warnings.catch_warnings():
            # A decompression-bomb warning becomes the error below: a photo that large is hostile.
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            with Image.open(path) as image:
                image.load()
                width, height = image.size
                orientation = image.getexif().get(EXIF_ORIENTATION, 1)
    except UnidentifiedImageError as error:
        return f"{path}: not an image ({_reason(error)}); remove it or pass only photos"
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as error:
        return f"{path}: refused, too many pixels ({_reason(error)})"
    except (OSError, SyntaxError, ValueError) as error:
        return f"{path}: truncated or corrupt image ({_reason(error)}); remove it or replace it"
    if min(width, height) < MIN_SIDE:
        return f"{path}: {width}x{height} pixels is too small for features (at least {MIN_SIDE} on a side)"
    return Photo(path, width, height, orientation not in (1, None))


def _reason(error: Exception) -> str:
    return str(error).split(" '")[0].strip() or type(error).__name__


def natural_key(name: str) -> list:
    """Sort key that orders digits by value: ``2.jpg`` before ``10.jpg``."""
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", name)]
