"""Training and evaluating NeRF models on a scene: the functions behind ``pointfield nerf``.

========================================  ===============================
``pointfield nerf train [SCENE] ...``      :func:`train`
``pointfield nerf eval RUN``               :func:`evaluate`
``pointfield nerf render RUN ...``         :func:`pointfield.fields.views.render`
========================================  ===============================

Example::

    from pointfield.fields.train import train, evaluate
    metrics = train(model="tiny", out="runs/cube", steps=2000)   # the built-in synthetic cube
    print(metrics["psnr"], metrics["ssim"])

The recipe: every pixel of the training views is a ray (``Cameras.rays``) with its colour;
each step renders ``batch_rays`` of them, drawn without replacement until all have been used
(one *epoch*, a pass over all training rays, then reshuffled), and minimises the mean squared
colour error of every render pass (NeRF: coarse and fine) with Adam, learning rate decayed
exponentially to a tenth over the run. Samples are jittered while training and at bin centres
when evaluating. The loop itself -- checkpoints, resuming, time limit, progress, NaN checks --
is :func:`pointfield.training.fit`, whose "epochs" are here rounds of ``eval_every`` steps
ending with an evaluation on held-out views.

Run folder (see :class:`pointfield.training.RunDirectory`): ``config.json``, ``metrics.jsonl``
(per round: ``step``, ``seconds``, ``loss`` = ``train_loss`` (the mean training loss),
``train_psnr`` (mean of the steps' PSNR), held-out ``psnr``, ``epochs`` = passes over the
training rays, ``lr``), ``metrics.json`` (``psnr`` and ``ssim`` averaged
over all held-out views, ``steps``, ``seconds``, ...), ``checkpoints/last.pt``,
``training_curves.png`` and ``heldout/NNN.png`` (ground truth | render | depth | opacity).
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from pointfield.errors import PointfieldError
from pointfield.scenes import Scene, SceneError, read_scene, synthetic_scene

TASK = "nerf"
CURVES_PNG = "training_curves.png"
HELDOUT_DIR = "heldout"
DEFAULT_STEPS = {"tiny": 2000, "nerf": 5000, "ngp": 3000}
LEARNING_RATES = {"tiny": 5e-4, "nerf": 5e-4, "ngp": 1e-2}
"""Adam's default learning rate per model (the hash grid's, as in Instant-NGP, is much larger)."""
FINAL_LEARNING_RATE_FRACTION = 0.1
RENDER_CHUNK = 16384


HeldoutRender = tuple[int, dict[str, np.ndarray], np.ndarray]
"""``(frame index, render {"color", "depth", "opacity"}, ground-truth image)``."""


@dataclass
class RaySet:
    """Every pixel of some views as a ray with its colour, flattened: R rays.

    ``origins``, ``directions`` ``(R, 3)`` float32 (unit directions), ``colors`` ``(R, 3)`` in
    [0, 1], ``near``, ``far`` ``(R,)`` distances along the ray.
    """

    origins: torch.Tensor
    directions: torch.Tensor
    colors: torch.Tensor
    near: torch.Tensor
    far: torch.Tensor

    def __len__(self) -> int:
        return self.origins.shape[0]


# -- scenes --------------------------------------------------------------------------------------


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
    if int(downscale) != downscale or downscale < 1:
        raise SceneError(f"--downscale must be a positive integer, got {downscale}")
    opened = opened.downscaled(int(downscale))
    if holdout_every is not None:
        opened = opened.with_holdout(holdout_every)
    if background is not None:
        opened = opened.with_background(background)
    return opened


def open_scene_of(config: dict[str, Any]) -> Scene:
    """The scene a run's ``config.json`` was trained on."""
    return open_scene(
        config["scene"], config["downscale"], config["holdout_every"], config["background"],
        config.get("cube_views", 100), config.get("cube_size", 100),
    )


