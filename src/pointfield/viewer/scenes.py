"""A scene folder in the browser: camera frustums with thumbnails, the sparse points, the photos.

:func:`show_scene` reads any scene ``pointfield scene info`` reads
(:func:`pointfield.scenes.read_scene`) and adds, under ``/<name>``:

- one frustum per camera, at its pose, with its field of view and aspect, coloured by split
  (train grey, test / val orange); the thumbnails (:data:`THUMBNAIL_SIZE` pixels) fill in from a
  thread while the page is already usable;
- the scene's sparse points (COLMAP ``points3D``, ``scene from-images``), where it has them;
- clicking a frustum shows its photo in the panel, with its name, and moves the camera there.

The frustums' size follows the spread of the cameras (:func:`frustum_scale`).
"""

from __future__ import annotations

import os
import threading
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from pointfield.scenes.formats.registry import read_scene
from pointfield.scenes.paths import scene_centre_and_up
from pointfield.scenes.scene import Scene
from pointfield.viewer.clouds import (
    DEFAULT_MAX_POINTS,
    as_uint8,
    decimate,
    typical_spacing,
)
from pointfield.viewer.server import Viewer, wxyz_of
from pointfield.viz.render import normalised_colours
from pointfield.viz.views import to_uint8

THUMBNAIL_SIZE = 96
PHOTO_SIZE = 480
SPLIT_COLOURS = {"train": (90, 90, 90), "test": (255, 140, 0), "val": (255, 140, 0)}


def frustum_scale(scene: Scene) -> float:
    """Frustum depth: a tenth of the cameras' mean distance to what they look at, less where
    neighbours are closer than twice that (so that frustums do not overlap)."""
    centres = scene.cameras.centers.double().numpy()
    target, _ = scene_centre_and_up(scene)
    reach = 0.1 * float(np.linalg.norm(centres - target, axis=1).mean()) or 0.1
    if len(centres) < 2:
        return reach
    distances = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    np.fill_diagonal(distances, np.inf)
    nearest = float(np.median(distances.min(axis=1)))
    return min(reach, nearest / 2) if nearest > 0 else reach


