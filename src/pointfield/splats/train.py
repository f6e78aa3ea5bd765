"""Training Gaussian splats on a scene: ``pointfield splat train`` (:func:`train`).

Example::

    from pointfield.splats.train import train
    from pointfield.splats.run import export
    metrics = train("nerf_synthetic/lego", out="runs/lego-splats", downscale=8, steps=3000)
    export("runs/lego-splats", "lego.ply")       # opens in any splat viewer

The recipe is the 3D Gaussian splatting paper's, scaled to short runs: splats start at the
scene's sparse points (COLMAP, ``scene from-images``), else at random in its bounding box
(``initial_splats`` of them; ``init="random"`` chooses this even where points exist); each step renders one training view (a seeded shuffle of the views per pass) and
minimises ``0.8 L1 + 0.2 (1 - SSIM)`` (:mod:`pointfield.splats.loss`) with Adam, one learning
rate per parameter (gsplat's: means ``1.6e-4 x scene scale`` decayed exponentially to a
hundredth, scales ``5e-3``, rotations ``1e-3``, opacities ``5e-2``, SH ``2.5e-3`` and a
twentieth of it for the higher bands). Where the images have alpha (objects on a transparent
background), ``0.1 mean |rendered opacity - alpha|`` is added, so that no splat haze lingers in
empty space and no surface the colour of the background turns transparent (as for the fields:
:mod:`pointfield.training.opacity`; a random background per image instead cost 0.7 dB on the
synthetic cube). Asked for (``opacity_entropy``, ``flatness``, ``depth_distortion``), the
splats' mean opacity entropy, their mean smallest scale over the scene scale and (from step
``DEPTH_DISTORTION_FROM``) the spread of each pixel's splats in depth are added too, which make
splats opaque discs in one layer on the surface rather than faint blobs filling a solid object:
better geometry from depth, at a cost in PSNR (:mod:`pointfield.splats.loss`). Asked for
(``antialiased``), splats train and render in the rasterizer's antialiased mode
(:func:`~pointfield.splats.rasterizer.rasterization`), where a surface of splats smaller than a
pixel is drawn much closer to its true outline: in classic mode the true cube's surface, tiled with
small flat splats, renders 11.7 % more outline pixels than the cube (3.3 % antialiased), and
training shrinks the object about a pixel to match. With Mip-Splatting's smaller filter
(``screen_dilation=0.1`` px^2 instead of 3DGS's 0.3) it is drawn closer still (tiled with discs
of 0.01: 3.8 % over its outline, against 6.2 % at 0.3). The run records both, and everything
that renders the run uses them. By default (``mip``, :mod:`pointfield.splats.mip`) splats train
with Mip-Splatting's 2D filter, the antialiased mode at 0.1 px^2, and its 3D filter at strength
``mip_smoothing`` 0 unless asked for (:data:`DEFAULT_MIP_SMOOTHING` says why).
:class:`~pointfield.splats.densification.DefaultStrategy` grows and prunes the splats from step 500 to half the run, never beyond ``max_splats``;
``strategy="mcmc"`` chooses :class:`~pointfield.splats.densification.MCMCStrategy` instead
(3DGS-MCMC: relocation of dead splats, a hard cap, its opacity and scale regularisers).

:class:`SplatTask` is this recipe as the one training lifecycle (:mod:`pointfield.training`)
runs it: checkpoints, resuming, time limit, progress and NaN checks come from there, and its
"epochs" are rounds of ``eval_every`` steps ending with an evaluation on held-out views (mean
of per-view PSNR, :mod:`pointfield.scenes.heldout`), exactly as ``nerf train``. The run folder holds
``config.json``, ``metrics.jsonl`` (per round: ``step``, ``seconds``, ``train_loss``,
``train_psnr``, ``splats``, held-out ``psnr``), ``metrics.json`` (``psnr`` and ``ssim`` over
all held-out views, ``splats``, ``steps``, ``seconds``), ``checkpoints/last.pt``,
``training_curves.png`` and ``heldout/NNN.png`` (ground truth | render | depth | alpha).
A resumed run restarts the densification statistics gathered since the last refinement.
"""

from __future__ import annotations

import math
import os
from typing import Any

import numpy as np
import torch

