"""Sparse points carried across from a COLMAP model that lies beside another description of a scene.

A folder often holds two descriptions of one capture: instant-ngp's ``colmap2nerf.py`` and
nerfstudio's ``ns-process-data`` write a ``transforms.json`` beside the COLMAP model it came
from (``sparse/0``), and LLFF folders keep theirs too. The transforms file is read first (it is
what NeRF tools train from) but it holds no points, or only a ``ply_file_path``; the model holds
the sparse points. When the scene that was read has no points and its folder holds a COLMAP
model of the same photos, the model's points are carried across into the scene's world frame.

The two frames differ by a similarity (colmap2nerf rotates the up direction onto +z, recentres
and rescales the cameras), found from the cameras the two share (matched by image file name) as
:func:`pointfield.scenes.alignment.pose_errors` finds it: ``p_scene = s R p_model + t``. The points
are carried only when that similarity fits every shared camera (rotation within
:data:`MAX_ROTATION_DEGREES`, centre within :data:`MAX_CENTRE_FRACTION` of the cameras' extent):
a model of other photos, or of the same photos posed again, is left alone.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.errors import PointfieldError
from pointfield.scenes.alignment import pose_errors
from pointfield.scenes.scene import Scene

MAX_ROTATION_DEGREES = 0.5
MAX_CENTRE_FRACTION = 0.005
MIN_SHARED_CAMERAS = 2


def with_companion_points(scene: Scene, root: Path) -> Scene:
    """``scene`` with the sparse points of the COLMAP model in ``root`` carried across (module
    docstring), or ``scene`` itself when it has points, there is no model, or the model is not of
    the same cameras. ``metadata["points_from"]`` names the model's folder when points were carried."""
    from pointfield.scenes.formats.colmap.scene import detect_colmap, read_colmap

    if scene.points is not None or not root.is_dir() or not detect_colmap(root):
        return scene
    try:
        model = read_colmap(root, missing_images="keep")
    except (PointfieldError, OSError):
        return scene  # a model that cannot be read adds nothing; the scene read stands on its own
    if model.points is None or len(model.points) == 0:
        return scene
    ours = {Path(frame.name).name: index for index, frame in enumerate(scene.frames)}
    shared = [(ours[Path(frame.name).name], index) for index, frame in enumerate(model.frames)
              if Path(frame.name).name in ours]
    if len(shared) < MIN_SHARED_CAMERAS:
        return scene
    given = scene.cameras.camera_to_world[[i for i, _ in shared]].double().numpy()
    found = model.cameras.camera_to_world[[j for _, j in shared]].double().numpy()
    fit = pose_errors(found, given)
    if fit.rotation_degrees.max() > MAX_ROTATION_DEGREES or fit.centre_fraction.max() > MAX_CENTRE_FRACTION:
        return scene
    points = fit.scale * model.points.points.astype(np.float64) @ fit.rotation.T + fit.translation
    carried = PointCloud(points.astype(model.points.points.dtype), dict(model.points.fields))
    metadata = {**scene.metadata, "points_from": model.metadata.get("path", str(root))}
    return dataclasses.replace(scene, points=carried, metadata=metadata)
