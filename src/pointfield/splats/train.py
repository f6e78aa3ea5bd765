"""Training, rendering and exporting Gaussian splats: the functions behind ``pointfield splat``.

========================================================  ====================================
``pointfield splat train [SCENE] --out RUN ...``           :func:`train`
``pointfield splat render RUN|scene.ply [--scene S] ...``  :func:`render`
``pointfield splat export RUN --out scene.ply``            :func:`export`
========================================================  ====================================

Example::

    from pointfield.splats.train import train, export
    metrics = train("nerf_synthetic/lego", out="runs/lego-splats", downscale=8, steps=3000)
    export("runs/lego-splats", "lego.ply")       # opens in any splat viewer

The recipe is the 3D Gaussian splatting paper's, scaled to short runs: splats start at the
scene's sparse points (COLMAP), else at random in its bounding box (``initial_splats`` of
them); each step renders one training view (a seeded shuffle of the views per pass) and
minimises ``0.8 L1 + 0.2 (1 - SSIM)`` (:mod:`pointfield.splats.loss`) with Adam, one learning
rate per parameter (gsplat's: means ``1.6e-4 x scene scale`` decayed exponentially to a
hundredth, scales ``5e-3``, rotations ``1e-3``, opacities ``5e-2``, SH ``2.5e-3`` and a
twentieth of it for the higher bands). :class:`~pointfield.splats.densification.DefaultStrategy`
grows and prunes the splats from step 500 to half the run, never beyond ``max_splats``.

The loop itself -- checkpoints, resuming, time limit, progress, NaN checks -- is
:func:`pointfield.training.fit`, whose "epochs" are rounds of ``eval_every`` steps ending with
an evaluation on held-out views, exactly as ``nerf train``. The run folder holds
``config.json``, ``metrics.jsonl`` (per round: ``step``, ``seconds``, ``train_loss``,
``train_psnr``, ``splats``, held-out ``psnr``), ``metrics.json`` (``psnr`` and ``ssim`` over
all held-out views, ``splats``, ``steps``, ``seconds``), ``checkpoints/last.pt``,
``training_curves.png`` and ``heldout/NNN.png`` (ground truth | render | depth | alpha).
A resumed run restarts the densification statistics gathered since the last refinement.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np
import torch

from pointfield.errors import PointfieldError
from pointfield.scenes import Cameras, Scene
from pointfield.splats.densification import DefaultStrategy
from pointfield.splats.gaussians import PARAMETER_NAMES, Gaussians
from pointfield.splats.loss import splat_loss
from pointfield.splats.rasterizer import rasterization

TASK = "splat"
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


# -- scenes and initialisation -------------------------------------------------------------------


def scene_scale(scene: Scene) -> float:
    """1.1 x the largest distance of a camera centre from their mean (the 3DGS "extent")."""
    centres = scene.cameras.centers.double().numpy()
    return 1.1 * float(np.linalg.norm(centres - centres.mean(0), axis=1).max()) or 1.0


def initial_gaussians(scene: Scene, count: int, seed: int) -> Gaussians:
    """Splats from the scene's sparse points; else ``count`` at random in its box.

    The box is the scene's ``aabb``; without one (Blender scenes), a cube around the point
    every camera looks at, of half-width a third of the mean camera distance to it (lego's
    cameras at radius 4 give the usual [-1.3, 1.3]^3).
    """
    if scene.points is not None and len(scene.points.points):
        colors = scene.points.fields.get("colors")
        return Gaussians.from_points(np.asarray(scene.points.points, np.float64), colors)
    if scene.aabb is not None:
        low, high = np.asarray(scene.aabb, dtype=np.float64)
    else:
        from pointfield.fields.views import scene_centre_and_up

        centre, _ = scene_centre_and_up(scene)
        half = np.linalg.norm(scene.cameras.centers.double().numpy() - centre, axis=1).mean() / 3
        low, high = centre - half, centre + half
    return Gaussians.random_in_box(count, low, high, seed=seed)


def camera_matrices(cameras: Cameras, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    """gsplat's ``viewmats`` (C, 4, 4) and ``Ks`` (C, 3, 3), float32 on ``device``."""
    if cameras.model != "PINHOLE" and bool(cameras.distortion.abs().max() > 0):
        raise PointfieldError(
            f"splats render pinhole cameras; these are {cameras.model} with distortion "
            f"(undistort the images first)"
        )
    return (cameras.world_to_camera().float().to(device), cameras.intrinsic_matrices().float().to(device))


