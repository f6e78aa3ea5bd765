"""Training NeRF models on a scene: ``pointfield nerf train`` (:func:`train`).

``nerf eval`` and ``nerf render`` are :func:`pointfield.fields.run.evaluate` and
:func:`pointfield.fields.run.render`, over the run that :func:`pointfield.load_run` opens.

Example::

    from pointfield.fields.train import train
    metrics = train(model="tiny", out="runs/cube", steps=2000)   # the built-in synthetic cube
    print(metrics["psnr"], metrics["ssim"])

The recipe: every pixel of the training views is a ray (``Cameras.rays``) with its colour;
each step renders ``batch_rays`` of them, drawn without replacement until all have been used
(one *epoch*, a pass over all training rays, then reshuffled), and minimises the mean squared
colour error of every render pass (NeRF: coarse and fine), plus on the fast field of an object
the distortion loss (:data:`BOUNDED_NGP_DISTORTION`), with Adam, learning rate decayed
exponentially to a tenth over the run. The hash-grid field (``ngp``) sizes its own batches
instead: as many random rays as keep a step near its ``target_samples``
(:class:`~pointfield.fields.field.RayBudget`). Each training ray passes through a random point
of its pixel and its samples are jittered along it (:mod:`pointfield.fields.training_rays`);
renders go through pixel centres, at bin centres. Every ray, training or rendering, is marched
between its own near and far: where it meets the region the field covers
(:func:`~pointfield.fields.run.field_extent`), not the training cameras' depth bounds.
:class:`NerfTask` is this recipe as the one training lifecycle (:mod:`pointfield.training`) runs
it: checkpoints, resuming, time limit, progress and NaN checks come from there, and its
"epochs" are rounds of ``eval_every`` steps ending with an evaluation on held-out views
(mean of per-view PSNR, :mod:`pointfield.scenes.heldout`).

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
from collections.abc import Callable, Sequence
from typing import Any

import torch

from pointfield.errors import PointfieldError
from pointfield.fields.field import RayBudget
from pointfield.fields.ngp import CUDA_OPTIONS
from pointfield.fields.rays import RayBundle, SceneExtent
from pointfield.fields.rendering import distortion_loss
from pointfield.fields.run import (
    TASK,
    build_field,
    field_extent,
    identity_of,
    render_field,
)
from pointfield.fields.scene_box import (
    default_max_resolution,
    scene_bounds,
    steps_a_pixel_allows,
)
from pointfield.fields.sdf import MIN_WEIGHT, NETWORK_LR_FRACTION
from pointfield.fields.training_rays import TrainingRays
from pointfield.metrics import psnr_from_mse
from pointfield.scenes.heldout import (
    HeldoutEvaluation,
    HeldoutRender,
    depth_bounds,
    depth_range,
    open_scene_of,
    scene_config,
    training_and_heldout,
    training_only_scores,
)
from pointfield.scenes.scene import Scene, SceneError
from pointfield.scenes.training_defaults import choose_scene_defaults
from pointfield.training import lifecycle
from pointfield.training.loop import TrainingState
from pointfield.training.opacity import (
    BACKGROUND_MEAN,
    alpha_loss_weight,
    random_background_loss,
    recomposite,
    uses_random_background,
)
from pointfield.training.run import RunDirectory
from pointfield.training.task import Step, Task
from pointfield.viz.plots import plot_training_curves
from pointfield.viz.views import save_panels

CURVES_PNG = "training_curves.png"
HELDOUT_DIR = "heldout"
DEFAULT_STEPS = {"tiny": 2000, "nerf": 5000, "ngp": 3000, "sdf": 3000}
LEARNING_RATES = {"tiny": 5e-4, "nerf": 5e-4, "ngp": 1e-2, "sdf": 1e-2}
"""Adam's default learning rate per model (the hash grids', as in Instant-NGP and instant-NSR, are much larger)."""
HASH_GRID_MODELS = ("ngp", "sdf")
"""The models on a hash grid in a box: their options come from the scene and device (:func:`default_ngp_options`)."""
FINAL_LEARNING_RATE_FRACTION = 0.1
BOUNDED_NGP_DISTORTION = 0.01
"""The distortion loss's default weight for the fast field on a bounded scene (an object on a
transparent background); 0 elsewhere (:func:`~pointfield.fields.rendering.distortion_loss`).