from pointfield.errors import PointfieldError
from pointfield.fields.encodings.spherical_harmonics import sh_to_rgb
from pointfield.metrics import psnr_from_mse
from pointfield.scenes.heldout import (
    HeldoutEvaluation,
    depth_range,
    open_scene_of,
    scene_config,
    training_and_heldout,
    training_only_scores,
)
from pointfield.scenes.paths import scene_centre_and_up
from pointfield.scenes.scene import Scene
from pointfield.scenes.training_defaults import choose_scene_defaults
from pointfield.splats.densification import STRATEGIES, make_strategy
from pointfield.splats.gaussians import PARAMETER_NAMES, Gaussians
from pointfield.splats.loss import (
    depth_distortion,
    flatness,
    opacity_entropy,
    splat_loss,
)
from pointfield.splats.mip import MIP_DILATION, REFRESH_EVERY, SMOOTHING, drawn, training_smoothing
from pointfield.splats.rasterizer import SCREEN_DILATION, rasterization, rasterizer_mode
from pointfield.splats.run import (
    TASK,
    camera_matrices,
    render_camera,
    render_views,
)
from pointfield.training import lifecycle
from pointfield.training.loop import TrainingState
from pointfield.training.opacity import alpha_loss_weight
from pointfield.training.run import RunDirectory
from pointfield.training.task import Step, Task
from pointfield.viz.plots import plot_training_curves
from pointfield.viz.views import save_panels

DEFAULT_STEPS = 3000
DEFAULT_MAX_SPLATS = 200_000
DEFAULT_INITIAL_SPLATS = 20_000
CURVES_PNG = "training_curves.png"
HELDOUT_DIR = "heldout"
LEARNING_RATES = {
    "means": 1.6e-4,  # times the scene scale
    "log_scales": 5e-3,
    "quats": 1e-3,
    "opacity_logits": 5e-2,
    "sh_dc": 2.5e-3,
    "sh_rest": 2.5e-3 / 20,
}
FINAL_MEANS_LEARNING_RATE_FRACTION = 0.01
DEFAULT_MIP = True
"""Mip-Splatting's filters are on by default: on the cube of ``make bench-near`` (600 steps) they
score 2.1 dB better held out and 3.7 dB better from 0.65x the training distance; lego at 100 x 100
after 1000 steps 0.30 and 0.06 dB lower on two held-out views, seeds 0 and 1 (docs/splats.md)."""
DEFAULT_MIP_SMOOTHING = 0.0
"""The 3D filter's strength ``s`` for new runs (:mod:`pointfield.splats.mip`; Mip-Splatting's is 0.2):
none. On ``make bench-near``'s cube (same run, 600 steps) every distance scored best without it:
held out 31.56 / 30.30 dB, from 0.65x 26.30 / 24.57, from 1.3x 33.38 / 32.27, turntable 28.88 /
26.70 (s = 0 / 0.2; 0.05 and 0.1 in between, in order). The 2D mip filter stays (docs/splats.md)."""
DEFAULT_OPACITY_ENTROPY = 0.0
"""The opacity entropy term's default weight: off. At 0.1 it gained the cube of ``make bench-near``
0.7 dB from 0.65x the training distance but cost lego at 100 x 100 2.3 dB after 1000 steps (it
pushed faint splats to nothing faster than densification grew them: 648 splats left against
2,009; docs/splats.md)."""
DEPTH_DISTORTION_FROM = 1000
"""The step from which the depth distortion (when asked for) is on: 2DGS starts it late too, once
densification has put splats where the surfaces are."""


def scene_scale(scene: Scene) -> float:
    """1.1 x the largest distance of a camera centre from their mean (the 3DGS "extent")."""
    centres = scene.cameras.centers.double().numpy()
    return 1.1 * float(np.linalg.norm(centres - centres.mean(0), axis=1).max()) or 1.0


INITS = ("auto", "points", "random")


