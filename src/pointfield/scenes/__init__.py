"""Scenes: posed images, their cameras and rays, every common dataset format, synthetic scenes.

One internal camera convention -- OpenCV / COLMAP: x right, y down, looking down +z, poses
camera-to-world -- with every format converted at the edge (see :mod:`pointfield.scenes.cameras`
and docs/cameras.md)::

    from pointfield.scenes import read_scene
    scene = read_scene("nerf_synthetic/lego", downscale=8)   # Blender, nerfstudio, LLFF, COLMAP, npz
    rays = scene.cameras.rays(0)                             # (H, W) rays through pixel centres
    image = scene.image(0)                                   # (H, W, 3) float32, alpha on white

    from pointfield.scenes import make_scene, synthetic_scene
    make_scene("cube", "cube-dataset", views=100, size=100)  # the built-in dataset, written to disk
    scene = synthetic_scene("cube")                          # the same, in memory: the default scene
"""

from pointfield.scenes.cameras import (
    CAMERA_MODELS,
    Cameras,
    Rays,
    look_at,
    opencv_to_opengl,
    opengl_to_opencv,
    pixel_centers,
)
from pointfield.scenes.formats import detect_scene_format, read_scene, scene_formats, write_scene
from pointfield.scenes.scene import Frame, Scene, SceneError
from pointfield.scenes.synthetic import (
    SYNTHETIC_SCENES,
    make_scene,
    render_scene,
    synthetic_scene,
    synthetic_truth,
)
from pointfield.scenes.tools import convert_scene, plot_cameras, scene_info

__all__ = [
    "CAMERA_MODELS",
    "SYNTHETIC_SCENES",
    "Cameras",
    "Frame",
    "Rays",
    "Scene",
    "SceneError",
    "convert_scene",
    "detect_scene_format",
    "look_at",
    "make_scene",
    "opencv_to_opengl",
    "opengl_to_opencv",
    "pixel_centers",
    "plot_cameras",
    "read_scene",
    "render_scene",
    "scene_formats",
    "scene_info",
    "synthetic_scene",
    "synthetic_truth",
    "write_scene",
]