It is what puts the field's surfaces where they are: without it, the textured cube's faces sit
1-3 % of the diagonal too deep, behind a soft shell of density (``make bench-geometry``,
benchmarks/RESULTS.md). Unbounded captures keep it off until it is measured on them.
"""


def default_ngp_options(scene: Scene, scene_box, device: torch.device) -> dict[str, Any]:
    """The ``ngp`` options a new run takes from its scene and device, under the user's own.

    The box and whether it is unbounded (``scene_box``, :func:`scene_bounds`), the finest
    hash-grid level (:func:`default_max_resolution`), and on CUDA the paper's hash grid
    (:data:`~pointfield.fields.ngp.CUDA_OPTIONS`), its 1,024 marching steps no finer than a
    quarter of a pixel (:func:`steps_a_pixel_allows`). They are written into the run's config,
    so a run resumed on another device keeps the grid it was trained with.
    """
    try:
        box, unbounded = scene_bounds(scene, scene_box)
    except ValueError as error:
        raise PointfieldError(str(error)) from None
    chosen = {"box": box, "unbounded": unbounded, "max_resolution": default_max_resolution(scene, unbounded)}
    if device.type == "cuda":
        chosen.update(CUDA_OPTIONS)
        chosen["steps_across_box"] = min(CUDA_OPTIONS["steps_across_box"], steps_a_pixel_allows(scene, box))
    return chosen


def scene_rays(scene: Scene, frames: Sequence[int], extent: SceneExtent,
               device: torch.device) -> tuple[RayBundle, torch.Tensor]:
    """Every pixel centre of ``frames`` as one :class:`RayBundle` bounded by ``extent``, and the ``(R, 3)`` colours."""
    bundle = RayBundle.cat([RayBundle.of_camera(scene.cameras, int(i), extent) for i in frames])
    colors = torch.cat([torch.from_numpy(scene.image(int(i)).reshape(-1, 3)) for i in frames])
    return bundle.to(device), colors.to(device)


def distortion_scale(scene: Scene, extent: SceneExtent) -> float:
    """The length the distortion loss measures distances in: the scene's depth range
    (:func:`~pointfield.scenes.heldout.depth_bounds`, what :data:`BOUNDED_NGP_DISTORTION` was
    measured with), else, for a scene without bounds, its box's diagonal."""
    try:
        near, far = depth_bounds(scene)
    except SceneError:
        return extent.diagonal
    return far - near


