"""Pictures of rendered views: colour | depth | opacity panels, and paths of them as GIF, MP4 or PNGs.

A view is a dict of numpy arrays ``{"rgb": (H, W, 3), "depth": (H, W), "opacity": (H, W)}``
(what :meth:`pointfield.scenes.run.SceneRun.render` gives, as numpy). Depth is drawn grey,
near white and far dark between the ``near`` and ``far`` it is given, with empty pixels black.
Output by suffix: ``.gif`` (imageio), ``.mp4`` (needs the ``imageio-ffmpeg`` package),
otherwise a folder of PNGs (``color_NNN.png``, ``depth_NNN.png``, ``opacity_NNN.png``).
"""

from __future__ import annotations

from pathlib import Path

import imageio.v2 as imageio
import imageio.v3 as iio
import numpy as np

from pointfield.atomic import atomic_path
from pointfield.errors import PointfieldError
from pointfield.viz.render import save_image

FRAMES_PER_SECOND = 20
VIDEO_SUFFIXES = (".gif", ".mp4")


def to_uint8(image: np.ndarray) -> np.ndarray:
    """``(H, W)`` or ``(H, W, 3)`` floats in [0, 1] -> ``(H, W, 3)`` uint8."""
    image = (np.clip(image, 0, 1) * 255).round().astype(np.uint8)
    return np.repeat(image[..., None], 3, axis=2) if image.ndim == 2 else image


def depth_image(depth: np.ndarray, opacity: np.ndarray, near: float, far: float) -> np.ndarray:
    """Depth as ``(H, W, 3)`` uint8 grey: near white, far dark, empty pixels black."""
    scaled = 1 - np.clip((depth - near) / max(far - near, 1e-9), 0, 1)
    return np.repeat((np.clip(scaled * opacity, 0, 1) * 255).round().astype(np.uint8)[..., None], 3, axis=2)


def view_panel(
    view: dict[str, np.ndarray], near: float, far: float, truth: np.ndarray | None = None
) -> np.ndarray:
    """[ground truth |] colour | depth | opacity side by side, ``(H, k W, 3)`` uint8."""
    panels = [] if truth is None else [to_uint8(truth)]
    panels += [
        to_uint8(view["rgb"]),
        depth_image(view["depth"], view["opacity"], near, far),
        to_uint8(view["opacity"]),
    ]
    return np.concatenate(panels, axis=1)


def check_views_output(out: Path) -> None:
    """Refuse an output ``write_views`` cannot write, before anything is rendered."""
    suffix = out.suffix.lower()
    if suffix == ".mp4":
        _require_ffmpeg()
    elif suffix not in ("", *VIDEO_SUFFIXES):
        raise PointfieldError(f"{out}: render output must end in .gif or .mp4, or be a folder")


def write_views(views: list[dict[str, np.ndarray]], out: Path, near: float, far: float) -> None:
    """Write rendered views as a GIF / MP4 of colour | depth | opacity panels, or as PNG files."""
    check_views_output(out)
    suffix = out.suffix.lower()
    if suffix in VIDEO_SUFFIXES:
        out.parent.mkdir(parents=True, exist_ok=True)
        frames = np.stack([view_panel(view, near, far) for view in views])
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
        save_image(out / f"color_{index:03d}.png", to_uint8(view["rgb"]))
        save_image(out / f"depth_{index:03d}.png", depth_image(view["depth"], view["opacity"], near, far))
        save_image(out / f"opacity_{index:03d}.png", to_uint8(view["opacity"]))


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