def initial_gaussians(scene: Scene, count: int, seed: int, init: str = "auto") -> Gaussians:
    """Splats from the scene's sparse points; else (or with ``init="random"``) ``count`` at random in its box.

    ``init``: "auto" (points when the scene has them), "points" (an error without them) or "random".

    The box is the scene's ``aabb``; without one (Blender scenes), a cube around the point
    every camera looks at, of half-width a third of the mean camera distance to it (lego's
    cameras at radius 4 give the usual [-1.3, 1.3]^3).
    """
    has_points = scene.points is not None and len(scene.points.points) > 0
    if init == "points" and not has_points:
        raise PointfieldError("splat init 'points' needs a scene with sparse points (COLMAP, scene from-images)")
    if has_points and init != "random":
        colors = scene.points.fields.get("colors")
        return Gaussians.from_points(np.asarray(scene.points.points, np.float64), colors)
    if scene.aabb is not None:
        low, high = np.asarray(scene.aabb, dtype=np.float64)
    else:
        centre, _ = scene_centre_and_up(scene)
        half = np.linalg.norm(scene.cameras.centers.double().numpy() - centre, axis=1).mean() / 3
        low, high = centre - half, centre + half
    return Gaussians.random_in_box(count, low, high, seed=seed)


class SplatTask(Task):
    """The splat recipe of the module doc, as the training lifecycle runs it.

    A batch is ``(step, view)``: the global step number (densification and the means' learning
    rate follow it) and the training view it renders.
    """

    name = TASK
    extendable = ("steps", "max_splats")
    loss_aliases = ("loss",)

    @classmethod
    def configure(cls, settings: dict[str, Any]) -> dict[str, Any]:
        # The defaults of a new run; a resumed run keeps its own config.json (the lifecycle), and
        # one made before these defaults, without the keys, keeps training and rendering without them.
        mip = DEFAULT_MIP if settings.get("mip") is None else bool(settings["mip"])
        config = {
            "task": TASK,
            **scene_config(settings),
            "steps": int(settings["steps"] if settings["steps"] is not None else DEFAULT_STEPS),
            "max_splats": int(settings["max_splats"] if settings["max_splats"] is not None else DEFAULT_MAX_SPLATS),
            "initial_splats": int(settings["initial_splats"]),
            "init": settings.get("init") or "auto",
            "seed": int(settings["seed"]),
            "eval_every": int(settings["eval_every"] or 250),
            "eval_views": int(settings["eval_views"]),
            "alpha_loss": settings.get("alpha_loss"),
            "opacity_entropy": float(DEFAULT_OPACITY_ENTROPY if settings.get("opacity_entropy") is None
                                     else settings["opacity_entropy"]),
            "flatness": settings.get("flatness"),
            # Mip-Splatting's filters (on unless turned off): the 3D one (pointfield.splats.mip) and,
            # as its 2D one, the antialiased mode with a 0.1 px^2 dilation unless another is asked for.
            "mip": mip,
            "mip_smoothing": float(DEFAULT_MIP_SMOOTHING if settings.get("mip_smoothing") is None
                                   else settings["mip_smoothing"]),
            "antialiased": bool(settings.get("antialiased") or mip),
            "screen_dilation": float(settings["screen_dilation"] if settings.get("screen_dilation") is not None
                                     else MIP_DILATION if mip else SCREEN_DILATION),
            "depth_distortion": settings.get("depth_distortion"),
            "strategy": settings.get("strategy") or "default",
        }
        if min(config["steps"], config["max_splats"], config["initial_splats"], config["eval_every"]) < 1:
            raise PointfieldError("--steps, --max-splats and --eval-every must be positive")
        if not (math.isfinite(config["mip_smoothing"]) and config["mip_smoothing"] >= 0):
            raise PointfieldError(f"--mip-smoothing must be a number >= 0, got {config['mip_smoothing']}")
        if not (math.isfinite(config["screen_dilation"]) and config["screen_dilation"] > 0):
            raise PointfieldError(f"--screen-dilation must be a positive number of px^2, got {config['screen_dilation']}")
        if config["strategy"] not in STRATEGIES:
            raise PointfieldError(f"--strategy must be one of {', '.join(STRATEGIES)}, got {config['strategy']!r}")
        if config["init"] not in INITS:
            raise PointfieldError(f"--init must be one of {', '.join(INITS)}, got {config['init']!r}")
        return config

    def __init__(self, config, device, distributed, progress):
        super().__init__(config, device, distributed, progress)
        choose_scene_defaults(config, device, say=distributed is None or distributed.is_main)
        self.scene = open_scene_of(config)
        self.train_frames, self.heldout_frames = training_and_heldout(self.scene)
        gaussians = initial_gaussians(self.scene, config["initial_splats"], config["seed"], config.get("init", "auto"))
        if len(gaussians) > config["max_splats"]:
            raise PointfieldError(
                f"the scene starts with {len(gaussians):,} splats, more than --max-splats "
                f"{config['max_splats']:,}"
            )
        self.model = self.trained = gaussians.to(device)
        extent = scene_scale(self.scene)
        self.optimizer = torch.optim.Adam(
            [{"params": [getattr(gaussians, name)], "lr": LEARNING_RATES[name] * (extent if name == "means" else 1),
              "name": name, "eps": 1e-15} for name in PARAMETER_NAMES]
        )
        self.means_learning_rate = LEARNING_RATES["means"] * extent
        total = config["steps"]
        self.strategy = make_strategy(config.get("strategy", "default"), scene_scale=extent,
                                      max_splats=config["max_splats"], seed=config["seed"], steps=total)
        # Each view renders at its own size: a posed photo set may hold several (one camera per size).
        self.sizes = [(int(w), int(h)) for w, h in zip(self.scene.cameras.width, self.scene.cameras.height)]
        self.viewmats, self.Ks = camera_matrices(self.scene.cameras, device)
        pixels = {int(i): self.scene.pixels(int(i)) for i in self.train_frames}  # (image, alpha or None)
        self.images = {i: torch.from_numpy(image).to(device) for i, (image, _) in pixels.items()}
        self.background = torch.as_tensor(self.scene.background, dtype=torch.float32, device=device)
        # Where the images have alpha, the rendered opacity is trained towards it too (module docstring).
        self.alpha_loss = alpha_loss_weight(config.get("alpha_loss"), self.scene, self.train_frames)
        self.alphas = {i: torch.from_numpy(alpha).to(device) for i, (_, alpha) in pixels.items()} if self.alpha_loss else {}
        # The geometry terms, where asked for (a run made before they existed has no such keys).
        self.opacity_entropy = float(config.get("opacity_entropy") or 0.0)
        self.flatness = float(config.get("flatness") or 0.0)
        self.mode = rasterizer_mode(config)  # classic, 0.3 px^2 in runs made before the settings
        self.depth_distortion = float(config.get("depth_distortion") or 0.0)
        self.epochs = math.ceil(total / config["eval_every"])
        self.evaluated = self.heldout_frames[: max(1, config["eval_views"])]
        self.heldout = HeldoutEvaluation(self.scene, self.heldout_frames, self.evaluated)
        self.identity = {"task": TASK, "sh_degree": gaussians.sh_degree}
        self.last_meta: dict[str, torch.Tensor] | None = None  # the previous step's, for densification
        self.last_size = self.sizes[0]  # and the (width, height) it was rendered at

    def warm_up(self) -> None:
        # The rasterizer's compiled kernels are built on first use (seconds): here, before the clock.
        # Rendered as an evaluation renders (one camera's own matrices): dynamo specialises on the
        # matrices' base, so a slice of every camera's (viewmats[:1]) left the first held-out view
        # to compile again. Training's differentiable rendering runs eagerly (rasterizer.py).
        frame = (self.evaluated if len(self.evaluated) else self.train_frames)[0]
        self.render(self.scene.cameras[[int(frame)]])

    def render(self, cameras) -> list[dict[str, torch.Tensor]]:
        return [render_camera(self.model, cameras, index, self.background, **self.mode)
                for index in range(len(cameras))]

    def _view_of_step(self, step: int) -> int:
        epoch, position = divmod(step, len(self.train_frames))
        generator = torch.Generator().manual_seed(self.config["seed"] * 1_000_003 + epoch)
        return int(self.train_frames[int(torch.randperm(len(self.train_frames), generator=generator)[position])])

    def batches(self, epoch: int) -> list[tuple[int, int]]:
        first = epoch * self.config["eval_every"]
        last = min(first + self.config["eval_every"], self.config["steps"])
        return [(step, self._view_of_step(step)) for step in range(first, last)]

    def step(self, batch: tuple[int, int]) -> Step:
        done, view = batch
        gaussians = self.model
        # The previous step's gradients are complete and applied: densify before rendering.
        # (A resumed run restarts the statistics gathered since the last refinement.)
        if self.last_meta is not None:
            self.strategy.after_backward(gaussians, self.optimizer, self.last_meta, done, *self.last_size)
        gaussians.active_sh_degree = self.strategy.sh_degree_at(done, gaussians.sh_degree)
        self.optimizer.param_groups[0]["lr"] = (
            self.means_learning_rate * FINAL_MEANS_LEARNING_RATE_FRACTION ** (done / self.config["steps"])
        )
        if self.config.get("mip") and (done % REFRESH_EVERY == 0 or gaussians.smoothing is None
                                       or len(gaussians.smoothing) != len(gaussians)):
            self._refresh_smoothing()
        distortion_wanted = self.depth_distortion and done >= DEPTH_DISTORTION_FROM
        if distortion_wanted:
            colors, depths, alphas, meta = self._render_with_squared_depth(view)
            rendered = colors[0, ..., :3]
        else:
            colors, _, alphas, meta = render_views(gaussians, self.viewmats[[view]], self.Ks[[view]],
                                                   *self.sizes[view], self.background, **self.mode)
            rendered = colors[0]
        meta["means2d"].retain_grad()
        self.last_meta, self.last_size = meta, self.sizes[view]
        target = self.images[view]
        mse = float(torch.mean((rendered.detach().clamp(0, 1) - target) ** 2))
        loss = splat_loss(rendered, target) + self.strategy.regularization(gaussians)
        if self.alpha_loss:
            loss = loss + self.alpha_loss * (alphas[0] - self.alphas[view]).abs().mean()
        if self.opacity_entropy:
            loss = loss + self.opacity_entropy * opacity_entropy(gaussians.opacities)
        if self.flatness:
            loss = loss + self.flatness * flatness(gaussians.scales, self.strategy.scene_scale)
        if distortion_wanted:
            loss = loss + self.depth_distortion * depth_distortion(depths[0], colors[0, ..., 3], alphas[0],
                                                                   self.strategy.scene_scale)
        return Step(loss,
                    {"psnr": psnr_from_mse(mse), "splats": float(len(gaussians))})

    def _refresh_smoothing(self) -> None:
        """Recompute Mip-Splatting's 3D filter from the training cameras (:mod:`pointfield.splats.mip`)."""
        self.model.smoothing = training_smoothing(self.model, self.scene.cameras[self.train_frames],
                                                  float(self.config.get("mip_smoothing", SMOOTHING)))

    def _render_with_squared_depth(self, view: int):
        """Render training ``view`` with a fourth colour channel: each splat's squared camera z,
        composited (for the depth distortion)."""
        gaussians, viewmat = self.model, self.viewmats[view]
        camera_centre = -viewmat[:3, :3].T @ viewmat[:3, 3]
        z = gaussians.means @ viewmat[2, :3] + viewmat[2, 3]
        features = torch.cat([
            sh_to_rgb(gaussians.sh_coefficients, gaussians.means - camera_centre, gaussians.active_sh_degree),
            (z * z)[:, None],
        ], dim=-1)
        background = torch.cat([self.background, self.background.new_zeros(1)])
        scales, opacities = drawn(gaussians)
        return rasterization(gaussians.means, gaussians.quats, scales, opacities, features,
                             self.viewmats[[view]], self.Ks[[view]], *self.sizes[view], backgrounds=background,
                             **self.mode)

    def evaluate(self, epoch: int) -> dict[str, float]:
        if not len(self.evaluated):  # --holdout-every 0: the round's training PSNR is the score
            return {"splats": len(self.model)}
        scores, _ = self.heldout.during(self.render)
        return {"psnr": scores["psnr"], "opacity_error": scores["opacity_error"], "splats": len(self.model)}

    def draw(self, run: RunDirectory, history: list[dict[str, Any]]) -> None:
        plotted = ("step", "train_loss", "train_psnr", "psnr")
        records = [{k: v for k, v in record.items() if k in plotted} for record in history]
        plot_training_curves(records, run.path / CURVES_PNG, title="Gaussian splats", x="step")

    def finish(self, run: RunDirectory, state: TrainingState) -> dict[str, Any]:
        if self.config.get("mip"):
            self._refresh_smoothing()  # for the final means, as a loaded run computes it
        if not len(self.heldout_frames):
            return {**training_only_scores(state), "splats": len(self.model), "steps": state.step}
        scores, renders = self.heldout.final(self.render, self.time_budget, self.progress)
        near, far = depth_range(self.scene, [view for _, view, _ in renders])
        save_panels(run.path / HELDOUT_DIR, renders, near, far)
        return {**scores, "splats": len(self.model), "steps": state.step}

    def finishing_seconds(self) -> float | None:
        return self.heldout.final_seconds()