class NerfTask(Task):
    """The NeRF recipe of the module doc, as the training lifecycle runs it.

    A batch is a step number: the step's rays are drawn from it (a seeded permutation per pass
    over the training rays, or, for models with a sample budget, random rays seeded by the
    step), so a resumed run draws what it would have drawn.
    """

    name = TASK
    extendable = ("steps",)
    loss_aliases = ("loss",)

    @classmethod
    def configure(cls, settings: dict[str, Any]) -> dict[str, Any]:
        model = settings["model"]
        if model not in DEFAULT_STEPS:
            raise PointfieldError(f"unknown NeRF model {model!r}; choose one of {', '.join(DEFAULT_STEPS)}")
        config = {
            "task": TASK,
            "model": model,
            "model_options": dict(settings["model_options"] or {}),
            **scene_config(settings),
            "scene_box": settings["scene_box"],
            "batch_rays": int(settings["batch_rays"]),
            "steps": int(settings["steps"] if settings["steps"] is not None else DEFAULT_STEPS[model]),
            "learning_rate": float(settings["learning_rate"] if settings["learning_rate"] is not None
                                   else LEARNING_RATES[model]),
            "seed": int(settings["seed"]),
            "eval_every": settings["eval_every"],
            "eval_views": int(settings["eval_views"]),
            "random_background": settings.get("random_background"),
            "alpha_loss": settings.get("alpha_loss"),
            "distortion": None if settings.get("distortion") is None else float(settings["distortion"]),
        }
        if config["batch_rays"] < 1 or config["steps"] < 1 or (config["eval_every"] or 1) < 1:
            raise PointfieldError("--batch-rays, --steps and --eval-every must be positive")
        if config["distortion"] is not None and not config["distortion"] >= 0:
            raise PointfieldError(f"--distortion must be 0 or more, got {config['distortion']}")
        return config

    def __init__(self, config, device, distributed, progress, *,
                 on_evaluate: Callable[[dict[str, float], list[HeldoutRender]], None] | None = None):
        super().__init__(config, device, distributed, progress)
        self.on_evaluate = on_evaluate
        choose_scene_defaults(config, device, say=distributed is None or distributed.is_main)
        self.scene = open_scene_of(config)
        self.train_frames, self.heldout_frames = training_and_heldout(self.scene)
        new_run = "box" not in config["model_options"]  # a resume has its box
        if config["model"] == "sdf" and "network_lr_fraction" not in config["model_options"]:
            # A run trained before the MLPs had their own rate resumes with its one rate (its optimizer's state).
            config["model_options"]["network_lr_fraction"] = NETWORK_LR_FRACTION if new_run else 1.0
        if config["model"] == "sdf" and "min_weight" not in config["model_options"]:
            # A run trained before faint sections were skipped resumes marching every one.
            config["model_options"]["min_weight"] = MIN_WEIGHT if new_run else 0.0
        if config["model"] in HASH_GRID_MODELS and new_run:
            scene_box = config.get("scene_box", "auto")
            if config["model"] == "sdf" and scene_box == "auto":
                scene_box = "bounded"  # a signed distance has no contracted form: the object's box
            chosen = default_ngp_options(self.scene, scene_box, device)
            config["model_options"] = {**chosen, **config["model_options"]}
        if "distortion" in config and config["distortion"] is None:
            bounded = config["model"] == "ngp" and not config["model_options"].get("unbounded", False)
            config["distortion"] = BOUNDED_NGP_DISTORTION if bounded else 0.0
        self.model = self.trained = build_field(config, device)
        self.extent = field_extent(config, self.scene)
        self.rays = TrainingRays(self.scene, self.train_frames, self.extent, device)
        self.colors = self.rays.colors
        self.background = torch.as_tensor(self.scene.background, dtype=torch.float32, device=device)
        # Opacity trained towards the images' alpha where they have it (training/opacity.py).
        self.alpha_loss = alpha_loss_weight(config.get("alpha_loss"), self.scene, self.train_frames, default=0.0)
        self.random_background = uses_random_background(config.get("random_background"), self.scene,
                                                        self.train_frames)
        # 1 - alpha of every training ray; both are off (0 / False) where the images have no alpha.
        self.transparency = self.rays.transparency if self.alpha_loss or self.random_background else None
        # The background training renders over, and the targets moved onto it: random backgrounds
        # in expectation render over their mean colour, grey (training/opacity.py).
        self.training_background = self.background
        if self.random_background:
            self.training_background = torch.full((3,), BACKGROUND_MEAN, device=device)
            self.colors = recomposite(self.colors, self.transparency, self.background, self.training_background)
        self.depth_scale = distortion_scale(self.scene, self.extent)
        # A run made before the distortion loss existed was trained without it, and resumes so.
        self.distortion = float(config.get("distortion", 0.0))
        self.steps_per_epoch = math.ceil(len(self.rays) / config["batch_rays"])
        self.round_steps = config["eval_every"] or min(self.steps_per_epoch, 500)
        self.epochs = math.ceil(config["steps"] / self.round_steps)
        if config["model"] in HASH_GRID_MODELS:
            # Instant-NGP's Adam: beta2 0.99 and a tiny epsilon, so rarely-touched hash entries
            # still move at the full learning rate.
            # fused: one kernel over the whole table instead of a dozen passes (6x faster on a CPU).
            groups = getattr(self.model, "parameter_groups", None)
            parameters = groups(config["learning_rate"]) if groups is not None else self.model.parameters()
            self.optimizer = torch.optim.Adam(parameters, lr=config["learning_rate"], betas=(0.9, 0.99),
                                              eps=1e-15, fused=device.type in ("cpu", "cuda"))
        else:
            self.optimizer = torch.optim.Adam(self.model.parameters(), lr=config["learning_rate"])
        # Exponential decay to FINAL_LEARNING_RATE_FRACTION over the run, stepped once per round.
        self.scheduler = torch.optim.lr_scheduler.ExponentialLR(
            self.optimizer, FINAL_LEARNING_RATE_FRACTION ** (1 / self.epochs)
        )
        self.identity = identity_of(config)
        self.budget = None if self.model.target_samples is None else RayBudget(self.model.target_samples)
        self.evaluated = self.heldout_frames[: max(1, config["eval_views"])]
        self.heldout = HeldoutEvaluation(self.scene, self.heldout_frames, self.evaluated)
        self._permutations: dict[int, torch.Tensor] = {}

    def warm_up(self) -> None:
        self.model.warm_up()  # one-time kernel compilation, before the training clock starts

    def render(self, cameras) -> list[dict[str, torch.Tensor]]:
        return [render_field(self.model, cameras, index, self.extent, self.background)
                for index in range(len(cameras))]

    def batches(self, epoch: int) -> range:
        first = epoch * self.round_steps
        return range(first, min(first + self.round_steps, self.config["steps"]))

    def _rays_of_step(self, step: int, generator: torch.Generator) -> torch.Tensor:
        if self.budget is not None:
            # Random rays with replacement, as many as keep the step near its sample budget.
            return torch.randint(len(self.rays), (self.budget.rays(),), generator=generator).to(self.device)
        # Pass e = step // steps_per_epoch walks a seeded permutation of all training rays.
        epoch, position = divmod(step, self.steps_per_epoch)
        if epoch not in self._permutations:
            self._permutations.clear()
            permutation = torch.Generator().manual_seed(self.config["seed"] * 1_000_003 + epoch)
            self._permutations[epoch] = torch.randperm(len(self.rays), generator=permutation).to(self.device)
        batch = self.config["batch_rays"]
        return self._permutations[epoch][position * batch : (position + 1) * batch]

    def step(self, step: int) -> Step:
        generator = torch.Generator().manual_seed(self.config["seed"] * 1_000_003 + int(step))
        self.model.before_step(int(step), generator)
        indices = self._rays_of_step(int(step), generator)
        alpha = None if self.transparency is None else 1 - self.transparency[indices]
        output = self.model(self.rays.rays(indices, generator), self.training_background, jitter=True)
        losses = [torch.mean((rendered.color - self.colors[indices]) ** 2) for rendered in output.passes]
        if self.random_background:
            # What the random backgrounds' spread adds to the colour error, in expectation.
            losses = [loss + random_background_loss(rendered.opacity, alpha)
                      for loss, rendered in zip(losses, output.passes)]
        # Of the final pass's colour (over random backgrounds, in expectation, where they are on).
        stats = {"psnr": psnr_from_mse(float(losses[-1].detach()))}
        if self.alpha_loss:
            losses.append(self.alpha_loss * (output.passes[-1].opacity - alpha).abs().mean())
        if self.distortion:
            # Each ray's weight drawn into one thin layer; distances in units of the scene's depth range.
            final = output.passes[-1]
            losses.append(self.distortion * distortion_loss(final.weights, final.samples, self.depth_scale))
        if self.budget is not None:
            self.budget.update(len(indices), output.samples)
            stats.update(rays=float(len(indices)), samples_per_ray=output.samples / max(len(indices), 1))
        auxiliary = {} if output.auxiliary_loss is None else {"auxiliary_loss": output.auxiliary_loss}
        return Step(sum(losses), stats, auxiliary)

    def evaluate(self, epoch: int) -> dict[str, float]:
        if not len(self.evaluated):  # --holdout-every 0: the round's training PSNR is the score
            return {}
        keep = self.on_evaluate is not None
        scores, renders = self.heldout.during(self.render, keep_renders=keep)
        finished = min((epoch + 1) * self.round_steps, self.config["steps"])
        record = {"psnr": scores["psnr"], "opacity_error": scores["opacity_error"],
                  "epochs": finished / self.steps_per_epoch}
        if keep:
            self.on_evaluate({**record, "step": finished}, renders)
        return record

    def draw(self, run: RunDirectory, history: list[dict[str, Any]]) -> None:
        plotted = ("step", "train_loss", "train_psnr", "psnr")
        records = [{k: v for k, v in record.items() if k in plotted} for record in history]
        plot_training_curves(records, run.path / CURVES_PNG, title=f"{self.config['model']} NeRF", x="step")

    def finish(self, run: RunDirectory, state: TrainingState) -> dict[str, Any]:
        """Score every held-out view (as many as the time budget holds); save their renders beside the truth."""
        if not len(self.heldout_frames):
            return {**training_only_scores(state), "steps": state.step, "epochs": state.step / self.steps_per_epoch,
                    "training_rays": len(self.rays)}
        scores, renders = self.heldout.final(self.render, self.time_budget, self.progress)
        save_panels(run.path / HELDOUT_DIR, renders, *depth_range(self.scene, [view for _, view, _ in renders]))
        return {
            **scores,
            "steps": state.step,
            "epochs": state.step / self.steps_per_epoch,
            "training_rays": len(self.rays),
        }

    def finishing_seconds(self) -> float | None:
        return self.heldout.final_seconds()


