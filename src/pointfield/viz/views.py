"""Pictures of rendered views: colour | depth | opacity panels, and paths of them as GIF, MP4 or files.

A view is a dict of numpy arrays ``{"rgb": (H, W, 3), "depth": (H, W), "median_depth": (H, W),
"opacity": (H, W)}`` (what :meth:`pointfield.scenes.run.SceneRun.render` gives, as numpy). Depth
is drawn grey, near white and far dark between the ``near`` and ``far`` it is given, with empty
pixels black (expected depth fades with opacity; median depth is black where it is 0).
Output by suffix: ``.gif`` (imageio), ``.mp4`` (needs the ``imageio-ffmpeg`` package),
otherwise a folder of files per view ``NNN``:

- ``color_NNN.png``, ``opacity_NNN.png``, and ``depth_NNN.png`` / ``median_depth_NNN.png``:
  the pictures;
- for each depth output (:data:`DEPTH_OUTPUTS`), the depth map itself: ``depth_NNN.npy``
  (float32 ``(H, W)``, scene units) and ``depth16_NNN.png`` (16-bit grey, ``depth / scale``
  rounded), likewise ``median_depth_NNN.npy`` and ``median_depth16_NNN.png``, with the one
  ``scale`` of the folder in ``depth_scale.json`` (:func:`depth_png_scale`). 0 means no surface.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import imageio.v2 as imageio
import imageio.v3 as iio
import numpy as np

from pointfield.atomic import atomic_path
from pointfield.errors import PointfieldError
from pointfield.viz.render import save_image

FRAMES_PER_SECOND = 20
VIDEO_SUFFIXES = (".gif", ".mp4")
PANELS = ("rgb", "depth", "opacity")
"""What a render writes unless told which outputs: colour, expected depth and opacity."""
DEPTH_OUTPUTS = ("depth", "median_depth")
"""The outputs that are distances along the ray in scene units: written as depth maps too."""
PICTURE_NAMES = {"rgb": "color"}
"""File names of pictures, where not the output's own name."""
DEPTH_PNG_STEPS = 65535
DEPTH_SCALE_FILE = "depth_scale.json"


def to_uint8(image: np.ndarray) -> np.ndarray:
    """``(H, W)`` or ``(H, W, 3)`` floats in [0, 1] -> ``(H, W, 3)`` uint8."""
    image = (np.clip(image, 0, 1) * 255).round().astype(np.uint8)
    return np.repeat(image[..., None], 3, axis=2) if image.ndim == 2 else image


def depth_image(depth: np.ndarray, opacity: np.ndarray, near: float, far: float) -> np.ndarray:
    """Depth as ``(H, W, 3)`` uint8 grey: near white, far dark, empty pixels black."""
    scaled = 1 - np.clip((depth - near) / max(far - near, 1e-9), 0, 1)
    return np.repeat((np.clip(scaled * opacity, 0, 1) * 255).round().astype(np.uint8)[..., None], 3, axis=2)


def picture(view: dict[str, np.ndarray], name: str, near: float, far: float) -> np.ndarray:
    """Output ``name`` of ``view`` as an ``(H, W, 3)`` uint8 picture.

    Expected depth fades with the view's opacity; median depth is black where it is 0 (the
    accumulated opacity never reached one half).
    """
    if name == "depth":
        return depth_image(view["depth"], view["opacity"], near, far)
    if name == "median_depth":
        return depth_image(view["median_depth"], (view["median_depth"] > 0).astype(np.float32), near, far)
    return to_uint8(view[name])


def view_panel(
    view: dict[str, np.ndarray], near: float, far: float, truth: np.ndarray | None = None,
    outputs: Sequence[str] = PANELS,
) -> np.ndarray:
    """``[ground truth |]`` the ``outputs``' pictures (``colour | depth | opacity``) side by side, ``(H, k W, 3)`` uint8."""
    panels = [] if truth is None else [to_uint8(truth)]
    panels += [picture(view, name, near, far) for name in outputs]
    return np.concatenate(panels, axis=1)


def depth_png_scale(views: list[dict[str, np.ndarray]], names: Sequence[str]) -> float:
    """Scene units per step of 16-bit depth PNGs: the largest depth of any view maps to 65535.

    One scale for every view and depth output ``names`` written together, so that they compare;
    1.0 where every depth is 0.
    """
    largest = max((float(view[name].max(initial=0.0)) for view in views for name in names), default=0.0)
    return largest / DEPTH_PNG_STEPS if largest > 0 else 1.0


