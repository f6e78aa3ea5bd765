"""Posed-image dataset formats: one module per format, one registry behind read_scene / write_scene.

Detection order (the first format that recognises a folder wins): Blender
(``transforms_{train,val,test}.json``), nerfstudio / instant-ngp (``transforms.json``), LLFF
(``poses_bounds.npy``), COLMAP (``cameras`` + ``images`` .bin/.txt, here or in ``sparse/0``),
npz (``tiny_nerf_data.npz``). Pass ``format=`` to choose another reading of the same folder.
"""

from pointfield.scenes.formats import blender, colmap, llff, npz, transforms_json  # noqa: F401  (registers)
from pointfield.scenes.formats.registry import (
    SceneFormat,
    detect_scene_format,
    read_scene,
    register,
    scene_format_named,
    scene_formats,
    write_scene,
)

__all__ = [
    "SceneFormat",
    "detect_scene_format",
    "read_scene",
    "register",
    "scene_format_named",
    "scene_formats",
    "write_scene",
]
