"""The one registry of scene formats behind :func:`read_scene` and :func:`write_scene`.

Each format module calls :func:`register` at import with a :class:`SceneFormat`: how to
recognise a dataset folder (or file) of that format, how to read it into a
:class:`~pointfield.scenes.scene.Scene`, and, for formats pointfield writes, how to write one.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import shutil
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pointfield.errors import FormatError, PointfieldError
from pointfield.scenes.formats.companions import with_companion_points
from pointfield.scenes.scene import Scene, SceneError


@dataclass(frozen=True)
class SceneFormat:
    """A posed-image dataset format.

    - ``detect(path) -> bool``: does ``path`` (a folder, or a file such as ``transforms.json``)
      hold a scene of this format? Cheap: looks at names, not contents.
    - ``read(path, missing_images=..., **options) -> Scene``: cameras converted to the internal
      OpenCV convention, ``metadata["format"]`` set.
    - ``write(scene, directory) -> None``: writes into an existing empty ``directory``; None for
      formats pointfield only reads.
    - ``priority``: detection tries lower numbers first, so a folder holding two formats (an
      LLFF folder usually also holds its COLMAP model) reads as the more specific one.
    """

    name: str
    description: str
    detect: Callable[[Path], bool]
    read: Callable[..., Scene]
    write: Callable[[Scene, Path], None] | None = None
    priority: int = 100


_FORMATS: dict[str, SceneFormat] = {}


def register(fmt: SceneFormat) -> SceneFormat:
    """Add a format (detection order follows ``priority``)."""
    _FORMATS[fmt.name] = fmt
    return fmt


def scene_formats() -> list[SceneFormat]:
    """Every registered scene format, in detection order."""
    return sorted(_FORMATS.values(), key=lambda fmt: fmt.priority)


def scene_format_named(name: str) -> SceneFormat:
    try:
        return _FORMATS[name]
    except KeyError:
        raise SceneError(f"unknown scene format {name!r}; known: {', '.join(_FORMATS)}") from None


def detect_scene_format(path: str | os.PathLike[str]) -> SceneFormat:
    """The first format whose ``detect`` accepts ``path``; FormatError when none does."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file or directory")
    for fmt in scene_formats():
        if fmt.detect(path):
            return fmt
    raise FormatError(
        path,
        "no scene found: expected transforms_train.json (Blender), transforms.json (nerfstudio / "
        "instant-ngp), poses_bounds.npy (LLFF), a COLMAP model (cameras, images, points3D .bin/.txt) "
        "or an .npz with images, poses and focal",
    )


def read_scene(
    path: str | os.PathLike[str],
    format: str | None = None,
    *,
    background: Any = "white",
    downscale: int = 1,
    holdout_every: int | None = None,
    missing_images: str = "skip",
    **options: Any,
) -> Scene:
    """Read a posed-image dataset into a :class:`Scene` with cameras in the OpenCV convention.

    - ``format``: one of :func:`scene_formats` names; detected from the folder's files if None.
    - ``background``: colour alpha is composited onto ("white", "black" or RGB in [0, 1]).
    - ``downscale``: integer factor; images are area-downscaled on load, cameras scaled to match.
    - ``holdout_every``: hold every N-th frame out as the "test" split when the dataset has none.
    - ``missing_images``: "skip" (one warning counting them), "error" or "keep" (poses only).
    - ``options``: format-specific (``images=`` folder for COLMAP and LLFF).

    Example::

        >>> scene = read_scene("data/nerf/lego_blender")
        >>> scene
        Scene(blender, 100 frames (train 100), Cameras(100, PINHOLE, 800x800, fx 1111.11, ...))
        >>> scene.image(0).shape
        (800, 800, 3)
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file or directory")
    fmt = scene_format_named(format) if format else detect_scene_format(path)
    scene = fmt.read(path, missing_images=missing_images, **options)
    if fmt.name != "colmap":  # a COLMAP model beside a transforms.json or LLFF poses gives its sparse points
        scene = with_companion_points(scene, Path(scene.metadata.get("root", path if path.is_dir() else path.parent)))
    scene.metadata["format"] = fmt.name
    scene = scene.with_background(background).downscaled(downscale)
    if holdout_every is not None:
        scene = scene.with_holdout(holdout_every)
    return scene


def write_scene(
    scene: Scene,
    out: str | os.PathLike[str],
    format: str = "nerfstudio",
    *,
    overwrite: bool = False,
) -> Path:
    """Write ``scene`` as a dataset folder ``out`` in ``format`` ("nerfstudio" or "blender").

    The folder appears whole or not at all (written beside it, then renamed). An existing
    non-empty ``out`` is an error unless ``overwrite``.
    """
    fmt = scene_format_named(format)
    if fmt.write is None:
        writable = [f.name for f in scene_formats() if f.write is not None]
        raise SceneError(
            f"pointfield reads {format} scenes but does not write them; write one of {', '.join(writable)}"
        )
    out = Path(out)
    with atomic_directory(out, overwrite=overwrite) as directory:
        fmt.write(scene, directory)
    return out


@contextlib.contextmanager
def atomic_directory(out: Path, *, overwrite: bool = False) -> Iterator[Path]:
    """Yield a fresh temporary folder beside ``out``; it replaces ``out`` when the block succeeds.

    On failure the temporary folder is removed and ``out`` is left as it was.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise PointfieldError(f"{out}: exists and is not a directory")
    if out.is_dir() and any(out.iterdir()) and not overwrite:
        raise PointfieldError(f"{out}: directory exists and is not empty (pass overwrite to replace it)")
    out.parent.mkdir(parents=True, exist_ok=True)
    temporary = out.with_name(f".{out.name}.{secrets.token_hex(4)}.tmp")
    temporary.mkdir()
    try:
        yield temporary
        if out.exists():
            retired = out.with_name(f".{out.name}.{secrets.token_hex(4)}.old")
            out.rename(retired)
            temporary.rename(out)
            shutil.rmtree(retired)
        else:
            temporary.rename(out)
    except BaseException:
        shutil.rmtree(temporary, ignore_errors=True)
        raise
