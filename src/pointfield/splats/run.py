"""Rendering, evaluating and exporting Gaussian splats: a trained run, or a splat ``.ply``.

=========================================================  ==============
``pointfield splat render RUN|scene.ply [--scene S] ...``  :func:`render`
``pointfield splat export RUN --out scene.ply``            :func:`export`
=========================================================  ==============

:class:`SplatRun` is what :func:`pointfield.load_run` opens for a splat run; it renders any
camera as every scene run does (:class:`~pointfield.scenes.run.SceneRun`). Depth is the
expected depth of the covered part of each pixel (the rasterizer's alpha-weighted depth over
its alpha), as for the fields; median depth is the depth of the splat at which the pixel's
accumulated alpha reaches one half. Both are distances along the pixel's ray.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from pointfield.devices import pick_device
from pointfield.errors import PointfieldError
from pointfield.scenes.cameras import Cameras
from pointfield.scenes.heldout import OUTPUTS, View, open_scene, training_and_heldout
from pointfield.scenes.run import SceneRun, render_path
from pointfield.splats.gaussians import PARAMETER_NAMES, Gaussians
from pointfield.splats.gsplat_rasterizer import choose_rasterizer, rasterization_gsplat
from pointfield.splats.mip import SMOOTHING, baked, drawn, training_smoothing
from pointfield.splats.ply import read_splat_mode, read_splats, write_splats
from pointfield.splats.rasterizer import SCREEN_DILATION, rasterization, rasterizer_mode
from pointfield.training.checkpoints import load_checkpoint
from pointfield.training.lifecycle import open_run
from pointfield.training.run import RunDirectory
from pointfield.viz.views import PANELS

TASK = "splat"


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
    median_depth: bool = False, antialiased: bool = False, screen_dilation: float = SCREEN_DILATION,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, dict[str, torch.Tensor]]:
    """Render ``gaussians`` into cameras: ``(colors (C, H, W, 3), depths, alphas, meta)``.

    ``rasterizer``: "pointfield" (:func:`~pointfield.splats.rasterizer.rasterization`), "gsplat"
    or "auto" (:mod:`pointfield.splats.gsplat_rasterizer`). ``median_depth``: also
    ``meta["median_depths"]`` ``(C, H, W)`` (camera z, as the rasterizer gives it); gsplat
    renders none, so with gsplat pointfield's rasterizer renders it, in a second pass.
    ``antialiased``, ``screen_dilation``: the rasterizers' mode and dilation (:func:`~pointfield.splats.rasterizer.rasterizer_mode`:
    the ones the splats were trained with).
    """
    chosen = choose_rasterizer(rasterizer, gaussians.means.device)
    scales, opacities = drawn(gaussians)  # with Mip-Splatting's 3D filter where the run has it
    splats = (gaussians.means, gaussians.quats, scales, opacities, gaussians.sh_coefficients)
    options = {"sh_degree": gaussians.active_sh_degree if sh_degree is None else sh_degree, "backgrounds": background,
               "antialiased": antialiased, "screen_dilation": screen_dilation}
    if chosen == "pointfield":
        return rasterization(*splats, viewmats, Ks, width, height, **options, median_depth=median_depth)
    colors, depths, alphas, meta = rasterization_gsplat(*splats, viewmats, Ks, width, height, **options)
    if median_depth:
        meta["median_depths"] = rasterization(*splats, viewmats, Ks, width, height, **options,
                                              median_depth=True)[3]["median_depths"]
    return colors, depths, alphas, meta


@torch.no_grad()
def render_camera(
    gaussians: Gaussians, cameras: Cameras, index: int, background: torch.Tensor, rasterizer: str = "pointfield",
    outputs: Sequence[str] = OUTPUTS, antialiased: bool = False, screen_dilation: float = SCREEN_DILATION,
) -> View:
    """Camera ``index`` rendered: ``rgb`` ``(H, W, 3)``, expected ``depth`` and ``opacity`` ``(H, W)``,
    and ``median_depth`` ``(H, W)`` where ``outputs`` asks for it.

    The rasterizer blends each splat's camera z; depth is reported, as for every scene model, as
    the distance along the pixel's ray: camera z (expected, or the median splat's) divided by
    the cosine between the ray and the optical axis.
    """
    device = gaussians.means.device
    viewmats, Ks = camera_matrices(cameras[[index]], device)
    width, height = int(cameras.width[index]), int(cameras.height[index])
    median = "median_depth" in outputs
    colors, depths, alphas, meta = render_views(gaussians, viewmats, Ks, width, height, background,
                                                rasterizer=rasterizer, median_depth=median, antialiased=antialiased,
                                                screen_dilation=screen_dilation)
    axis_cosine = cameras.rays(index).axis_cosine.to(device, depths.dtype)
    view = {
        "rgb": colors[0].clamp(0, 1),
        "depth": depths[0] / alphas[0].clamp_min(1e-6) / axis_cosine,
        "opacity": alphas[0].clamp(0, 1),
    }
    if median:
        view["median_depth"] = meta["median_depths"][0] / axis_cosine
    return view


class SplatRun(SceneRun):
    """A trained splat run: its Gaussians (all SH degrees the run reached) render any camera,
    in the rasterizer mode they were trained in (:func:`~pointfield.splats.rasterizer.rasterizer_mode`)."""

    tasks = (TASK,)

    def __init__(self, directory: RunDirectory, config: dict[str, Any], module: Gaussians, device: torch.device,
                 rasterizer: str = "auto"):
        super().__init__(directory, config, module, device)
        self.rasterizer = choose_rasterizer(rasterizer, device)

    @classmethod
    def open(cls, directory: RunDirectory, config: dict[str, Any], device: torch.device) -> SplatRun:
        payload = load_checkpoint(directory.checkpoint, {"task": TASK})
        state = payload["model"]
        missing = [name for name in PARAMETER_NAMES if name not in state]
        if missing:
            raise PointfieldError(f"{directory.checkpoint}: no {', '.join(missing)} in the checkpoint")
        try:
            gaussians = Gaussians(**{name: state[name].float() for name in PARAMETER_NAMES})
        except ValueError as error:
            raise PointfieldError(f"{directory.checkpoint}: {error}") from None
        extra = state.get("_extra_state")
        if isinstance(extra, dict) and "active_sh_degree" in extra:
            gaussians.active_sh_degree = int(extra["active_sh_degree"])
        gaussians = gaussians.to(device).eval()
        run = cls(directory, config, gaussians, device)
        if config.get("mip"):
            train_frames, _ = training_and_heldout(run.scene)
            # A mip run made before the strength was recorded was trained with Mip-Splatting's 0.2.
            gaussians.smoothing = training_smoothing(gaussians, run.scene.cameras[train_frames],
                                                     float(config.get("mip_smoothing", SMOOTHING)))
        return run

    @property
    def gaussians(self) -> Gaussians:
        return self.module

    def render_one(self, cameras: Cameras, index: int, outputs: Sequence[str] = OUTPUTS) -> View:
        return render_camera(self.gaussians, cameras, index, self.background, self.rasterizer, outputs,
                             **rasterizer_mode(self.config))


def export(run: str | os.PathLike[str], out: str | os.PathLike[str]) -> dict[str, Any]:
    """Write a trained run's splats as a standard splat ``.ply``, with the run's rasterizer mode
    in a header comment (:mod:`pointfield.splats.ply`), so that rendering the file draws them as
    they were trained to be drawn."""
    opened = open_run((SplatRun,), run, "cpu")
    gaussians, mode = opened.gaussians, rasterizer_mode(opened.config)
    if gaussians.smoothing is not None:
        gaussians = baked(gaussians)  # the 3D filter in the scales and opacities, for any viewer
    write_splats(out, gaussians, mode)
    return {"out": str(out), "splats": len(gaussians), "sh_degree": gaussians.sh_degree, **mode}


def export_centres(run: str | os.PathLike[str], out: str | os.PathLike[str]) -> dict[str, Any]:
    """Write a trained run's splat centres as a point cloud: colour from SH degree 0, and opacity.

    The degree-0 colour is the view-independent part: ``rgb = 0.5 + C0 * sh_dc``, clipped to [0, 1].
    """
    from pointfield.clouds.cloud import PointCloud
    from pointfield.clouds.formats.registry import write
    from pointfield.fields.encodings.spherical_harmonics import C0

    gaussians = open_run((SplatRun,), run, "cpu").gaussians
    with torch.no_grad():
        rgb = (0.5 + C0 * gaussians.sh_dc[:, 0, :]).clamp(0, 1)
        cloud = PointCloud(
            gaussians.means.double().numpy(),
            {"colors": (rgb * 255).round().to(torch.uint8).numpy(), "opacity": gaussians.opacities.float().numpy()},
        )
    write(out, cloud)
    return {"out": str(out), "points": len(cloud.points)}


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
    outputs: Sequence[str] = PANELS,
    progress: bool = True,
) -> dict[str, Any]:
    """Render a run folder or a splat ``.ply`` along a camera path into ``out``.

    ``path``: orbit, spiral or dataset (:mod:`pointfield.scenes.paths`). A run uses the scene
    it was trained on unless ``scene`` is given; a ``.ply`` needs ``scene`` for its cameras (at
    ``downscale``). ``out`` ending in ``.gif`` / ``.mp4`` gets a video of panels of ``outputs``
    (default colour | depth | opacity), anything else a folder of PNGs, with depth maps as
    ``.npy`` and 16-bit PNG files too (:func:`pointfield.viz.views.write_views`).
    ``rasterizer``: "pointfield", "gsplat" or "auto" (gsplat where it can run). ``progress``: a bar
    over the frames.
    """
    source = Path(source)
    if source.is_dir():
        opened = open_run((SplatRun,), source, device)
        opened.rasterizer = choose_rasterizer(rasterizer, opened.device)
        result = opened.render_path(path, frames=frames, out=out, scene=scene, downscale=downscale, outputs=outputs,
                                    progress=progress)
        return {**result, "splats": len(opened.gaussians), "rasterizer": opened.rasterizer}
    if scene is None:
        raise PointfieldError(f"{source}: a splat file has no cameras; pass --scene SCENE to render it")
    torch_device = pick_device(device)
    chosen = choose_rasterizer(rasterizer, torch_device)  # before anything is read or written
    gaussians, mode = read_splats(source).to(torch_device), read_splat_mode(source)
    around = open_scene(scene, downscale)
    background = torch.as_tensor(around.background, dtype=torch.float32, device=torch_device)

    def render_cameras(cameras: Cameras, rendered: Sequence[str]) -> list[View]:
        return [render_camera(gaussians, cameras, index, background, chosen, rendered, **mode)
                for index in range(len(cameras))]

    result = render_path(render_cameras, around, path, frames=frames, out=out, outputs=outputs, progress=progress)
    return {**result, "splats": len(gaussians), "rasterizer": chosen, **mode}