def training_and_heldout(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Frame indices to train on and to evaluate on ("test", else "val"), both with images."""
    where = scene.metadata.get("path", "scene")
    train_frames = scene.splits.get("train", np.arange(0))
    train_frames = np.array([i for i in train_frames if scene.frames[i].has_image], dtype=np.int64)
    if len(train_frames) == 0:
        raise SceneError(f"{where}: no training views with images")
    for name in ("test", "val"):
        held = np.array([i for i in scene.splits.get(name, []) if scene.frames[i].has_image], dtype=np.int64)
        if len(held):
            return train_frames, held
    raise SceneError(
        f"{where}: no held-out views with images (no test or val split); pass --holdout-every N "
        f"to hold every N-th training view out"
    )


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


def scene_rays(scene: Scene, frames, device: torch.device, with_colors: bool = True) -> RaySet:
    """All pixels of ``frames`` as one :class:`RaySet` on ``device`` (colours from the images)."""
    bounds = ray_bounds(scene)
    parts: dict[str, list[torch.Tensor]] = {k: [] for k in ("origins", "directions", "colors", "near", "far")}
    for index in frames:
        rays = scene.cameras.rays(int(index)).reshape(-1)
        count = rays.shape[0]
        parts["origins"].append(rays.origins.float())
        parts["directions"].append(rays.directions.float())
        if with_colors:
            parts["colors"].append(torch.from_numpy(scene.image(int(index)).reshape(-1, 3)))
        else:
            parts["colors"].append(torch.zeros(count, 3))
        parts["near"].append(torch.full((count,), float(bounds[index, 0])))
        parts["far"].append(torch.full((count,), float(bounds[index, 1])))
    return RaySet(**{name: torch.cat(values).to(device) for name, values in parts.items()})


# -- rendering views ----------------------------------------------------------------------------


@torch.no_grad()
def render_view(
    model: nn.Module, rays: RaySet, height: int, width: int, background: torch.Tensor
) -> dict[str, np.ndarray]:
    """Render one view's rays: ``color`` ``(H, W, 3)``, ``depth`` and ``opacity`` ``(H, W)`` numpy."""
    from pointfield.fields.nerf import render_in_chunks

    model.eval()
    out = render_in_chunks(
        model, rays.origins, rays.directions, rays.near, rays.far, background, chunk=RENDER_CHUNK
    )
    return {
        "color": out["color"].clamp(0, 1).reshape(height, width, 3).cpu().numpy(),
        "depth": out["depth"].reshape(height, width).cpu().numpy(),
        "opacity": out["opacity"].reshape(height, width).cpu().numpy(),
    }


def depth_image(depth: np.ndarray, opacity: np.ndarray, near: float, far: float) -> np.ndarray:
    """Depth as ``(H, W, 3)`` uint8 grey: near white, far dark, empty pixels black."""
    scaled = 1 - np.clip((depth - near) / max(far - near, 1e-9), 0, 1)
    return np.repeat((np.clip(scaled * opacity, 0, 1) * 255).round().astype(np.uint8)[..., None], 3, axis=2)


def to_uint8(image: np.ndarray) -> np.ndarray:
    """``(H, W)`` or ``(H, W, 3)`` floats in [0, 1] -> ``(H, W, 3)`` uint8."""
    image = (np.clip(image, 0, 1) * 255).round().astype(np.uint8)
    return np.repeat(image[..., None], 3, axis=2) if image.ndim == 2 else image


def view_panel(
    rendered: dict[str, np.ndarray], near: float, far: float, truth: np.ndarray | None = None
) -> np.ndarray:
    """[ground truth |] colour | depth | opacity side by side, ``(H, k W, 3)`` uint8."""
    panels = [] if truth is None else [to_uint8(truth)]
    panels += [
        to_uint8(rendered["color"]),
        depth_image(rendered["depth"], rendered["opacity"], near, far),
        to_uint8(rendered["opacity"]),
    ]
    return np.concatenate(panels, axis=1)


def heldout_scores(
    model: nn.Module,
    scene: Scene,
    frames,
    device: torch.device,
    background: torch.Tensor,
    keep_renders: bool = False,
) -> tuple[dict[str, float], list[HeldoutRender]]:
    """Mean PSNR and SSIM over held-out ``frames``; with ``keep_renders`` also each render.

    Returns ``({"psnr", "ssim", "views", "render_seconds_per_view"}, [(frame, render, truth)])``.
    """
    from pointfield.image_metrics import psnr, ssim

    scores_psnr, scores_ssim, renders = [], [], []
    started = time.perf_counter()
    for index in frames:
        rays = scene_rays(scene, [index], device)
        height, width = int(scene.cameras.height[index]), int(scene.cameras.width[index])
        rendered = render_view(model, rays, height, width, background)
        truth = rays.colors.reshape(height, width, 3).cpu().numpy()
        scores_psnr.append(psnr(rendered["color"], truth))
        if min(height, width) >= 11:
            scores_ssim.append(ssim(rendered["color"], truth))
        if keep_renders:
            renders.append((int(index), rendered, truth))
    seconds = time.perf_counter() - started
    scores = {
        "psnr": float(np.mean(scores_psnr)),
        "ssim": float(np.mean(scores_ssim)) if scores_ssim else math.nan,
        "views": len(frames),
        "render_seconds_per_view": seconds / max(len(frames), 1),
    }
    return scores, renders


# -- training -------------------------------------------------------------------------------------


def train(
    scene: str | os.PathLike[str] | None = None,
    *,
    model: str = "tiny",
    out: str | os.PathLike[str] = "runs/nerf",
    steps: int | None = None,
    max_time: float | None = None,
    batch_rays: int = 1024,
    downscale: int = 1,
    holdout_every: int | None = None,
    background: str | Sequence[float] | None = None,
    device: str | None = None,
    seed: int = 0,
    resume: bool = False,
    eval_every: int | None = None,
    eval_views: int = 1,
    learning_rate: float | None = None,
    model_options: dict[str, Any] | None = None,
    scene_box: str | Sequence[float] = "auto",
    progress: bool = True,
    cube_views: int = 100,
    cube_size: int = 100,
    on_evaluate: Callable[[dict[str, float], list[HeldoutRender]], None] | None = None,
) -> dict[str, Any]:
    """Train a NeRF model on ``scene`` into run folder ``out``; returns the final metrics.

    ``steps`` defaults to 2000 (tiny) or 5000 (nerf); ``max_time`` stops earlier (seconds of
    training, summed over resumed sessions). ``eval_every`` steps (default: one epoch, at most
    500 steps) the first ``eval_views`` held-out views are rendered and scored. Without
    ``scene``, the synthetic cube of ``cube_views`` views of ``cube_size`` pixels square is
    rendered and trained on. ``background`` ("white", "black" or an RGB triple) replaces the
    scene's: images' alpha is composited onto it and so is every render. ``model_options`` go to the model's
    constructor (``samples`` for tiny, ``coarse_samples``/``fine_samples`` for nerf).
    ``scene_box`` (ngp only; see :func:`pointfield.fields.ngp.scene_bounds`): "auto", "bounded",
    "unbounded" or six numbers. ``learning_rate`` defaults to :data:`LEARNING_RATES` of the model.
    ``on_evaluate(record, renders)`` is called after each evaluation with the round's
    ``{"step", "epochs", "psnr"}`` and the held-out renders
    ``[(frame, render, truth)]`` (the exercise draws its strip with it).
    """
    from pointfield.devices import pick_device
    from pointfield.fields.nerf import MODELS, build_model
    from pointfield.training import RunDirectory, fit

    if model not in MODELS:
        raise PointfieldError(f"unknown NeRF model {model!r}; choose one of {', '.join(MODELS)}")
    run = RunDirectory(out)
    config = {
        "task": TASK,
        "model": model,
        "model_options": dict(model_options or {}),
        "scene": None if scene is None else str(Path(scene).resolve()),
        "cube_views": int(cube_views),
        "cube_size": int(cube_size),
        "downscale": int(downscale),
        "holdout_every": holdout_every,
        "background": background,
        "batch_rays": int(batch_rays),
        "steps": int(steps if steps is not None else DEFAULT_STEPS[model]),
        "learning_rate": float(learning_rate if learning_rate is not None else LEARNING_RATES[model]),
        "seed": int(seed),
        "eval_every": eval_every,
        "eval_views": int(eval_views),
    }
    if resume and run.exists():
        saved = run.read_config()
        if saved.get("task") != TASK:
            raise PointfieldError(f"{run.path} is a {saved.get('task')!r} run, not a NeRF run")
        # The run's own settings win; only the length of training may be extended.
        config = {**saved, "steps": config["steps"] if steps is not None else saved["steps"]}
    if config["batch_rays"] < 1 or config["steps"] < 1 or (config["eval_every"] or 1) < 1:
        raise PointfieldError("--batch-rays, --steps and --eval-every must be positive")
    scene_data = open_scene_of(config)
    train_frames, heldout_frames = training_and_heldout(scene_data)
    if config["model"] == "ngp" and "box" not in config["model_options"]:
        from pointfield.fields.ngp import default_max_resolution, scene_bounds

        try:
            box, unbounded = scene_bounds(scene_data, scene_box)
        except ValueError as error:
            raise PointfieldError(str(error)) from None
        chosen = {"box": box, "unbounded": unbounded,
                  "max_resolution": default_max_resolution(scene_data, unbounded)}
        config["model_options"] = {**chosen, **config["model_options"]}
    torch_device = pick_device(device)
    torch.manual_seed(config["seed"])
    try:
        network = build_model(config["model"], **config["model_options"]).to(torch_device)
    except TypeError as error:
        raise PointfieldError(f"model options do not fit model {config['model']!r} ({error})") from None
    run.create(resume)  # only now: a bad scene or option leaves an existing folder untouched
    run.write_config(config)

    rays = scene_rays(scene_data, train_frames, torch_device)
    background_color = torch.as_tensor(scene_data.background, device=torch_device)
    batch = config["batch_rays"]
    steps_per_epoch = math.ceil(len(rays) / batch)
    round_steps = config["eval_every"] or min(steps_per_epoch, 500)
    rounds = math.ceil(config["steps"] / round_steps)
    if config["model"] == "ngp":
        # Instant-NGP's Adam: beta2 0.99 and a tiny epsilon, so rarely-touched hash entries
        # still move at the full learning rate.
        # fused: one kernel over the whole table instead of a dozen passes (6x faster on a CPU).
        optimizer = torch.optim.Adam(network.parameters(), lr=config["learning_rate"], betas=(0.9, 0.99), eps=1e-15,
                                     fused=torch_device.type in ("cpu", "cuda"))
    else:
        optimizer = torch.optim.Adam(network.parameters(), lr=config["learning_rate"])
    # Exponential decay to FINAL_LEARNING_RATE_FRACTION over the run, stepped once per round.
    scheduler = torch.optim.lr_scheduler.ExponentialLR(
        optimizer, FINAL_LEARNING_RATE_FRACTION ** (1 / rounds)
    )
    evaluated = heldout_frames[: max(1, config["eval_views"])]

    adaptive = hasattr(network, "rays_for_next_step")

    def batches(round_index: int) -> list[torch.Tensor | int]:
        first = round_index * round_steps
        last = min(first + round_steps, config["steps"])
        # Models that size their own batches (ngp) get the step number and draw rays in step().
        return list(range(first, last)) if adaptive else [epoch_batch(s) for s in range(first, last)]

    permutations: dict[int, torch.Tensor] = {}

    def epoch_batch(step: int) -> torch.Tensor:
        """Step ``step``'s ray indices: epoch e = step // steps_per_epoch walks a seeded permutation."""
        epoch, position = divmod(step, steps_per_epoch)
        if epoch not in permutations:
            permutations.clear()
            generator = torch.Generator().manual_seed(config["seed"] * 1_000_003 + epoch)
            permutations[epoch] = torch.randperm(len(rays), generator=generator).to(torch_device)
        return permutations[epoch][position * batch : (position + 1) * batch]

    def step(batch: torch.Tensor | int) -> tuple[torch.Tensor, dict[str, float]]:
        indices = batch
        if adaptive:
            # Random rays with replacement, as many as keep the step near its sample budget;
            # seeded by the step so a resumed run draws what it would have drawn.
            generator = torch.Generator().manual_seed(config["seed"] * 1_000_003 + int(batch))
            network.before_step(int(batch), generator)
            indices = torch.randint(len(rays), (network.rays_for_next_step(),), generator=generator).to(torch_device)
        passes = network(
            rays.origins[indices], rays.directions[indices], rays.near[indices], rays.far[indices],
            background_color, jitter=True,
        )
        target = rays.colors[indices]
        losses = [torch.mean((rendered.color - target) ** 2) for rendered in passes]
        from pointfield.image_metrics import psnr_from_mse

        extras = {"psnr": psnr_from_mse(float(losses[-1].detach()))}
        auxiliary = network.auxiliary_loss() if adaptive else None
        if auxiliary is not None:
            extras["auxiliary_loss"] = float(auxiliary.detach())
            losses.append(auxiliary)
        if adaptive:
            extras["rays"] = float(len(indices))
            extras["samples_per_ray"] = network.last_samples / max(len(indices), 1)
        return sum(losses), extras

    def evaluate(round_index: int) -> dict[str, float]:
        keep = on_evaluate is not None
        scores, renders = heldout_scores(network, scene_data, evaluated, torch_device, background_color, keep)
        network.train()
        finished = min((round_index + 1) * round_steps, config["steps"])
        record = {"psnr": scores["psnr"], "epochs": finished / steps_per_epoch}
        if keep:
            on_evaluate({**record, "step": finished}, renders)
        return record

    def redraw(history: list[dict[str, Any]]) -> None:
        from pointfield.viz.plots import plot_training_curves

        plotted = ("step", "train_loss", "train_psnr", "psnr")
        records = [{k: v for k, v in record.items() if k in plotted} for record in history]
        plot_training_curves(records, run.path / CURVES_PNG, title=f"{config['model']} NeRF", x="step")

    if hasattr(network, "warm_up"):
        network.warm_up()  # one-time kernel compilation, before the training clock starts
    identity = {"task": TASK, "model": config["model"], "model_options": config["model_options"]}
    state = fit(
        network, optimizer, step, batches, rounds, run=run, identity=identity, scheduler=scheduler,
        evaluate=evaluate, on_epoch_end=redraw, loss_aliases=("loss",), resume=resume,
        max_seconds=max_time, device=torch_device, progress=progress,
    )
    return _finish_run(
        run, network, scene_data, heldout_frames, torch_device, background_color, state, len(rays),
        steps_per_epoch,
    )


def _finish_run(
    run,
    network: nn.Module,
    scene: Scene,
    heldout_frames: np.ndarray,
    device: torch.device,
    background: torch.Tensor,
    state,
    ray_count: int,
    steps_per_epoch: int,
) -> dict[str, Any]:
    """Score every held-out view, save their renders beside the ground truth, write metrics.json."""
    from pointfield.viz.render import save_image

    scores, renders = heldout_scores(network, scene, heldout_frames, device, background, keep_renders=True)
    bounds = ray_bounds(scene)
    folder = run.path / HELDOUT_DIR
    folder.mkdir(exist_ok=True)
    for index, rendered, truth in renders:
        save_image(folder / f"{index:03d}.png", view_panel(rendered, *bounds[index], truth=truth))
    metrics = {
        **scores,
        "steps": state.step,
        "epochs": state.step / steps_per_epoch,
        "seconds": round(state.seconds, 3),
        "training_rays": ray_count,
    }
    run.write_final_metrics(metrics)
    return metrics


# -- using a trained run -----------------------------------------------------------------------------


def load_run(
    run: str | os.PathLike[str], device: str | None = None
) -> tuple[Any, dict[str, Any], nn.Module, torch.device]:
    """A trained run's folder, config, model (weights loaded, eval mode) and device."""
    from pointfield.devices import pick_device
    from pointfield.fields.nerf import MODELS, build_model
    from pointfield.training import RunDirectory, load_checkpoint, restore

    folder = RunDirectory(run)
    config = folder.read_config()
    if config.get("task") != TASK or config.get("model") not in MODELS:
        raise PointfieldError(
            f"{folder.path}: not a NeRF run (task {config.get('task')!r}, model {config.get('model')!r})"
        )
    torch_device = pick_device(device)
    try:
        network = build_model(config["model"], **config.get("model_options", {})).to(torch_device)
    except (TypeError, ValueError) as error:
        raise PointfieldError(
            f"{folder.config}: model options do not fit model {config['model']!r} ({error})"
        ) from None
    identity = {"task": TASK, "model": config["model"], "model_options": config.get("model_options", {})}
    payload = load_checkpoint(folder.checkpoint, identity, map_location=torch_device)
    restore(folder.checkpoint, payload, network)
    network.eval()
    return folder, config, network, torch_device


def evaluate(run: str | os.PathLike[str], device: str | None = None) -> dict[str, Any]:
    """PSNR and SSIM of a trained run on its scene's held-out views (``pointfield nerf eval``)."""
    folder, config, network, torch_device = load_run(run, device)
    scene = open_scene_of(config)
    _, heldout = training_and_heldout(scene)
    background = torch.as_tensor(scene.background, device=torch_device)
    scores, _ = heldout_scores(network, scene, heldout, torch_device, background)
    return {"run": str(folder.path), "model": config["model"], **scores}