def depth_png(depth: np.ndarray, scale: float) -> np.ndarray:
    """``(H, W)`` depth in scene units -> uint16 ``round(depth / scale)``; 0 only where depth is 0.

    A depth closer than half a step is written as 1, so that 0 keeps meaning "no surface".
    """
    steps = np.clip(np.round(depth / scale), 0, DEPTH_PNG_STEPS)
    return np.where(depth > 0, np.maximum(steps, 1), 0).astype(np.uint16)


def write_depth_maps(views: list[dict[str, np.ndarray]], out: Path, names: Sequence[str]) -> None:
    """Write the depth outputs ``names`` of ``views`` into folder ``out``: ``.npy``, 16-bit PNG, scale."""
    scale = depth_png_scale(views, names)
    for index, view in enumerate(views):
        for name in names:
            with atomic_path(out / f"{name}_{index:03d}.npy") as tmp:
                np.save(tmp, view[name].astype(np.float32))
            with atomic_path(out / f"{name}16_{index:03d}.png") as tmp:
                iio.imwrite(tmp, depth_png(view[name], scale), extension=".png")
    with atomic_path(out / DEPTH_SCALE_FILE) as tmp:
        tmp.write_text(json.dumps({"scale": scale, "units": "scene units per PNG step", "zero": "no surface"},
                                  indent=2) + "\n")


def check_views_output(out: Path) -> None:
    """Refuse an output ``write_views`` cannot write, before anything is rendered."""
    suffix = out.suffix.lower()
    if suffix == ".mp4":
        _require_ffmpeg()
    elif suffix not in ("", *VIDEO_SUFFIXES):
        raise PointfieldError(f"{out}: render output must end in .gif or .mp4, or be a folder")


def write_views(
    views: list[dict[str, np.ndarray]], out: Path, near: float, far: float, outputs: Sequence[str] = PANELS,
) -> None:
    """Write the ``outputs`` of rendered views: a GIF / MP4 of their panels, or a folder of files (module doc).

    The expected depth's picture needs each view's ``opacity`` too, whether ``outputs`` has it or not.
    """
    check_views_output(out)
    suffix = out.suffix.lower()
    if suffix in VIDEO_SUFFIXES:
        out.parent.mkdir(parents=True, exist_ok=True)
        frames = np.stack([view_panel(view, near, far, outputs=outputs) for view in views])
        with atomic_path(out) as tmp:
            if suffix == ".gif":
                iio.imwrite(tmp, frames, extension=".gif", duration=1000 / FRAMES_PER_SECOND, loop=0)
            else:
                # libx264 needs even sizes: pad with one white row / column where odd.
                pad = ((0, 0), (0, frames.shape[1] % 2), (0, frames.shape[2] % 2), (0, 0))
                _write_mp4(tmp, np.pad(frames, pad, constant_values=255))
        return
    out.mkdir(parents=True, exist_ok=True)
    for index, view in enumerate(views):
        for name in outputs:
            save_image(out / f"{PICTURE_NAMES.get(name, name)}_{index:03d}.png", picture(view, name, near, far))
    depths = [name for name in outputs if name in DEPTH_OUTPUTS]
    if depths:
        write_depth_maps(views, out, depths)


def save_panels(folder: Path, renders: list[tuple[int, dict[str, np.ndarray], np.ndarray]], near: float,
                far: float) -> None:
    """``folder/NNN.png`` for each ``(frame, view, truth)``: ground truth | colour | depth | opacity."""
    folder.mkdir(parents=True, exist_ok=True)
    for index, view, truth in renders:
        save_image(folder / f"{index:03d}.png", view_panel(view, near, far, truth=truth))


def _write_mp4(path: Path, frames: np.ndarray) -> None:
    writer = imageio.get_writer(
        path, format="FFMPEG", fps=FRAMES_PER_SECOND, codec="libx264", macro_block_size=1
    )
    with writer:
        for frame in frames:
            writer.append_data(frame)


def _require_ffmpeg() -> None:
    try:
        import imageio_ffmpeg  # optional (the `video` extra): only MP4 needs it

        imageio_ffmpeg.get_ffmpeg_exe()
    except (ImportError, RuntimeError) as error:
        raise PointfieldError(
            f"writing MP4 needs the imageio-ffmpeg package ({error}); write a .gif or a folder instead"
        ) from None
