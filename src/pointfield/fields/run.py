"""A trained radiance field opened for use: :class:`FieldRun`, and rendering a field into cameras.

Every pixel of a camera is a ray (:meth:`pointfield.scenes.Cameras.rays`) through its centre,
marched between its own near and far distances: where it enters and leaves the region the field
covers (:func:`field_extent`, :meth:`~pointfield.fields.rays.SceneExtent.near_far`), whatever
camera it comes from -- nearer than the training cameras, farther, or inside the box. Rendered
without gradients in chunks of :data:`RENDER_CHUNK` rays, at the samplers' bin centres (no
jitter), so renders are repeatable.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from functools import cached_property
from typing import Any

import torch
from torch import nn

from pointfield.errors import PointfieldError
from pointfield.fields.field import RadianceField, render_in_chunks
from pointfield.fields.models import MODELS, build_model
from pointfield.fields.rays import RayBundle, SceneExtent
from pointfield.fields.scene_box import scene_bounds
from pointfield.scenes.cameras import Cameras
from pointfield.scenes.heldout import OUTPUTS, View
from pointfield.scenes.run import SceneRun
from pointfield.scenes.scene import Scene
from pointfield.training.lifecycle import open_run, restore_model
from pointfield.training.run import RunDirectory
from pointfield.viz.views import PANELS

TASK = "nerf"
RENDER_CHUNK = 16384


SDF_OPTIONS_OF_OLD_RUNS = {"network_lr_fraction": 1.0, "min_weight": 0.0}
"""``sdf`` options that runs made before them behaved as (``NerfTask`` fills them in when such a run
resumes): left out of the identity, so that those runs' checkpoints, which do not name them, match."""


def identity_of(config: dict[str, Any]) -> dict[str, Any]:
    """What a NeRF run's checkpoints must match: the model and its options (less :data:`SDF_OPTIONS_OF_OLD_RUNS`)."""
    options = config.get("model_options", {})
    if config["model"] == "sdf":
        options = {key: value for key, value in options.items()
                   if key not in SDF_OPTIONS_OF_OLD_RUNS or value != SDF_OPTIONS_OF_OLD_RUNS[key]}
    return {"task": TASK, "model": config["model"], "model_options": options}


def build_field(config: dict[str, Any], device: torch.device) -> RadianceField:
    """The (untrained) model a run's config describes, on ``device``."""
    try:
        return build_model(config["model"], **config.get("model_options", {})).to(device)
    except (TypeError, ValueError) as error:
        raise PointfieldError(f"model options do not fit model {config['model']!r} ({error})") from None


def field_extent(config: dict[str, Any], scene: Scene) -> SceneExtent:
    """Where every ray of a run's field is marched, whichever camera it comes from.

    ``ngp``: its own box (``model_options``), contracted around when unbounded. ``tiny`` and
    ``nerf``, which do not contract space: the box of the run's ``--scene-box`` numbers, else
    the scene's bounded box (:func:`~pointfield.fields.scene_box.scene_bounds`: its ``aabb``,
    its sparse points' central 98 %, or the cube its cameras look into), beyond which they
    render the background.
    """
    options = config.get("model_options", {})
    if "box" in options:
        return SceneExtent(options["box"], bool(options.get("unbounded", False)))
    chosen = config.get("scene_box", "auto")
    try:
        box, _ = scene_bounds(scene, "bounded" if isinstance(chosen, str) else chosen)
    except ValueError as error:
        raise PointfieldError(str(error)) from None
    return SceneExtent(box)


@torch.no_grad()
def render_field(
    model: nn.Module, cameras: Cameras, index: int, extent: SceneExtent, background: torch.Tensor,
    chunk: int = RENDER_CHUNK,
) -> View:
    """Camera ``index`` rendered by ``model``: ``rgb`` ``(H, W, 3)``; ``depth``, ``median_depth``, ``opacity`` ``(H, W)``.

    Each pixel's ray runs between its own near and far of ``extent`` (:meth:`SceneExtent.near_far`).
    Both depths are distances along the pixel's (unit) ray from the camera centre, in scene units
    (:data:`pointfield.scenes.heldout.OUTPUTS`).
    """
    bundle = RayBundle.of_camera(cameras, index, extent).to(background.device)
    was_training = model.training
    model.eval()
    out = render_in_chunks(model, bundle, background, chunk=chunk)
    model.train(was_training)
    height, width = int(cameras.height[index]), int(cameras.width[index])
    return {
        "rgb": out["rgb"].clamp(0, 1).reshape(height, width, 3),
        "depth": out["depth"].reshape(height, width),
        "median_depth": out["median_depth"].reshape(height, width),
        "opacity": out["opacity"].reshape(height, width),
    }


class FieldRun(SceneRun):
    """A trained TinyNeRF, NeRF or hash-grid field: renders any camera of its scene's space."""

    tasks = (TASK,)

    @classmethod
    def open(cls, directory: RunDirectory, config: dict[str, Any], device: torch.device) -> FieldRun:
        if config.get("model") not in MODELS:
            raise PointfieldError(f"{directory.path}: not a NeRF run (model {config.get('model')!r})")
        model = restore_model(directory, build_field(config, device), identity_of(config), device)
        return cls(directory, config, model, device)

    @cached_property
    def extent(self) -> SceneExtent:
        """Where any camera's rays are marched, each its own near and far: :func:`field_extent`."""
        return field_extent(self.config, self.scene)

    def render_one(self, cameras: Cameras, index: int, outputs: Sequence[str] = OUTPUTS) -> View:
        # Every output comes from the same pass, at no extra cost: all are rendered.
        return render_field(self.module, cameras, index, self.extent, self.background)


def evaluate(run: str | os.PathLike[str], device: str | None = None) -> dict[str, Any]:
    """PSNR (mean of per-view PSNR) and SSIM of a trained run on its held-out views (``nerf eval``)."""
    return open_run((FieldRun,), run, device).evaluate()


def render(
    run: str | os.PathLike[str],
    *,
    path: str = "orbit",
    frames: int | None = None,
    out: str | os.PathLike[str] = "render.gif",
    device: str | None = None,
    outputs: Sequence[str] = PANELS,
    progress: bool = True,
) -> dict[str, Any]:
    """Render a trained run along ``path`` into ``out`` (``.gif``, ``.mp4`` or a folder): ``nerf render``.

    ``outputs``: which of :data:`~pointfield.scenes.heldout.OUTPUTS` to write (default colour,
    depth and opacity); depth outputs written into a folder come as depth maps too
    (:func:`pointfield.viz.views.write_views`). ``progress``: a bar over the frames.
    """
    return open_run((FieldRun,), run, device).render_path(path, frames=frames, out=out, outputs=outputs,
                                                          progress=progress)
