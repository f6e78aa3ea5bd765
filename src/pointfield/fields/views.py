"""Rendering a trained NeRF along a camera path: ``pointfield nerf render``.

Paths (all cameras share the first scene camera's intrinsics; poses in pointfield's OpenCV
convention, built with :func:`pointfield.scenes.look_at`):

- ``orbit``: ``frames`` cameras on a circle around the scene's centre, at the training
  cameras' mean distance and height, looking at the centre. When the training cameras only
  cover an arc (a capture of something against a wall, a forward-facing scene: a gap of more
  than 90 degrees between neighbouring cameras), the orbit sweeps that arc there and back
  instead, so it never looks at what no photo saw and still loops smoothly.
- ``spiral``: the orbit with its height swinging up and down twice per turn.
- ``dataset``: the scene's own cameras in order (``frames`` of them, evenly spaced).

The centre is the point nearest to all training cameras' optical axes (least squares), "up"
is the mean of their up vectors (-y in OpenCV). Output by suffix: ``.gif`` (imageio),
``.mp4`` (needs the ``imageio-ffmpeg`` package), otherwise a folder of PNGs
(``color_NNN.png``, ``depth_NNN.png``, ``opacity_NNN.png``). GIF and MP4 frames show colour,
depth and opacity side by side.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
import torch

from pointfield.errors import PointfieldError
from pointfield.scenes import Cameras, Scene, look_at

PATHS = ("orbit", "spiral", "dataset")
FRAMES_PER_SECOND = 20


def scene_centre_and_up(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares point nearest every camera's optical axis, and the cameras' mean up vector."""
    rotations = scene.cameras.rotations.double().numpy()
    centre, pinned = scene.cameras.axes_focus()
    if not pinned:  # (nearly) parallel axes: no single point to look at; one unit ahead
        centre = scene.cameras.centers.double().numpy().mean(0) + rotations[:, :, 2].mean(0)
    up = -rotations[:, :, 1].mean(0)
    return centre, up / max(np.linalg.norm(up), 1e-12)


def orbit_angles(camera_angles: np.ndarray, count: int) -> np.ndarray:
    """``count`` angles (radians) for an orbit given the training cameras' angles around the centre.

    The full circle when the cameras surround the scene; otherwise the arc they span (its
    largest gap between neighbours, over 90 degrees, left out), swept there and back.
    """
    ordered = np.sort(np.mod(camera_angles, 2 * np.pi))
    gaps = np.diff(np.concatenate([ordered, ordered[:1] + 2 * np.pi]))
    widest = int(np.argmax(gaps))
    if len(ordered) < 2 or gaps[widest] <= np.pi / 2:
        return 2 * np.pi * np.arange(count) / count
    start = ordered[(widest + 1) % len(ordered)]  # the arc begins after the gap ...
    span = 2 * np.pi - gaps[widest]  # ... and runs to where the gap begins
    phase = 0.5 - 0.5 * np.cos(2 * np.pi * np.arange(count) / count)  # 0 -> 1 -> 0, easing at the ends
    return start + span * phase


def path_cameras(scene: Scene, path: str, frames: int | None) -> Cameras:
    """The cameras of render path ``path`` (see the module docstring)."""
    if path not in PATHS:
        raise PointfieldError(f"unknown render path {path!r}; choose one of {', '.join(PATHS)}")
    count = len(scene) if (path == "dataset" and frames is None) else (60 if frames is None else frames)
    if count < 1:
        raise PointfieldError(f"a render path needs at least one frame, got --frames {count}")
    cameras = scene.cameras
    if path == "dataset":
        return cameras[np.linspace(0, len(scene) - 1, min(count, len(scene))).round().astype(np.int64)]
    centre, up = scene_centre_and_up(scene)
    offsets = cameras.centers.double().numpy() - centre
    height = offsets @ up
    horizontal = offsets - height[:, None] * up
    radius = float(np.linalg.norm(horizontal, axis=1).mean())
    first = horizontal[0] / max(np.linalg.norm(horizontal[0]), 1e-12)
    second = np.cross(up, first)
    angles = orbit_angles(np.arctan2(horizontal @ second, horizontal @ first), count)
    heights = np.full(count, float(height.mean()))
    if path == "spiral":
        heights = heights + 0.5 * float(height.std() + 0.25 * radius) * np.sin(2 * angles)
    around = np.cos(angles)[:, None] * first + np.sin(angles)[:, None] * second
    eyes = centre + radius * around + heights[:, None] * up
    poses = look_at(eyes, target=centre, up=up)
    return Cameras(
        poses, cameras.fx[0].item(), cameras.fy[0].item(), cameras.cx[0].item(), cameras.cy[0].item(),
        int(cameras.width[0]), int(cameras.height[0]),
    )


