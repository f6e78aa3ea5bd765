"""Which part of a scene to reconstruct: the scene box, bounded or not, and the grid's finest level.

``pointfield nerf train --model ngp`` asks :func:`scene_bounds` for the box the fast field covers
(``--scene-box``), :func:`default_max_resolution` for the finest hash-grid level, and
:func:`steps_a_pixel_allows` for the finest marching step its images can use. Scenes are
read duck-typed (``cameras``, ``splits``, ``alpha``, ``aabb``, ``points``, ``near_far`` of
:class:`pointfield.scenes.Scene`).
"""

from __future__ import annotations

import math

import numpy as np


def default_max_resolution(scene, unbounded: bool) -> int:
    """The finest hash-grid level for a scene: twice the image's longer side (four times when unbounded).

    Finer than that, a grid cell is smaller than what one pixel sees of the box; the
    contraction keeps the region of interest in the central half of the cube, hence the 4.
    """
    side = int(max(int(scene.cameras.width.max()), int(scene.cameras.height.max())))
    return max(64, (4 if unbounded else 2) * side)


STEPS_PER_PIXEL = 4
"""The most marching steps one pixel's footprint at the box's centre may span (see :func:`steps_a_pixel_allows`)."""
NO_STEP_LIMIT = 1 << 30
"""What :func:`steps_a_pixel_allows` returns where a pixel sees no width at the box's centre."""


def steps_a_pixel_allows(scene, box) -> int:
    """The most steps across ``box``'s diagonal that keep a step no finer than a quarter of a pixel.

    A pixel's footprint is, over the cameras, the median of the distance to the box's centre
    over the focal length. Steps far finer than that resolve nothing the images show, and they
    also stall training: on the textured cube at 100 x 100 (a tight box, so the paper's 1,024
    steps are a fourteenth of a pixel), the hash-grid field stayed a semi-transparent fog
    (held-out 22.3 dB after 400 steps on the CPU, 21.5 dB after 18 s on an H200) where 256
    steps (about a quarter of a pixel) reached 30.3 and 32.9 dB; lego at 100 x 100 (a loose
    box, a fifth of a pixel) trains with 1,024 (benchmarks/previous-runs.md, "The GPU leases", fourth
    lease).
    """
    box = np.asarray(box, dtype=np.float64).reshape(2, 3)
    cameras = scene.cameras
    distance = np.linalg.norm(cameras.centers.double().cpu().numpy() - box.mean(axis=0), axis=1)
    focal = np.maximum(cameras.fx.double().cpu().numpy(), cameras.fy.double().cpu().numpy())
    footprint = float(np.median(distance / focal))
    steps = STEPS_PER_PIXEL * float(np.linalg.norm(box[1] - box[0])) / footprint if footprint > 0 else math.inf
    return max(1, int(min(steps, NO_STEP_LIMIT)))


def scene_bounds(scene, scene_box="auto") -> tuple[list[list[float]], bool]:
    """The ``(2, 3)`` box to reconstruct and whether the scene is unbounded, for ``--scene-box``.

    ``scene_box``: "auto" (default), "bounded", "unbounded", or six numbers
    ``min x, y, z, max x, y, z`` (a bounded box). Automatically, a scene whose images have an
    alpha channel is a synthetic object on a transparent background (bounded); real photos are
    unbounded (contracted, proposal sampler). A bounded box is the scene's ``aabb`` if it has
    one, else the central 98 % of its sparse points, else the cube the cameras look into:
    centred where the optical axes pass closest (for a forward-facing capture, whose axes do not
    meet, half-way between the median near and far bounds ahead of the cameras), half as wide as
    the median camera's view at that distance (``distance * tan(fov / 2)``) plus 10 %. For an
    unbounded scene the box is always that last one -- the region of interest that the
    contraction leaves undistorted -- since a capture's ``aabb`` (e.g. instant-ngp's ``aabb_scale``) encloses its background too.
    """
    if not isinstance(scene_box, str):
        values = [float(v) for v in scene_box]
        if len(values) != 6:
            raise ValueError(f"--scene-box needs six numbers (min x y z, max x y z), got {len(values)}")
        return [values[:3], values[3:]], False
    if scene_box not in ("auto", "bounded", "unbounded"):
        raise ValueError(f"--scene-box must be auto, bounded, unbounded or six numbers, got {scene_box!r}")
    if scene_box == "auto":
        first = int(scene.splits.get("train", np.arange(len(scene)))[0])
        unbounded = scene.alpha(first) is None
    else:
        unbounded = scene_box == "unbounded"
    if unbounded:
        box = _box_cameras_look_into(scene.cameras, scene.near_far)
    elif scene.aabb is not None:
        box = np.asarray(scene.aabb, dtype=np.float64)
    elif scene.points is not None and len(scene.points):
        box = np.percentile(np.asarray(scene.points.points, dtype=np.float64), [1, 99], axis=0)
    else:
        box = _box_cameras_look_into(scene.cameras, scene.near_far)
    return box.tolist(), unbounded


def _box_cameras_look_into(cameras, near_far=None) -> np.ndarray:
    """The ``(2, 3)`` cube the cameras look into (:func:`scene_bounds`)."""
    centers = cameras.centers.double().numpy()
    focus, pinned = cameras.axes_focus()
    if not pinned and near_far is not None:
        # Nearly parallel axes (a forward-facing capture): look half-way between the median
        # near and far bounds ahead of the cameras instead.
        axis = cameras.rotations[:, :, 2].double().numpy().mean(axis=0)
        middle = float(np.median(np.asarray(near_far, dtype=np.float64).mean(axis=1)))
        focus = centers.mean(axis=0) + middle * axis / np.linalg.norm(axis)
    distance = np.median(np.linalg.norm(centers - focus, axis=1))
    half_fov = np.maximum(np.arctan(cameras.width.double().numpy() / (2 * cameras.fx.double().numpy())),
                          np.arctan(cameras.height.double().numpy() / (2 * cameras.fy.double().numpy())))
    half = 1.1 * distance * np.tan(np.median(half_fov))
    return np.stack([focus - half, focus + half])
