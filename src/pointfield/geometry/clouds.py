"""Point clouds from any trained scene model: rendered depth back-projected, with colours and normals.

Built on the one run interface (``load_run(path).render(cameras)``), so it works the same for
TinyNeRF, NeRF, the hash-grid field and splats. For each camera of a path (the training views by
default) every pixel with opacity of at least ``min_opacity`` becomes a point::

    p = o + t d          o, d: the pixel's ray (unit d); t: the rendered depth (``depth``)
    colour = the rendered colour;  normal = (dP/dx) x (dP/dy), turned to face the camera

where ``dP/dx``, ``dP/dy`` are central differences of the back-projected points between the
pixel's neighbours (pixels whose four neighbours are not all kept get no normal: NaN). ``depth``
is "expected" (the opacity-weighted mean distance along the ray, the default) or "median" (where
the accumulated opacity passes 0.5): at a silhouette or behind a thin haze the expected depth
blends the surface with what lies behind it, the median picks one (docs/geometry.md measures
both). Then the
cloud is cropped to a box (optional), stray points in empty space are dropped by a statistical
test (:func:`pointfield.clouds.ops.statistical_inliers`) and, with ``points``, thinned to that
many by farthest point sampling. The cloud is written in any format pointfield writes.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.ops import farthest_point_subset, statistical_inliers
from pointfield.errors import PointfieldError
from pointfield.scenes.cameras import Cameras

DEPTHS = ("expected", "median")
"""The rendered depth geometry is made from (module docstring)."""


def backproject(view: dict[str, torch.Tensor], cameras: Cameras, index: int, min_opacity: float = 0.5) -> PointCloud:
    """One rendered view (``rgb``, ``depth``, ``opacity``) of camera ``index`` as points (module docstring).

    Fields: ``colors`` uint8 ``(N, 3)``, ``normals`` float32 ``(N, 3)`` (NaN at silhouette edges),
    ``opacity`` float32 ``(N,)``.
    """
    rays = cameras.rays(index)
    depth = view["depth"].to(rays.origins.device, rays.origins.dtype)
    opacity = view["opacity"].to(depth.device)
    keep = (opacity >= min_opacity) & (depth > 0) & torch.isfinite(depth)
    points = rays.at(depth)  # (H, W, 3)
    normals = torch.full_like(points, float("nan"))
    # Central differences need both neighbours kept, horizontally and vertically.
    inner = keep[1:-1, 1:-1] & keep[1:-1, :-2] & keep[1:-1, 2:] & keep[:-2, 1:-1] & keep[2:, 1:-1]
    across = points[1:-1, 2:] - points[1:-1, :-2]
    down = points[2:, 1:-1] - points[:-2, 1:-1]
    normal = torch.nn.functional.normalize(torch.linalg.cross(across, down), dim=-1)
    facing_away = (normal * rays.directions[1:-1, 1:-1]).sum(-1, keepdim=True) > 0
    normal = torch.where(facing_away, -normal, normal)
    normals[1:-1, 1:-1] = torch.where(inner[..., None], normal, normals[1:-1, 1:-1])
    colours = (view["rgb"].to(depth.device).clamp(0, 1) * 255).round().to(torch.uint8)
    return PointCloud(
        points[keep].cpu().numpy(),
        {
            "colors": colours[keep].cpu().numpy(),
            "normals": normals[keep].float().cpu().numpy(),
            "opacity": opacity[keep].float().cpu().numpy(),
        },
    )


def cloud_from_views(
    views: Sequence[dict[str, torch.Tensor]], cameras: Cameras, min_opacity: float = 0.5
) -> PointCloud:
    """The back-projected points of every view, concatenated (float64 points)."""
    parts = [backproject(view, cameras, index, min_opacity) for index, view in enumerate(views)]
    points = np.concatenate([part.points for part in parts]).astype(np.float64)
    fields = {name: np.concatenate([part.fields[name] for part in parts]) for name in parts[0].fields}
    return PointCloud(points, fields)


def clean_cloud(
    cloud: PointCloud,
    *,
    crop: Sequence[float] | None = None,
    outlier_neighbours: int = 16,
    outlier_std: float = 2.0,
    points: int | None = None,
) -> PointCloud:
    """Crop to ``crop`` = (x0, y0, z0, x1, y1, z1), drop statistical outliers, thin to ``points`` (FPS).

    ``outlier_neighbours = 0`` keeps every point.
    """
    if crop is not None:
        low, high = np.asarray(crop[:3], np.float64), np.asarray(crop[3:], np.float64)
        if len(crop) != 6 or np.any(low >= high):
            raise PointfieldError(f"crop must be x0 y0 z0 x1 y1 z1 with each low below its high, got {list(crop)}")
        cloud = cloud.select(np.all((cloud.points >= low) & (cloud.points <= high), axis=1))
    if outlier_neighbours > 0 and len(cloud.points):
        cloud = cloud.select(statistical_inliers(cloud.points, outlier_neighbours, outlier_std))
    if points is not None and len(cloud.points) > points:
        cloud = cloud.select(farthest_point_subset(cloud.points, points))
    return cloud


def export_cloud(
    run: str | os.PathLike[str] | Any,
    out: str | os.PathLike[str],
    *,
    path: str = "dataset",
    frames: int | None = None,
    min_opacity: float = 0.5,
    depth: str = "expected",
    crop: Sequence[float] | None = None,
    points: int | None = None,
    outlier_neighbours: int = 16,
    outlier_std: float = 2.0,
    device: str | None = None,
    progress: bool = True,
    views: list[dict[str, torch.Tensor]] | None = None,
) -> dict[str, Any]:
    """Write the point cloud of a trained scene run (a folder, or an opened :class:`SceneRun`) to ``out``.

    ``path``: "dataset" (the run's training views), "orbit" or "spiral" (``frames`` cameras around
    the scene). ``views``: :func:`render_views` of those cameras, when the caller has them already
    (``nerf export --mesh --cloud`` renders once for both). Returns a summary: points written,
    views rendered, points before cleaning. Raises :class:`PointfieldError` for a run that is not
    a scene run, a bad path or crop, and an empty result (everything rendered transparent).
    """
    from pointfield.clouds.formats.registry import write

    scene_run = open_scene_run(run, device)
    cameras = cameras_of(scene_run, path, frames)
    views = render_views(scene_run, cameras, progress, given=views, depth=depth)
    cloud = cloud_from_views(views, cameras, min_opacity)
    rendered = len(cloud.points)
    if rendered == 0:
        raise PointfieldError(
            f"{scene_run.path}: no pixel of the {len(cameras)} views has opacity >= {min_opacity}; "
            "everything rendered transparent (lower --min-opacity, or train longer)"
        )
    cloud = clean_cloud(cloud, crop=crop, outlier_neighbours=outlier_neighbours, outlier_std=outlier_std,
                        points=points)
    if len(cloud.points) == 0:
        raise PointfieldError(f"{scene_run.path}: no point is left inside the crop box {list(crop or [])}")
    write(out, cloud)
    return {"out": str(out), "points": len(cloud.points), "views": len(cameras), "rendered_points": rendered}


def render_views(scene_run, cameras, progress: bool = True,
                 given: list[dict[str, torch.Tensor]] | None = None,
                 depth: str = "expected") -> list[dict[str, torch.Tensor]]:
    """The run's ``rgb`` (H, W, 3), ``depth`` (the ``depth`` of :data:`DEPTHS`) and ``opacity``
    (H, W) from every camera, one camera at a time: what both exports start from, and most of
    their time. ``given``: renders the caller already has, returned as they are (one per camera,
    or a ValueError)."""
    from tqdm.auto import tqdm

    if depth not in DEPTHS:
        raise PointfieldError(f"depth must be one of {', '.join(DEPTHS)}, got {depth!r}")
    if given is not None:
        if len(given) != len(cameras):
            raise ValueError(f"{len(given)} rendered views for {len(cameras)} cameras")
        return given

    rendered = "depth" if depth == "expected" else "median_depth"  # the run's output of that name
    views = []
    for index in tqdm(range(len(cameras)), desc="rendering", unit="view", disable=not progress):
        view = scene_run.render(cameras[[index]], outputs=("rgb", rendered, "opacity"))[0]
        views.append({"rgb": view["rgb"], "depth": view[rendered], "opacity": view["opacity"]})
    return views


def rendered_depth_maps(scene_run, cameras, min_opacity: float = 0.5, progress: bool = True,
                        views: list[dict[str, torch.Tensor]] | None = None,
                        depth: str = "expected") -> list[tuple[torch.Tensor, torch.Tensor]]:
    """``[(z-depth (H, W), colour (H, W, 3))]`` of every camera as the run renders it; 0 depth where
    the opacity is below ``min_opacity`` (what TSDF fusion takes). ``views``: the renders, when
    already made (:func:`render_views`)."""
    rendered = render_views(scene_run, cameras, progress, given=views, depth=depth)
    views = []
    for index, view in enumerate(rendered):
        rays = cameras.rays(index)
        z_depth = view["depth"].to(rays.axis_cosine) * rays.axis_cosine
        z_depth = torch.where(view["opacity"].to(z_depth.device) >= min_opacity, z_depth, torch.zeros_like(z_depth))
        views.append((z_depth.float(), view["rgb"]))
    return views


def cameras_of(scene_run, path: str, frames: int | None):
    """The cameras to render geometry from, on the run's device: the run's training views
    ("dataset"; ``frames`` of them, evenly spaced through the list, if given) or ``frames`` cameras
    of an orbit / spiral. Spaced, not the first ones: a capture's first views often share one side."""
    from pointfield.scenes.heldout import training_and_heldout
    from pointfield.scenes.paths import PATHS, path_cameras

    if path not in PATHS:
        raise PointfieldError(f"path must be one of {', '.join(PATHS)}, got {path!r}")
    scene = scene_run.scene
    if path == "dataset":
        training, _ = training_and_heldout(scene)
        if frames and frames < len(training):
            training = training[np.linspace(0, len(training) - 1, frames).round().astype(int)]
        cameras = scene.cameras[training]
    else:
        cameras = path_cameras(scene, path, frames)
    return cameras.to(scene_run.device)


def open_scene_run(run, device):
    """An opened scene run: ``run`` itself, or the run in folder ``run``; else a clear error."""
    from pointfield.scenes.run import SceneRun

    if isinstance(run, SceneRun):
        return run
    import pointfield

    opened = pointfield.load_run(run, device)
    if not isinstance(opened, SceneRun):
        raise PointfieldError(
            f"{run}: a {opened.model_name} run, not a scene run (tiny, nerf, ngp or splat); "
            "geometry comes from scene models"
        )
    return opened