def render_views(
    gaussians: Gaussians, viewmats: torch.Tensor, Ks: torch.Tensor, width: int, height: int,
    background: torch.Tensor, sh_degree: int | None = None, rasterizer: str = "pointfield",
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, dict[str, torch.Tensor]]:
    """Render ``gaussians`` into cameras: ``(colors (C, H, W, 3), depths, alphas, meta)``.

    ``rasterizer``: "pointfield" (:func:`~pointfield.splats.rasterizer.rasterization`), "gsplat"
    or "auto" (:mod:`pointfield.splats.gsplat_rasterizer`).
    """
    from pointfield.splats.gsplat_rasterizer import choose_rasterizer, rasterization_gsplat

    chosen = choose_rasterizer(rasterizer, gaussians.means.device)
    return (rasterization_gsplat if chosen == "gsplat" else rasterization)(
        gaussians.means, gaussians.quats, gaussians.scales, gaussians.opacities,
        gaussians.sh_coefficients, viewmats, Ks, width, height,
        sh_degree=gaussians.active_sh_degree if sh_degree is None else sh_degree,
        backgrounds=background,
    )


# -- training ----------------------------------------------------------------------------------


def train(
    scene: str | os.PathLike[str] | None = None,
    *,
    out: str | os.PathLike[str] = "runs/splat",
    steps: int | None = None,
    max_time: float | None = None,
    downscale: int = 1,
    holdout_every: int | None = None,
    background: str | None = None,
    device: str | None = None,
    seed: int = 0,
    resume: bool = False,
    max_splats: int = DEFAULT_MAX_SPLATS,
    initial_splats: int = DEFAULT_INITIAL_SPLATS,
    eval_every: int | None = None,
    eval_views: int = 3,
    progress: bool = True,
    cube_views: int = 100,
    cube_size: int = 100,
) -> dict[str, Any]:
    """Train splats on ``scene`` (the synthetic cube when None) into run folder ``out``.

    ``steps`` defaults to 3000; ``max_time`` stops earlier (seconds, summed over resumed
    sessions). Every ``eval_every`` steps (default 250) the first ``eval_views`` held-out
    views are scored. ``max_splats`` caps densification (a message says when it bites).
    Returns the final metrics (also in ``out/metrics.json``).
    """
    from pointfield.devices import pick_device
    from pointfield.fields.train import open_scene_of, training_and_heldout
    from pointfield.image_metrics import psnr_from_mse
    from pointfield.training import RunDirectory, fit, load_checkpoint

    run = RunDirectory(out)
    config = {
        "task": TASK,
        "scene": None if scene is None else str(Path(scene).resolve()),
        "cube_views": int(cube_views),
        "cube_size": int(cube_size),
        "downscale": int(downscale),
        "holdout_every": holdout_every,
        "background": background,
        "steps": int(steps if steps is not None else DEFAULT_STEPS),
        "max_splats": int(max_splats),
        "initial_splats": int(initial_splats),
        "seed": int(seed),
        "eval_every": int(eval_every or 250),
        "eval_views": int(eval_views),
    }
    if resume and run.exists():
        saved = run.read_config()
        if saved.get("task") != TASK:
            raise PointfieldError(f"{run.path} is a {saved.get('task')!r} run, not a splat run")
        # The run's own settings win; only the length of training and the cap may change.
        config = {**saved, "steps": config["steps"] if steps is not None else saved["steps"],
                  "max_splats": config["max_splats"]}
    if config["steps"] < 1 or config["max_splats"] < 1 or config["initial_splats"] < 1 or config["eval_every"] < 1:
        raise PointfieldError("--steps, --max-splats and --eval-every must be positive")
    scene_data = open_scene_of(config)
    train_frames, heldout_frames = training_and_heldout(scene_data)
    torch_device = pick_device(device)
    run.create(resume)  # only now: a bad scene or option leaves an existing folder untouched
    run.write_config(config)

    torch.manual_seed(config["seed"])
    gaussians = initial_gaussians(scene_data, config["initial_splats"], config["seed"])
    if len(gaussians) > config["max_splats"]:
        raise PointfieldError(
            f"the scene starts with {len(gaussians):,} splats, more than --max-splats "
            f"{config['max_splats']:,}"
        )
    gaussians = gaussians.to(torch_device)
    extent = scene_scale(scene_data)
    optimizer = torch.optim.Adam(
        [{"params": [getattr(gaussians, name)], "lr": LEARNING_RATES[name] * (extent if name == "means" else 1),
          "name": name, "eps": 1e-15} for name in PARAMETER_NAMES]
    )
    means_learning_rate = LEARNING_RATES["means"] * extent
    total_steps = config["steps"]
    strategy = DefaultStrategy(
        scene_scale=extent, max_splats=config["max_splats"], seed=config["seed"],
        refine_start=min(500, total_steps // 10), refine_stop=max(total_steps // 2, 1),
        sh_degree_interval=max(min(1000, total_steps // 4), 1),
    )

    height, width = int(scene_data.cameras.height[0]), int(scene_data.cameras.width[0])
    viewmats, Ks = camera_matrices(scene_data.cameras, torch_device)
    images = {int(i): torch.from_numpy(scene_data.image(int(i))).to(torch_device) for i in train_frames}
    background_color = torch.as_tensor(scene_data.background, dtype=torch.float32, device=torch_device)
    round_steps = config["eval_every"]
    rounds = math.ceil(total_steps / round_steps)
    evaluated = heldout_frames[: max(1, config["eval_views"])]

    def view_of_step(step_index: int) -> int:
        epoch, position = divmod(step_index, len(train_frames))
        generator = torch.Generator().manual_seed(config["seed"] * 1_000_003 + epoch)
        return int(train_frames[int(torch.randperm(len(train_frames), generator=generator)[position])])

    def batches(round_index: int) -> list[int]:
        first = round_index * round_steps
        return [view_of_step(s) for s in range(first, min(first + round_steps, total_steps))]

    progress_state = {"step": 0, "meta": None}
    if resume and run.checkpoint.is_file():
        progress_state["step"] = int(load_checkpoint(run.checkpoint)["state"].get("step", 0))

    def step(view: int) -> tuple[torch.Tensor, dict[str, float]]:
        done = progress_state["step"]
        # The previous step's gradients are complete and applied: densify before rendering.
        if progress_state["meta"] is not None:
            strategy.after_backward(gaussians, optimizer, progress_state["meta"], done, width, height)
        gaussians.active_sh_degree = strategy.sh_degree_at(done, gaussians.sh_degree)
        optimizer.param_groups[0]["lr"] = means_learning_rate * FINAL_MEANS_LEARNING_RATE_FRACTION ** (done / total_steps)
        colors, _, _, meta = render_views(gaussians, viewmats[[view]], Ks[[view]], width, height, background_color)
        meta["means2d"].retain_grad()
        progress_state["meta"] = meta
        progress_state["step"] = done + 1
        rendered = colors[0]
        loss = splat_loss(rendered, images[view])
        mse = float(torch.mean((rendered.detach().clamp(0, 1) - images[view]) ** 2))
        return loss, {"psnr": psnr_from_mse(mse), "splats": float(len(gaussians))}

    def evaluate(round_index: int) -> dict[str, float]:
        scores, _ = heldout_scores(gaussians, scene_data, evaluated, torch_device, background_color)
        return {"psnr": scores["psnr"], "splats": len(gaussians)}

    def redraw(history: list[dict[str, Any]]) -> None:
        from pointfield.viz.plots import plot_training_curves

        plotted = ("step", "train_loss", "train_psnr", "psnr")
        records = [{k: v for k, v in record.items() if k in plotted} for record in history]
        plot_training_curves(records, run.path / CURVES_PNG, title="Gaussian splats", x="step")

    # The rasterizer's compiled kernels are built on first use (seconds): here, before the clock.
    with torch.no_grad():
        render_views(gaussians, viewmats[:1], Ks[:1], width, height, background_color)
    identity = {"task": TASK, "sh_degree": gaussians.sh_degree}
    state = fit(
        gaussians, optimizer, step, batches, rounds, run=run, identity=identity,
        evaluate=evaluate, on_epoch_end=redraw, loss_aliases=("loss",), resume=resume, max_seconds=max_time,
        device=torch_device, progress=progress,
    )
    scores, renders = heldout_scores(gaussians, scene_data, heldout_frames, torch_device, background_color, keep_renders=True)
    save_heldout_panels(run.path / HELDOUT_DIR, renders, scene_data)
    metrics = {**scores, "splats": len(gaussians), "steps": state.step, "seconds": round(state.seconds, 3)}
    run.write_final_metrics(metrics)
    return metrics


@torch.no_grad()
def heldout_scores(
    gaussians: Gaussians, scene: Scene, frames, device: torch.device, background: torch.Tensor,
    keep_renders: bool = False,
) -> tuple[dict[str, float], list[tuple[int, dict[str, np.ndarray], np.ndarray]]]:
    """PSNR (of the mean MSE) and mean SSIM over ``frames``; the renders when ``keep_renders``."""
    from pointfield.image_metrics import psnr_from_mse, ssim

    height, width = int(scene.cameras.height[0]), int(scene.cameras.width[0])
    viewmats, Ks = camera_matrices(scene.cameras[np.asarray(frames)], device)
    squared_errors, similarities, renders = [], [], []
    for position, frame in enumerate(frames):
        colors, depths, alphas, _ = render_views(gaussians, viewmats[[position]], Ks[[position]], width, height, background)
        image = colors[0].clamp(0, 1).cpu().numpy()
        truth = scene.image(int(frame))
        squared_errors.append(float(np.mean((image - truth) ** 2)))
        similarities.append(ssim(image, truth))
        if keep_renders:
            renders.append((int(frame), view_arrays(colors[0], depths[0], alphas[0]), truth))
    return {"psnr": psnr_from_mse(float(np.mean(squared_errors))), "ssim": float(np.mean(similarities)),
            "views": len(frames)}, renders


def view_arrays(colors: torch.Tensor, depths: torch.Tensor, alphas: torch.Tensor) -> dict[str, np.ndarray]:
    """One render as the ``color`` / ``depth`` (expected, per covered pixel) / ``opacity`` arrays the viewers take."""
    expected_depth = depths / alphas.clamp_min(1e-6)
    return {
        "color": colors.clamp(0, 1).cpu().numpy(),
        "depth": expected_depth.cpu().numpy(),
        "opacity": alphas.clamp(0, 1).cpu().numpy(),
    }


def depth_range(scene: Scene, views: list[dict[str, np.ndarray]]) -> tuple[float, float]:
    """Near and far for depth pictures: the scene's bounds, else the rendered depths' 1-99 %."""
    from pointfield.fields.train import ray_bounds
    from pointfield.scenes import SceneError

    try:
        bounds = ray_bounds(scene)
        return float(bounds[:, 0].min()), float(bounds[:, 1].max())
    except SceneError:
        depths = np.concatenate([view["depth"][view["opacity"] > 0.5] for view in views])
        if len(depths) == 0:
            return 0.0, 1.0
        near, far = np.percentile(depths, [1, 99])
        return float(near), float(max(far, near + 1e-6))


def save_heldout_panels(folder: Path, renders: list, scene: Scene) -> None:
    from pointfield.fields.train import view_panel
    from pointfield.viz.render import save_image

    folder.mkdir(parents=True, exist_ok=True)
    near, far = depth_range(scene, [view for _, view, _ in renders]) if renders else (0.0, 1.0)
    for index, view, truth in renders:
        save_image(folder / f"{index:03d}.png", view_panel(view, near, far, truth=truth))


# -- using a trained run or a splat file ----------------------------------------------------------


def load_run(run: str | os.PathLike[str], device: str | None = None) -> tuple[dict[str, Any], Gaussians, torch.device]:
    """A trained run's config and its splats (all SH degrees the run reached) on ``device``."""
    from pointfield.devices import pick_device
    from pointfield.training import RunDirectory, load_checkpoint

    folder = RunDirectory(run)
    config = folder.read_config()
    if config.get("task") != TASK:
        raise PointfieldError(f"{folder.path}: not a splat run (task {config.get('task')!r})")
    payload = load_checkpoint(folder.checkpoint, {"task": TASK})
    state = payload["model"]
    missing = [name for name in PARAMETER_NAMES if name not in state]
    if missing:
        raise PointfieldError(f"{folder.checkpoint}: no {', '.join(missing)} in the checkpoint")
    try:
        gaussians = Gaussians(**{name: state[name].float() for name in PARAMETER_NAMES})
    except ValueError as error:
        raise PointfieldError(f"{folder.checkpoint}: {error}") from None
    extra = state.get("_extra_state")
    if isinstance(extra, dict) and "active_sh_degree" in extra:
        gaussians.active_sh_degree = int(extra["active_sh_degree"])
    torch_device = pick_device(device)
    return config, gaussians.to(torch_device), torch_device


def export(run: str | os.PathLike[str], out: str | os.PathLike[str]) -> dict[str, Any]:
    """Write a trained run's splats as a standard splat ``.ply``."""
    from pointfield.splats.ply import write_splats

    _, gaussians, _ = load_run(run, "cpu")
    write_splats(out, gaussians)
    return {"out": str(out), "splats": len(gaussians), "sh_degree": gaussians.sh_degree}


def render(
    source: str | os.PathLike[str],
    *,
    scene: str | os.PathLike[str] | None = None,
    downscale: int = 1,
    path: str = "orbit",
    frames: int | None = None,
    out: str | os.PathLike[str] = "render.gif",
    device: str | None = None,
    rasterizer: str = "auto",
) -> dict[str, Any]:
    """Render a run folder or a splat ``.ply`` along a camera path into ``out``.

    ``path``: orbit, spiral or dataset (see :func:`pointfield.fields.views.path_cameras`).
    A run uses the scene it was trained on unless ``scene`` is given; a ``.ply`` needs
    ``scene`` for its cameras (at ``downscale``). ``out`` ending in ``.gif`` / ``.mp4`` gets a
    video of colour | depth | alpha panels, anything else a folder of PNGs. ``rasterizer``:
    see :func:`render_views` (by default gsplat where it can run).
    """
    from pointfield.devices import pick_device
    from pointfield.fields.train import open_scene, open_scene_of
    from pointfield.fields.views import path_cameras, write_views
    from pointfield.splats.gsplat_rasterizer import choose_rasterizer
    from pointfield.splats.ply import read_splats

    source = Path(source)
    out = Path(out)
    if out.suffix.lower() not in ("", ".gif", ".mp4"):
        raise PointfieldError(f"{out}: render output must end in .gif or .mp4, or be a folder")
    if source.is_dir():
        config, gaussians, torch_device = load_run(source, device)
        scene_data = open_scene(scene, downscale) if scene is not None else open_scene_of(config)
        background = scene_data.background
    else:
        if scene is None:
            raise PointfieldError(f"{source}: a splat file has no cameras; pass --scene SCENE to render it")
        torch_device = pick_device(device)
        gaussians = read_splats(source).to(torch_device)
        scene_data = open_scene(scene, downscale)
        background = scene_data.background
    chosen = choose_rasterizer(rasterizer, torch_device)  # before anything is rendered or written
    cameras = path_cameras(scene_data, path, frames)
    viewmats, Ks = camera_matrices(cameras, torch_device)
    background_color = torch.as_tensor(background, dtype=torch.float32, device=torch_device)
    views = []
    with torch.no_grad():
        for index in range(len(cameras)):
            width, height = int(cameras.width[index]), int(cameras.height[index])
            colors, depths, alphas, _ = render_views(
                gaussians, viewmats[[index]], Ks[[index]], width, height, background_color, rasterizer=chosen,
            )
            views.append(view_arrays(colors[0], depths[0], alphas[0]))
    near, far = depth_range(scene_data, views)
    write_views(views, out, near, far)
    return {"out": str(out), "frames": len(views), "path": path, "splats": len(gaussians),
            "rasterizer": chosen}
