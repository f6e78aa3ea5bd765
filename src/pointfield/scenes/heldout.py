"""Training and held-out views of a scene, and the one evaluation every scene model gets.

Every scene model (TinyNeRF, NeRF, the hash-grid field, Gaussian splats) is trained on the
"train" split of a scene and scored on its "test" split (else "val", else every N-th training
view held out with ``holdout_every``: by default every 8th,
:mod:`pointfield.scenes.training_defaults`; ``holdout_every=0`` holds none out, and the run
reports its training PSNR only). The score is the same for every model, during training,
after it and in the benchmarks (:func:`heldout_scores`):

- PSNR: the mean over held-out views of each view's PSNR, ``10 log10(1 / MSE_view)`` with
  colours in [0, 1] (as NeRF papers and nerfstudio report it: :func:`pointfield.metrics.mean_psnr`);
- SSIM: the mean over views of :func:`pointfield.metrics.ssim` (Gaussian window 11, sigma 1.5).

A model is scored through its renderer, a callable ``render(cameras) -> [view, ...]`` with one
``{"rgb": (H, W, 3), "depth": (H, W), "median_depth": (H, W), "opacity": (H, W)}`` dict of
tensors per camera (:data:`OUTPUTS`) -- what :meth:`SceneRun.render` gives -- so nothing here
knows which model it scores.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from pointfield.metrics import SSIM_WINDOW, mean_psnr, mean_ssim
from pointfield.scenes.cameras import Cameras
from pointfield.scenes.formats import read_scene
from pointfield.scenes.scene import Scene, SceneError
from pointfield.scenes.synthetic import synthetic_scene
from pointfield.training import console
from pointfield.training.budget import WRITING_SECONDS, TimeBudget

OUTPUTS = ("rgb", "depth", "median_depth", "opacity")
"""What a scene model renders: colour ``(H, W, 3)`` in [0, 1]; expected depth ``(H, W)``, the
opacity-weighted mean distance along the ray in scene units (0 where nothing is hit); median
depth ``(H, W)``, the distance along the ray at which the accumulated opacity passes 0.5, in
scene units (0 where it never does): the surface, where the expected depth of a
semi-transparent or doubled one falls between the layers; accumulated opacity ``(H, W)`` in
[0, 1]."""

View = dict[str, torch.Tensor]
Renderer = Callable[[Cameras], list[View]]
HeldoutRender = tuple[int, dict[str, np.ndarray], np.ndarray]
"""``(frame index, {output: array} as numpy (:data:`OUTPUTS`), ground-truth image)``."""


def open_scene(
    scene: str | os.PathLike[str] | None,
    downscale: int = 1,
    holdout_every: int | None = None,
    background: str | Sequence[float] | None = None,
    cube_views: int = 100,
    cube_size: int = 100,
) -> Scene:
    """The scene to train on: read from ``scene`` (any format), or the synthetic cube when None.

    The cube is ``cube_views`` views of ``cube_size`` x ``cube_size`` pixels
    (:func:`pointfield.scenes.synthetic_scene`).
    """
    if scene is None:
        opened = synthetic_scene("cube", views=cube_views, size=cube_size)
    else:
        opened = read_scene(scene)
    if isinstance(downscale, str) or int(downscale) != downscale or downscale < 1:
        raise SceneError(f"--downscale must be a positive integer, got {downscale}")
    opened = opened.downscaled(int(downscale))
    if holdout_every == 0:  # nothing held out: training_and_heldout gives no held-out views
        opened = replace(opened, metadata={**opened.metadata, "holdout_every": 0})
    elif holdout_every is not None:
        opened = opened.with_holdout(holdout_every)
    if background is not None:
        opened = opened.with_background(background)
    return opened


SCENE_SETTINGS = ("scene", "cube_views", "cube_size", "downscale", "holdout_every", "background")
"""What a scene run's ``config.json`` records of its scene: the arguments of :func:`open_scene`."""