def train(
    scene: str | os.PathLike[str] | None = None,
    *,
    out: str | os.PathLike[str] = "runs/splat",
    steps: int | None = None,
    max_time: float | None = None,
    max_training_time: float | None = None,
    downscale: int | str = "auto",
    holdout_every: int | None = None,
    background: str | None = None,
    alpha_loss: float | None = None,
    opacity_entropy: float | None = None,
    flatness: float | None = None,
    antialiased: bool = False,
    screen_dilation: float | None = None,
    mip: bool | None = None,
    mip_smoothing: float | None = None,
    depth_distortion: float | None = None,
    device: str | None = None,
    seed: int = 0,
    resume: bool = False,
    max_splats: int | None = None,
    initial_splats: int = DEFAULT_INITIAL_SPLATS,
    init: str = "auto",
    strategy: str = "default",
    eval_every: int | None = None,
    eval_views: int = 3,
    progress: bool = True,
    cube_views: int = 100,
    cube_size: int = 100,
) -> dict[str, Any]:
    """Train splats on ``scene`` (the synthetic cube when None) into run folder ``out``.

    ``steps`` defaults to 3000; ``max_time``: the call returns within that many seconds of
    wall clock, start-up and the final evaluation included (which scores as many held-out views
    as fit, ``views`` of ``heldout_views``); ``max_training_time`` stops after that many seconds
    of training instead (evaluation excluded, summed over resumed sessions), then scores every
    held-out view: what benchmarks at equal training time use. Every ``eval_every`` steps
    (default 250) the first ``eval_views`` held-out views are scored. ``max_splats`` (default
    200,000) caps densification (a message says when it bites). ``alpha_loss``: weight of the
    mean absolute difference between rendered opacity and the images' alpha, added to the loss
    where the images have alpha (default 0.1; 0 turns it off). ``opacity_entropy``, ``flatness``
    and ``depth_distortion``: weights of the
    geometry terms of :mod:`pointfield.splats.loss` (default off; ``GEOMETRY_WEIGHTS`` there are
    the ones measured). ``antialiased``: train (and render) in the rasterizer's antialiased mode;
    ``screen_dilation``: the variance in px^2 added to every splat's screen footprint (default
    0.1 with the mip filters, else 0.3, :data:`~pointfield.splats.rasterizer.SCREEN_DILATION`).
    ``mip`` (default True, :data:`DEFAULT_MIP`; False turns it off): Mip-Splatting's filters
    (:mod:`pointfield.splats.mip`): each splat's 3D smoothing filter from the training cameras, and
    the antialiased mode with a 0.1 px^2 dilation as the 2D mip filter, so that the splats hold up
    closer than they were trained. ``mip_smoothing``: the 3D filter's strength ``s`` (default
    :data:`DEFAULT_MIP_SMOOTHING`; Mip-Splatting's is 0.2). A run made before these defaults keeps what it was trained
    with (no filters; a mip run, ``s`` = 0.2) when resumed or loaded. ``strategy``: how
    splats are added and removed, "default" (3DGS's cloning, splitting and pruning) or "mcmc"
    (3DGS-MCMC: dead splats relocated, the count grown to ``max_splats``), see
    :mod:`pointfield.splats.densification`. Resuming, only ``steps`` and ``max_splats`` may
    change. Returns the final metrics (also in ``out/metrics.json``).
    """
    settings = {
        "scene": scene, "steps": steps, "downscale": downscale, "holdout_every": holdout_every,
        "background": background, "alpha_loss": alpha_loss, "opacity_entropy": opacity_entropy,
        "flatness": flatness, "antialiased": antialiased,
        "screen_dilation": screen_dilation, "mip": mip, "mip_smoothing": mip_smoothing,
        "depth_distortion": depth_distortion, "seed": seed,
        "max_splats": max_splats, "initial_splats": initial_splats, "init": init, "strategy": strategy,
        "eval_every": eval_every, "eval_views": eval_views, "cube_views": cube_views, "cube_size": cube_size,
    }
    return lifecycle.train(SplatTask, settings, out=out, resume=resume, device=device, max_time=max_time,
                           max_training_time=max_training_time, progress=progress)
