"""Camera paths through a scene, for turntables and fly-throughs of any scene model.

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
is the mean of their up vectors (-y in OpenCV).
"""

from __future__ import annotations

import numpy as np

from pointfield.errors import PointfieldError
from pointfield.scenes.cameras import Cameras, look_at
from pointfield.scenes.scene import Scene

PATHS = ("orbit", "spiral", "dataset")


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