def scene_config(settings: dict[str, Any]) -> dict[str, Any]:
    """The :data:`SCENE_SETTINGS` of a new run's config, from the caller's settings (paths made absolute)."""
    scene = settings["scene"]
    return {
        "scene": None if scene is None else str(Path(scene).resolve()),
        "cube_views": int(settings["cube_views"]),
        "cube_size": int(settings["cube_size"]),
        # "auto" until the task knows its device (training_defaults.choose_scene_defaults).
        "downscale": "auto" if settings["downscale"] == "auto" else int(settings["downscale"]),
        "holdout_every": settings["holdout_every"],
        "background": settings["background"],
    }


def open_scene_of(config: dict[str, Any]) -> Scene:
    """The scene a run's ``config.json`` was trained on."""
    return open_scene(
        config["scene"], config["downscale"], config["holdout_every"], config["background"],
        config.get("cube_views", 100), config.get("cube_size", 100),
    )


def training_and_heldout(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Frame indices to train on and to evaluate on ("test", else "val"), both with images.

    A scene opened with ``holdout_every=0`` and no such split has no held-out views: an empty array.
    """
    where = scene.metadata.get("path", "scene")
    train_frames = scene.splits.get("train", np.arange(0))
    train_frames = np.array([i for i in train_frames if scene.frames[i].has_image], dtype=np.int64)
    if len(train_frames) == 0:
        raise SceneError(f"{where}: no training views with images")
    for name in ("test", "val"):
        held = np.array([i for i in scene.splits.get(name, []) if scene.frames[i].has_image], dtype=np.int64)
        if len(held):
            return train_frames, held
    if scene.metadata.get("holdout_every") == 0:
        return train_frames, np.arange(0, dtype=np.int64)
    raise SceneError(
        f"{where}: no held-out views with images (no test or val split); pass --holdout-every N "
        f"to hold every N-th training view out"
    )


def training_only_scores(state: Any) -> dict[str, Any]:
    """A run without held-out views (``holdout_every=0``): its last round's training PSNR, and no held-out score.

    ``state``: the finished :class:`~pointfield.training.loop.TrainingState`.
    """
    last = state.history[-1] if state.history else {}
    return {"train_psnr": last.get("train_psnr"), "views": 0}


def ray_bounds(scene: Scene) -> np.ndarray:
    """Per-frame ``(N, 2)`` near and far distances: the scene's own, else from its bounding box.

    Without ``near_far``, the bounding sphere of ``aabb`` (or of the sparse points) seen from
    each camera gives ``near = max(d - r, 0.05 d)``, ``far = d + r`` for a camera at distance d
    from its centre.
    """
    if scene.near_far is not None:
        return np.asarray(scene.near_far, dtype=np.float64)
    if scene.aabb is not None:
        box = np.asarray(scene.aabb, dtype=np.float64)
    elif scene.points is not None and len(scene.points):
        points = np.asarray(scene.points.points, dtype=np.float64)
        box = np.percentile(points, [1, 99], axis=0)
    else:
        raise SceneError(
            f"{scene.metadata.get('path', 'scene')}: no near/far bounds, bounding box or points "
            f"to tell where along the rays the scene is"
        )
    centre, radius = box.mean(axis=0), 0.5 * np.linalg.norm(box[1] - box[0])
    distance = np.linalg.norm(scene.cameras.centers.numpy() - centre, axis=1)
    return np.stack([np.maximum(distance - radius, 0.05 * distance), distance + radius], axis=1)


def depth_bounds(scene: Scene) -> tuple[float, float]:
    """The nearest ``near`` and farthest ``far`` of :func:`ray_bounds` over all the scene's cameras."""
    bounds = ray_bounds(scene)
    return float(bounds[:, 0].min()), float(bounds[:, 1].max())


def depth_range(scene: Scene, views: list[dict[str, np.ndarray]]) -> tuple[float, float]:
    """Near and far for depth pictures: :func:`depth_bounds`, else the rendered depths' 1-99 %."""
    try:
        return depth_bounds(scene)
    except SceneError:
        depths = np.concatenate([view["depth"][view["opacity"] > 0.5] for view in views]) if views else []
        if len(depths) == 0:
            return 0.0, 1.0
        near, far = np.percentile(depths, [1, 99])
        return float(near), float(max(far, near + 1e-6))


def as_numpy(view: View) -> dict[str, np.ndarray]:
    """A rendered view's tensors as float32 numpy arrays (colour and opacity clamped to [0, 1])."""
    arrays = {name: value.detach().float().cpu().numpy() for name, value in view.items()}
    for name in ("rgb", "opacity"):
        if name in arrays:
            arrays[name] = np.clip(arrays[name], 0, 1)
    return arrays


@torch.no_grad()
def heldout_scores(
    render: Renderer, scene: Scene, frames: Sequence[int], keep_renders: bool = False,
    until: float = math.inf, progress: bool = False,
) -> tuple[dict[str, float], list[HeldoutRender]]:
    """PSNR (mean of per-view PSNR), mean SSIM and opacity error of ``render`` over held-out ``frames``.

    Returns ``({"psnr", "ssim", "opacity_error", "views", "heldout_views",
    "render_seconds_per_view"}, renders)``, with ``renders`` ``[(frame, view arrays, truth)]``
    when ``keep_renders`` (else empty). SSIM needs views of at least 11 x 11 pixels; smaller ones
    give NaN. ``opacity_error`` is the mean over views of the mean absolute difference between
    the rendered opacity and the image's alpha (NaN for images without alpha): how far the
    geometry is from the object's silhouette, which colour alone does not pin down on a
    background of the object's colour.

    ``until`` (a :func:`time.perf_counter` reading): the first view is always scored, each
    further one only if the mean time of those before says it is done by then; ``views`` is how
    many were scored, ``heldout_views`` how many were asked for. ``progress``: a bar over the
    views on a terminal once the evaluation has taken a couple of seconds, and off a terminal a
    line at least every minute (:mod:`pointfield.training.console`).
    """
    images, truths, renders, opacity_errors = [], [], [], []
    started = last_line = time.perf_counter()
    bar = console.progress_bar(progress, total=len(frames), desc="held-out views", unit="view", delay=2)
    for frame in frames:
        now = time.perf_counter()
        if images and now + (now - started) / len(images) > until:
            break
        view = as_numpy(render(scene.cameras[[int(frame)]])[0])
        truth, alpha = scene.pixels(int(frame))
        if alpha is not None:
            opacity_errors.append(float(np.abs(view["opacity"] - alpha).mean()))
        images.append(view["rgb"])
        truths.append(truth)
        if keep_renders:
            renders.append((int(frame), view, truth))
        bar.update(1)
        if progress and bar.disable and time.perf_counter() - last_line >= console.STATUS_SECONDS:
            last_line = time.perf_counter()
            console.write_line(f"held-out view {len(images)}/{len(frames)} rendered ({last_line - started:.0f} s)")
    bar.close()
    seconds = time.perf_counter() - started
    window = [i for i, truth in enumerate(truths) if min(truth.shape[:2]) >= SSIM_WINDOW]
    scores = {
        "psnr": mean_psnr(images, truths),
        "ssim": mean_ssim([images[i] for i in window], [truths[i] for i in window]) if window else math.nan,
        "opacity_error": float(np.mean(opacity_errors)) if opacity_errors else math.nan,
        "views": len(images),
        "heldout_views": len(frames),
        "render_seconds_per_view": seconds / max(len(images), 1),
    }
    return scores, renders


class HeldoutEvaluation:
    """A scene task's held-out scoring: a few views after each round, all of them at the end.

    It times every view it renders, so that the final evaluation's cost is known before
    training stops (:meth:`final_seconds`, what the time budget keeps for it) and the final
    evaluation renders only the views the budget has room for (:mod:`pointfield.training.budget`).
    """

    def __init__(self, scene: Scene, heldout: Sequence[int], during: Sequence[int]):
        self.scene, self.heldout, self.during_training = scene, heldout, during
        self.seconds_per_view: float | None = None

    def during(self, render: Renderer, keep_renders: bool = False) -> tuple[dict[str, float], list[HeldoutRender]]:
        """The views scored after each round of training."""
        return self._scored(render, self.during_training, keep_renders)

    def final(
        self, render: Renderer, budget: TimeBudget, progress: bool = False
    ) -> tuple[dict[str, float], list[HeldoutRender]]:
        """Every held-out view, or as many as ``budget`` leaves time for (at least one), with their renders.

        Where even one view at full size would not fit (a view's measured cost is more than the
        time left), the views are scored at a half, a quarter ... of their size, down to
        :data:`SMALLEST_FINAL_SIDE` pixels, and ``evaluation_downscale`` in the scores says by how much.
        A run stopped before any evaluation has no measured cost: under a finite budget one view is
        first rendered at the smallest size and timed (:meth:`_probe`), so that a first full-size
        view of an untrained field (minutes on a CPU) cannot overrun ``--max-time``.
        """
        until = budget.deadline - WRITING_SECONDS
        if self.seconds_per_view is None and math.isfinite(until) and len(self.heldout):
            self.seconds_per_view = self._probe(render)
        factor = self._downscale_to_fit(until - time.perf_counter())
        scene = self.scene.downscaled(factor)
        scores, renders = self._scored(render, self.heldout, True, until=until, progress=progress, scene=scene)
        return ({**scores, "evaluation_downscale": factor} if factor > 1 else scores), renders

    def final_seconds(self) -> float | None:
        """The final evaluation's estimated seconds, from the views rendered so far (None before any)."""
        return None if self.seconds_per_view is None else self.seconds_per_view * len(self.heldout)

    def _probe(self, render: Renderer) -> float:
        """A full-size view's seconds, estimated from one held-out view rendered at the smallest
        final size and scaled by the pixels (a render's cost is in proportion to its rays; the small
        render's fixed costs make this an overestimate, which errs towards fitting the budget)."""
        side = min(int(self.scene.cameras.width.min()), int(self.scene.cameras.height.min()))
        factor = 1
        while side // (2 * factor) >= SMALLEST_FINAL_SIDE:
            factor *= 2
        camera = self.scene.cameras[[int(self.heldout[0])]]
        small = camera.scaled(factor) if factor > 1 else camera
        started = time.perf_counter()
        render(small)
        full_pixels = int(camera.width[0]) * int(camera.height[0])
        return (time.perf_counter() - started) * full_pixels / (int(small.width[0]) * int(small.height[0]))

    def _downscale_to_fit(self, seconds: float) -> int:
        """The power of two by which to shrink the views so that one renders in ``seconds`` (its cost ~ its pixels)."""
        if self.seconds_per_view is None:
            return 1
        side = min(int(self.scene.cameras.width.min()), int(self.scene.cameras.height.min()))
        factor = 1
        while self.seconds_per_view / factor**2 > seconds and side // (2 * factor) >= SMALLEST_FINAL_SIDE:
            factor *= 2
        return factor

    def _scored(self, render: Renderer, frames: Sequence[int], keep_renders: bool, scene: Scene | None = None,
                **options: Any):
        scores, renders = heldout_scores(render, scene or self.scene, frames, keep_renders, **options)
        if scene is None or scene is self.scene:  # a cost measured at full size
            self.seconds_per_view = scores["render_seconds_per_view"]
        return scores, renders


SMALLEST_FINAL_SIDE = 32
"""The smallest side, in pixels, a final evaluation shrinks its views to (to fit a time budget)."""
