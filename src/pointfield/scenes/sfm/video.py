"""Frames to pose from a video: the sharpest frame of each stretch, so that motion blur stays out.

A hand-held clip blurs whenever the camera moves fast, and blurred frames match badly. The
clip's frames are split into ``count`` consecutive windows of equal length and each window
gives its sharpest frame, measured by :func:`sharpness`. Frames are decoded one at a time by
ffmpeg (through imageio and imageio-ffmpeg, which ships its own ffmpeg binary); only the best
frame of the current window is held, so a long 4K clip needs no more memory than two frames.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from pointfield.scenes.sfm.errors import PosingError

SHARPNESS_SIDE = 640
"""Sharpness is measured on the grey frame shrunk to at most this long side (by block means)."""
MIN_FRAMES = 3


def sharpness(image: np.ndarray) -> float:
    """Variance of the Laplacian of the grey image: high for crisp edges, low for blur.

    ``image`` is ``(H, W)`` or ``(H, W, C)``, any numeric type; grey is the mean of the first three
    channels. The Laplacian is the 4-neighbour stencil ``L = p[y-1,x] + p[y+1,x] + p[y,x-1] +
    p[y,x+1] - 4 p[y,x]`` over interior pixels, after shrinking the frame by an integer factor
    (block means) to at most :data:`SHARPNESS_SIDE` pixels on its longer side.
    """
    grey = np.asarray(image, np.float32)
    if grey.ndim == 3:
        grey = grey[..., :3].mean(axis=2)
    factor = max(1, -(-max(grey.shape) // SHARPNESS_SIDE))
    if factor > 1:
        height, width = (grey.shape[0] // factor) * factor, (grey.shape[1] // factor) * factor
        grey = grey[:height, :width].reshape(height // factor, factor, width // factor, factor).mean(axis=(1, 3))
    laplacian = grey[:-2, 1:-1] + grey[2:, 1:-1] + grey[1:-1, :-2] + grey[1:-1, 2:] - 4 * grey[1:-1, 1:-1]
    return float(laplacian.var()) if laplacian.size else 0.0


def extract_frames(
    clip: str | os.PathLike[str], folder: str | os.PathLike[str], count: int = 150, *, progress: bool = True
) -> list[Path]:
    """Write the sharpest frame of each of ``count`` windows of ``clip`` as ``folder/frame_00001.jpg``, ...

    Frames are numbered in time order; each file is written atomically (JPEG, quality 95). A clip
    with fewer frames than ``count`` gives all of them. Raises :class:`PosingError` for a
    missing clip, one ffmpeg cannot decode, or ``count`` under 3.
    """
    clip, folder = Path(clip), Path(folder)
    if count < MIN_FRAMES:
        raise PosingError(f"--frames must be at least {MIN_FRAMES}, got {count}")
    if not clip.is_file():
        raise PosingError(f"{clip}: no such video file")
    frames = _frame_count(clip)
    windows = min(count, frames)
    folder.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    best: tuple[float, np.ndarray] | None = None
    window = 0
    for index, frame in enumerate(_frames(clip, frames, progress)):
        # Frame i belongs to window floor(i * windows / frames): equal windows, none empty.
        frame_window = index * windows // frames
        if frame_window != window and best is not None:
            written.append(_write(folder, len(written) + 1, best[1]))
            best = None
        window = frame_window
        score = sharpness(frame)
        if best is None or score > best[0]:
            best = (score, frame)
    if best is not None:
        written.append(_write(folder, len(written) + 1, best[1]))
    if not written:
        raise PosingError(f"{clip}: no frame could be decoded; is it a video file?")
    return written


def _frame_count(clip: Path) -> int:
    """Frames in the clip: counted by decoding once (container metadata is often an estimate)."""
    iio = _imageio()
    try:
        frames = sum(1 for _ in iio.imiter(clip, plugin="FFMPEG"))
    except (OSError, RuntimeError, ValueError, StopIteration) as error:
        message = str(error).strip().splitlines()[-1] if str(error).strip() else type(error).__name__
        raise PosingError(
            f"{clip}: no video stream could be decoded (ffmpeg: {message[:200]}); is it a video file?"
        ) from None
    if frames == 0:
        raise PosingError(f"{clip}: no frame could be decoded; is it a video file?")
    return frames


def _frames(clip: Path, frames: int, progress: bool):
    from tqdm.auto import tqdm

    iio = _imageio()
    with tqdm(total=frames, desc="frames", unit="frame", disable=not progress) as bar:
        for frame in iio.imiter(clip, plugin="FFMPEG"):
            bar.update(1)
            yield frame


def _write(folder: Path, number: int, frame: np.ndarray) -> Path:
    from PIL import Image

    from pointfield.atomic import atomic_path

    path = folder / f"frame_{number:05d}.jpg"
    with atomic_path(path) as temporary:
        Image.fromarray(np.asarray(frame, np.uint8)[..., :3]).save(temporary, format="JPEG", quality=95)
    return path


def _imageio():
    try:
        import imageio.v3 as iio
        import imageio_ffmpeg  # noqa: F401  (the FFMPEG plugin needs it)
    except ImportError:
        raise PosingError(
            "reading video needs imageio-ffmpeg: pip install imageio-ffmpeg (or pointfield[video])"
        ) from None
    return iio
