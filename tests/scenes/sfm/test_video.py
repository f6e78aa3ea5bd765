"""Video frames: the sharpest frame of each window is kept, and what is not a video says so."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image
from scipy.ndimage import uniform_filter

from pointfield.scenes.sfm import PosingError, extract_frames, sharpness

iio = pytest.importorskip("imageio.v3")
pytest.importorskip("imageio_ffmpeg")

WINDOW, WINDOWS, SIZE = 4, 10, (128, 96)


def textured_frames() -> tuple[np.ndarray, list[int]]:
    """``WINDOWS * WINDOW`` frames of a drifting texture; one sharp frame per window, the rest blurred."""
    rng = np.random.default_rng(0)
    texture = rng.integers(0, 256, (SIZE[1], SIZE[0] * 3, 3)).astype(np.float32)
    texture = uniform_filter(texture, size=(3, 3, 1))
    frames, sharp = [], []
    for index in range(WINDOWS * WINDOW):
        frame = texture[:, 4 * index : 4 * index + SIZE[0]]
        if index % WINDOW == (index // WINDOW) % WINDOW:  # the sharp one moves around in its window
            sharp.append(index)
        else:
            frame = uniform_filter(frame, size=(9, 9, 1))
        frames.append(np.clip(frame, 0, 255).astype(np.uint8))
    return np.stack(frames), sharp


def test_sharpness_is_higher_for_crisp_than_for_blurred_images():
    frames, sharp = textured_frames()
    assert sharpness(frames[sharp[0]]) > 3 * sharpness(frames[sharp[0] + 1])
    assert sharpness(np.zeros((10, 10))) == 0.0


def test_the_sharpest_frame_of_each_window_is_written_in_time_order(tmp_path):
    frames, sharp = textured_frames()
    clip = tmp_path / "walk.mp4"
    iio.imwrite(clip, frames, plugin="FFMPEG", fps=10, quality=10)
    written = extract_frames(clip, tmp_path / "frames", count=WINDOWS, progress=False)
    assert [p.name for p in written] == [f"frame_{i:05d}.jpg" for i in range(1, WINDOWS + 1)]
    for path, expected in zip(written, sharp):
        image = np.asarray(Image.open(path), np.float32)
        nearest = int(np.argmin([np.abs(image - f).mean() for f in frames.astype(np.float32)]))
        assert nearest == expected


def test_asking_for_more_frames_than_the_clip_has_gives_every_frame(tmp_path):
    frames, _ = textured_frames()
    clip = tmp_path / "short.mp4"
    iio.imwrite(clip, frames[:6], plugin="FFMPEG", fps=10)
    assert len(extract_frames(clip, tmp_path / "frames", count=150, progress=False)) == 6


def test_missing_files_non_videos_and_too_few_frames_are_refused(tmp_path):
    with pytest.raises(PosingError, match="no such video file"):
        extract_frames(tmp_path / "missing.mp4", tmp_path / "out")
    fake = tmp_path / "clip.mp4"
    fake.write_text("not a video")
    with pytest.raises(PosingError, match="clip.mp4: .*is it a video file"):
        extract_frames(fake, tmp_path / "out")
    with pytest.raises(PosingError, match="at least 3"):
        extract_frames(fake, tmp_path / "out", count=2)