def scene_framing(scene: Scene, back: float = 2.0, lift: float = 0.5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(target, eye, up)`` for a first look from the scene's first training camera
    (:func:`first_training_camera`), along its own axis, from ``back`` times its distance to what
    the cameras look at, raised by ``lift`` times that distance. ``up`` is the cameras' mean up
    (:func:`~pointfield.scenes.paths.scene_centre_and_up`), so that the page orbits upright.
    ``back=1, lift=0`` is that camera's own view, as its photo shows it (less any roll of its own);
    the defaults step back and up so that its neighbours' frustums are in view too."""
    centre, up = scene_centre_and_up(scene)
    index = first_training_camera(scene)
    forward = scene.cameras.rotations.double().numpy()[index][:, 2]  # OpenCV axes: looking down +z
    camera = scene.cameras.centers.double().numpy()[index]
    distance = float(np.linalg.norm(centre - camera)) or 1.0
    eye = camera - (back - 1) * distance * forward + lift * distance * up
    return camera + distance * forward, eye, up


def first_training_camera(scene: Scene) -> int:
    """The first camera of the training split (in no held-out split), where a page of the scene starts."""
    held_out = {int(index) for name in ("val", "test") for index in scene.splits.get(name, [])}
    return next((index for index in range(len(scene)) if index not in held_out), 0)


def vertical_fov(scene: Scene, index: int) -> float:
    """Camera ``index``'s vertical field of view in radians, ``2 atan(h / 2 fy)``, as viser takes it."""
    cameras = scene.cameras
    return float(2 * np.arctan(0.5 * int(cameras.height[index]) / float(cameras.fy[index])))


def split_of(scene: Scene) -> list[str]:
    """The split each frame belongs to (train when it is in none)."""
    names = ["train"] * len(scene)
    for name in ("val", "test"):
        for index in scene.splits.get(name, []):
            names[int(index)] = name
    return names


def add_frustums(viewer: Viewer, scene: Scene, node: str, *, thumbnails: bool = True,
                 on_click: Any = None, visible: bool = True) -> list[Any]:
    """One frustum per camera of ``scene`` under ``node``; thumbnails fill in from a thread."""
    cameras = scene.cameras
    rotations = cameras.rotations.double().numpy()
    centres = cameras.centers.double().numpy() - viewer.origin
    scale = frustum_scale(scene)
    splits = split_of(scene)
    handles = []
    for index in range(len(cameras)):
        width, height = int(cameras.width[index]), int(cameras.height[index])
        handle = viewer.server.scene.add_camera_frustum(
            f"{node}/{index:04d}", fov=vertical_fov(scene, index), aspect=width / height, scale=scale,
            thickness=scale / 60, color=SPLIT_COLOURS[splits[index]],
            wxyz=wxyz_of(rotations[index]), position=tuple(centres[index]), visible=visible,
        )
        if on_click is not None:
            handle.on_click(lambda event, i=index: on_click(i, event))
        handles.append(handle)
    if thumbnails:
        def fill() -> None:
            for index, handle in enumerate(handles):
                if scene.frames[index].has_image:
                    handle.image = resized(scene.image(index), THUMBNAIL_SIZE)

        threading.Thread(target=fill, name="pointfield-view-thumbnails", daemon=True).start()
    return handles


def resized(image: np.ndarray, longest_side: int) -> np.ndarray:
    """A scene's ``(H, W, 3)`` float image in [0, 1] as uint8, at most ``longest_side`` pixels along its longer side."""
    picture = Image.fromarray(to_uint8(image))
    picture.thumbnail((longest_side, longest_side))
    return np.asarray(picture)


class SceneView:
    """A scene on the page: its frustums, sparse points and the photo panel (see the module doc)."""

    def __init__(self, viewer: Viewer, scene: Scene, name: str, max_points: int):
        self.viewer = viewer
        self.scene = scene
        self.name = name
        gui = viewer.server.gui
        with gui.add_folder(name):
            counts = ", ".join(f"{split} {len(frames)}" for split, frames in scene.splits.items())
            cameras = scene.cameras
            gui.add_markdown(
                f"{scene.metadata.get('format', 'scene')} scene, {len(scene)} cameras ({counts}), "
                f"{int(cameras.width[0])}x{int(cameras.height[0])}"
                + (f", {len(scene.points.points):,} sparse points" if scene.points is not None else "")
            )
            self.caption = gui.add_markdown("click a camera to see its photo")
            self.photo = gui.add_image(np.zeros((9, 16, 3), np.uint8), visible=False)
        self.frustums = add_frustums(viewer, scene, f"/{name}/cameras", on_click=self.clicked)
        self.points = None
        if scene.points is not None and len(scene.points.points):
            points = np.asarray(scene.points.points, np.float64)
            colours = scene.points.fields.get("colors")
            size = typical_spacing(points.min(0), points.max(0), len(points)) / 2
            keep = decimate(len(points), max_points)
            keep = slice(None) if keep is None else keep
            self.points = viewer.server.scene.add_point_cloud(
                f"/{name}/points", (points[keep] - viewer.origin).astype(np.float32),
                (200, 200, 200) if colours is None else as_uint8(normalised_colours(colours[keep])),
                point_size=size, precision="float32",
            )

    def clicked(self, index: int, event: Any) -> None:
        """Show camera ``index``'s photo and move the clicking tab's camera to its pose."""
        frame = self.scene.frames[index]
        self.caption.content = f"camera {index}: **{frame.name}**"
        if frame.has_image:
            self.photo.image = resized(self.scene.image(index), PHOTO_SIZE)
            self.photo.visible = True
        cameras = self.scene.cameras
        camera = event.client.camera
        centre = cameras.centers.double().numpy()[index] - self.viewer.origin
        rotation = cameras.rotations.double().numpy()[index]
        camera.wxyz = wxyz_of(rotation)
        camera.position = tuple(centre)
        camera.fov = vertical_fov(self.scene, index)


def show_scene(viewer: Viewer, path: str | os.PathLike[str], name: str, *,
               max_points: int = DEFAULT_MAX_POINTS) -> SceneView:
    """Add the scene at ``path`` to the page (see the module doc); returns its view."""
    scene = read_scene(Path(path))
    centres = scene.cameras.centers.double().numpy()
    low, high = centres.min(0), centres.max(0)
    if scene.points is not None and len(scene.points.points):
        low = np.minimum(low, np.asarray(scene.points.points).min(0))
        high = np.maximum(high, np.asarray(scene.points.points).max(0))
    viewer.recentre(low, high)
    viewer.grow(low, high)
    view = SceneView(viewer, scene, name, max_points)
    viewer.first_look(*scene_framing(scene))
    return view