def render(
    run: str | os.PathLike[str],
    *,
    path: str = "orbit",
    frames: int | None = None,
    out: str | os.PathLike[str] = "render.gif",
    device: str | None = None,
) -> dict[str, Any]:
    """Render a trained run along ``path`` into ``out`` (``.gif``, ``.mp4`` or a folder)."""
    from pointfield.fields.train import RaySet, load_run, open_scene_of, ray_bounds, render_view

    out = Path(out)
    suffix = out.suffix.lower()
    if suffix == ".mp4":
        _require_ffmpeg()
    elif suffix not in ("", ".gif"):
        raise PointfieldError(f"{out}: render output must end in .gif or .mp4, or be a folder")
    _, config, network, torch_device = load_run(run, device)
    scene = open_scene_of(config)
    cameras = path_cameras(scene, path, frames)
    bounds = ray_bounds(scene)
    near, far = float(bounds[:, 0].min()), float(bounds[:, 1].max())
    background = torch.as_tensor(scene.background, device=torch_device)
    views = []
    for index in range(len(cameras)):
        rays = cameras.rays(index).reshape(-1)
        count = rays.shape[0]
        ray_set = RaySet(
            rays.origins.float().to(torch_device), rays.directions.float().to(torch_device),
            torch.zeros(count, 3, device=torch_device),
            torch.full((count,), near, device=torch_device), torch.full((count,), far, device=torch_device),
        )
        height, width = int(cameras.height[index]), int(cameras.width[index])
        views.append(render_view(network, ray_set, height, width, background))
    write_views(views, out, near, far)
    return {"out": str(out), "frames": len(views), "path": path}


def write_views(views: list[dict[str, np.ndarray]], out: Path, near: float, far: float) -> None:
    """Write rendered views as a GIF / MP4 of colour | depth | opacity panels, or as PNG files."""
    import imageio.v3 as iio

    from pointfield.atomic import atomic_path
    from pointfield.fields.train import depth_image, to_uint8, view_panel
    from pointfield.viz.render import save_image

    suffix = out.suffix.lower()
    if suffix in (".gif", ".mp4"):
        out.parent.mkdir(parents=True, exist_ok=True)
        frames = np.stack([view_panel(view, near, far) for view in views])
        with atomic_path(out) as tmp:
            if suffix == ".gif":
                iio.imwrite(tmp, frames, extension=".gif", duration=1000 / FRAMES_PER_SECOND, loop=0)
            else:
                # libx264 needs even sizes: pad with one white row / column where odd.
                pad = ((0, 0), (0, frames.shape[1] % 2), (0, frames.shape[2] % 2), (0, 0))
                frames = np.pad(frames, pad, constant_values=255)
                _write_mp4(tmp, frames)
        return
    out.mkdir(parents=True, exist_ok=True)
    for index, view in enumerate(views):
        save_image(out / f"color_{index:03d}.png", to_uint8(view["color"]))
        save_image(out / f"depth_{index:03d}.png", depth_image(view["depth"], view["opacity"], near, far))
        save_image(out / f"opacity_{index:03d}.png", to_uint8(view["opacity"]))


def _write_mp4(path: Path, frames: np.ndarray) -> None:
    import imageio.v2 as imageio

    writer = imageio.get_writer(
        path, format="FFMPEG", fps=FRAMES_PER_SECOND, codec="libx264", macro_block_size=1
    )
    with writer:
        for frame in frames:
            writer.append_data(frame)


def _require_ffmpeg() -> None:
    try:
        import imageio_ffmpeg

        imageio_ffmpeg.get_ffmpeg_exe()
    except (ImportError, RuntimeError) as error:
        raise PointfieldError(
            f"writing MP4 needs the imageio-ffmpeg package ({error}); write a .gif or a folder instead"
        ) from None
