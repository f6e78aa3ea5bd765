"""The functions behind ``pointfield scene info|convert|cameras`` (``make`` is :func:`make_scene`).

Each command is a thin layer over the function of the same name and arguments here.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from pointfield.scenes.cameras import CAMERA_MODELS
from pointfield.scenes.formats import read_scene, write_scene
from pointfield.scenes.scene import Scene


def scene_info(
    path: str | os.PathLike[str],
    *,
    format: str | None = None,
    holdout_every: int | None = None,
    missing_images: str = "skip",
) -> dict[str, Any]:
    """Summary of the scene at ``path`` as a JSON-ready dict.

    Keys: ``path``, ``format``, ``frames`` (frames with an image), ``frames_listed`` (frames the
    dataset lists, images or not), ``splits`` (name -> count), ``width``, ``height``, ``fx``,
    ``fy``, ``cx``, ``cy`` (numbers when all cameras share them, else per-frame lists),
    ``camera_model``, ``distortion`` (name -> value when shared, else per-frame lists), ``near``,
    ``far`` (smallest near and largest far, or None), ``aabb`` (or None), ``points`` (count).
    """
    scene = read_scene(path, format, holdout_every=holdout_every, missing_images=missing_images)
    return describe_scene(scene)


def describe_scene(scene: Scene) -> dict[str, Any]:
    """The :func:`scene_info` dict of a scene already in memory."""
    cameras = scene.cameras
    info: dict[str, Any] = {
        "path": scene.metadata.get("path"),
        "format": scene.metadata.get("format"),
        "frames": sum(frame.has_image for frame in scene.frames),
        "frames_listed": scene.metadata.get("frames_listed", len(scene)),
        "splits": {name: len(indices) for name, indices in scene.splits.items()},
    }
    for key, values in (
        ("width", cameras.width),
        ("height", cameras.height),
        ("fx", cameras.fx),
        ("fy", cameras.fy),
        ("cx", cameras.cx),
        ("cy", cameras.cy),
    ):
        info[key] = _shared_or_list(values.tolist())
    info["camera_model"] = cameras.model
    info["distortion"] = {
        name: _shared_or_list(cameras.distortion[:, k].tolist())
        for k, name in enumerate(CAMERA_MODELS[cameras.model])
    }
    if scene.near_far is not None and len(scene.near_far):
        info["near"], info["far"] = float(np.min(scene.near_far[:, 0])), float(np.max(scene.near_far[:, 1]))
    else:
        info["near"] = info["far"] = None
    info["aabb"] = None if scene.aabb is None else np.asarray(scene.aabb, dtype=float).tolist()
    info["points"] = 0 if scene.points is None else len(scene.points)
    for key in ("encoding", "colmap_models", "aabb_scale", "holdout_every", "image_scale"):
        if key in scene.metadata:
            info[key] = scene.metadata[key]
    return info


def format_scene_info(info: dict[str, Any]) -> str:
    """The human-readable lines ``pointfield scene info`` prints."""

    def shown(value: Any) -> str:
        if isinstance(value, list):
            return f"{min(value):.6g}..{max(value):.6g} (per frame)" if value else "-"
        return f"{value:.6g}" if isinstance(value, float) else str(value)

    size = f"{shown(info['width'])} x {shown(info['height'])}"
    splits = ", ".join(f"{name} {count}" for name, count in info["splits"].items()) or "none"
    distortion = ", ".join(f"{name} {shown(value)}" for name, value in info["distortion"].items())
    lines = [
        f"{info['path']}: {info['format']} scene",
        f"  frames    {info['frames']} with images ({info['frames_listed']} listed); splits: {splits}",
        f"  images    {size}",
        (f"  camera    {info['camera_model']}, fx {shown(info['fx'])}, fy {shown(info['fy'])}, "
         f"cx {shown(info['cx'])}, cy {shown(info['cy'])}"),
    ]
    if distortion:
        lines.append(f"  distortion {distortion}")
    if info["near"] is not None:
        lines.append(f"  near/far  {info['near']:.6g} .. {info['far']:.6g}")
    if info["aabb"] is not None:
        low, high = info["aabb"]
        lines.append(f"  aabb      {[round(v, 4) for v in low]} .. {[round(v, 4) for v in high]}")
    lines.append(f"  points    {info['points'] or 'none'}")
    return "\n".join(lines)


def convert_scene(
    input: str | os.PathLike[str],
    output: str | os.PathLike[str],
    format: str = "nerfstudio",
    *,
    input_format: str | None = None,
    downscale: int = 1,
    holdout_every: int | None = None,
    missing_images: str = "skip",
    overwrite: bool = False,
) -> Path:
    """Read the scene at ``input`` and write it to the folder ``output`` as ``format`` (nerfstudio or blender).

    Images are copied unchanged where the format allows, otherwise re-encoded as PNG; with
    ``downscale`` they are area-downscaled and the cameras scaled to match.
    """
    scene = read_scene(
        input, input_format, downscale=downscale, holdout_every=holdout_every, missing_images=missing_images
    )
    return write_scene(scene, output, format, overwrite=overwrite)


def plot_cameras(
    path: str | os.PathLike[str] | Scene,
    out: str | os.PathLike[str],
    *,
    format: str | None = None,
    holdout_every: int | None = None,
    max_points: int = 20000,
) -> Path:
    """Write a PNG of the camera frustums (coloured by split) and sparse points of a scene."""
    from pointfield.scenes.cameras_plot import draw_cameras  # matplotlib: only when a plot is asked for

    scene = (
        path
        if isinstance(path, Scene)
        else read_scene(path, format, holdout_every=holdout_every, missing_images="keep")
    )
    return draw_cameras(scene, out, max_points=max_points)


def _shared_or_list(values: list) -> Any:
    if values and all(v == values[0] for v in values):
        return values[0]
    return values
