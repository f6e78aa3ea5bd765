"""COLMAP sparse models: ``cameras``, ``images``, ``points3D`` in ``.bin`` or ``.txt``, read into a Scene.

Registered as the scene format ``"colmap"``. Modules: ``model`` (what a model holds),
``binary`` and ``text`` (the two encodings of its files), ``folder`` (finding a model and
reading it whole), ``scene`` (poses inverted to camera-to-world, cameras converted, images
found: a model as a :class:`~pointfield.scenes.scene.Scene`).
"""

from pointfield.scenes.formats.colmap.folder import find_model_folder, read_colmap_model
from pointfield.scenes.formats.colmap.model import (
    ColmapCamera,
    ColmapImage,
    ColmapModel,
)
from pointfield.scenes.formats.colmap.scene import (
    detect_colmap,
    image_camera_to_world,
    quaternion_to_rotation,
    read_colmap,
)
from pointfield.scenes.formats.registry import SceneFormat, register

register(
    SceneFormat(
        name="colmap",
        description="COLMAP sparse model (cameras/images/points3D .bin or .txt; world-to-camera quaternions)",
        detect=detect_colmap,
        read=read_colmap,
        priority=40,
    )
)

__all__ = [
    "ColmapCamera",
    "ColmapImage",
    "ColmapModel",
    "detect_colmap",
    "find_model_folder",
    "image_camera_to_world",
    "quaternion_to_rotation",
    "read_colmap",
    "read_colmap_model",
]