def train(
    scene: str | os.PathLike[str] | None = None,
    *,
    model: str = "ngp",
    out: str | os.PathLike[str] = "runs/nerf",
    steps: int | None = None,
    max_time: float | None = None,
    max_training_time: float | None = None,
    batch_rays: int = 1024,
    downscale: int | str = "auto",
    holdout_every: int | None = None,
    background: str | Sequence[float] | None = None,
    random_background: bool | None = None,
    alpha_loss: float | None = None,
    distortion: float | None = None,
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

    ``model`` is "ngp" (the hash-grid field, the default: the fast one), "tiny" (the lesson's
    TinyNeRF), "nerf" (the original coarse + fine NeRF) or "sdf" (the hash-grid signed distance
    field rendered as NeuS does, :mod:`pointfield.fields.sdf`; always in the object's bounded box).
    ``steps`` defaults to 2000 (tiny), 5000 (nerf) or 3000 (ngp, sdf); ``max_time``: the call returns
    within that many seconds of wall clock, start-up and the final evaluation included (which
    scores as many held-out views as fit, ``views`` of ``heldout_views``); ``max_training_time``
    stops after that many seconds of training instead (evaluation excluded, summed over resumed
    sessions), then scores every held-out view: what benchmarks at equal training time use.
    Every ``eval_every`` steps (default: one epoch, at most 500 steps) the first ``eval_views``
    held-out views are rendered and scored. Without ``scene``, the synthetic cube of
    ``cube_views`` views of ``cube_size`` pixels square is rendered and trained on.
    ``background`` ("white", "black" or an RGB triple) replaces the scene's: images' alpha is
    composited onto it and so is every render.
    Where the images have alpha, opacity is trained towards it (:mod:`pointfield.training.opacity`):
    ``random_background`` trains as if a random colour were behind each ray, in expectation
    (None: on), and ``alpha_loss`` adds ``weight * mean |opacity - alpha|`` to the loss (None: 0,
    off). ``distortion``: the weight of mip-NeRF 360's distortion loss on the final pass's
    weights, which draws each ray's weight into one thin layer (None:
    :data:`BOUNDED_NGP_DISTORTION` for ngp on a bounded scene, else 0).
    ``model_options`` go to the model's constructor (``samples`` for tiny,
    ``coarse_samples``/``fine_samples`` for nerf). ``scene_box`` (ngp only; see
    :func:`pointfield.fields.scene_box.scene_bounds`): "auto", "bounded", "unbounded" or six
    numbers. ``learning_rate`` defaults to :data:`LEARNING_RATES` of the model.
    ``on_evaluate(record, renders)`` is called after each evaluation with the round's
    ``{"step", "epochs", "psnr"}`` and the held-out renders ``[(frame, view, truth)]`` (the
    exercise draws its strip with it). Resuming, only ``steps`` may change.
    """
    settings = {
        "scene": scene, "model": model, "model_options": model_options, "steps": steps,
        "batch_rays": batch_rays, "downscale": downscale, "holdout_every": holdout_every,
        "background": background, "random_background": random_background, "alpha_loss": alpha_loss, "distortion": distortion, "seed": seed,
        "eval_every": eval_every, "eval_views": eval_views, "learning_rate": learning_rate, "scene_box": scene_box if isinstance(scene_box, str) else list(scene_box),
        "cube_views": cube_views, "cube_size": cube_size,
    }
    return lifecycle.train(NerfTask, settings, options={"on_evaluate": on_evaluate}, out=out, resume=resume,
                           device=device, max_time=max_time, max_training_time=max_training_time, progress=progress)
