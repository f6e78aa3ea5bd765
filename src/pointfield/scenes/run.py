"""A trained scene model opened for use: one way to render any camera, whatever the model.

:class:`SceneRun` is what :func:`pointfield.load_run` gives for a radiance-field run (tiny,
nerf, ngp) or a splat run. Each renders cameras the same way::

    run = pointfield.load_run("runs/lego-ngp")
    views = run.render(run.scene.cameras[[0, 5]], outputs=("rgb", "depth"))
    views[0]["rgb"].shape          # (H, W, 3), float in [0, 1], on run.device
    run.evaluate()                 # {"psnr": ..., "ssim": ...} on the held-out views
    run.render_path("orbit", frames=60, out="turntable.gif")
    run.render_path("dataset", out="depths", outputs=("depth", "median_depth"))  # depth maps

The outputs are those of :data:`pointfield.scenes.heldout.OUTPUTS`: ``rgb`` ``(H, W, 3)``,
``depth`` ``(H, W)`` (expected distance along the ray, in scene units; 0 where nothing is hit),
``median_depth`` ``(H, W)`` (the distance along the ray where the accumulated opacity passes
0.5, in scene units; 0 where it never does) and ``opacity`` ``(H, W)``. The viewer and the
geometry exporters are written against this.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from functools import cached_property, partial
from pathlib import Path
from typing import Any

import torch

from pointfield.errors import PointfieldError
from pointfield.scenes.cameras import Cameras
from pointfield.scenes.heldout import (
    OUTPUTS,
    View,
    as_numpy,
    depth_range,
    heldout_scores,
    open_scene,
    open_scene_of,
    training_and_heldout,
)
from pointfield.scenes.paths import path_cameras
from pointfield.scenes.scene import Scene
from pointfield.training.run import Run
from pointfield.viz.views import PANELS, check_views_output, write_views


def check_outputs(outputs: Sequence[str]) -> None:
    """Refuse output names that are not in :data:`OUTPUTS`."""
    unknown = [name for name in outputs if name not in OUTPUTS]
    if unknown:
        raise PointfieldError(f"unknown render outputs {unknown}; choose from {', '.join(OUTPUTS)}")


class SceneRun(Run):
    """Base of the field and splat runs: subclasses implement :meth:`render_one`."""

    @cached_property
    def scene(self) -> Scene:
        """The scene the run was trained on (read when first asked for)."""
        return open_scene_of(self.config)

    @property
    def background(self) -> torch.Tensor:
        """``(3,)`` colour behind everything, on the run's device: the training scene's."""
        return torch.as_tensor(self.scene.background, dtype=torch.float32, device=self.device)

    def render_one(self, cameras: Cameras, index: int, outputs: Sequence[str] = OUTPUTS) -> View:
        """Camera ``index`` of ``cameras`` rendered: at least ``outputs`` (of :data:`OUTPUTS`)."""
        raise NotImplementedError

    @torch.no_grad()
    def render(self, cameras: Cameras, outputs: Sequence[str] = OUTPUTS) -> list[View]:
        """Render every camera: one ``{output: tensor}`` dict per camera (see the module doc)."""
        check_outputs(outputs)
        views = []
        for index in range(len(cameras)):
            view = self.render_one(cameras, index, outputs)
            views.append({name: view[name] for name in outputs})
        return views

    def evaluate(self) -> dict[str, Any]:
        """PSNR (mean of per-view PSNR) and SSIM on the run's held-out views."""
        _, heldout = training_and_heldout(self.scene)
        if not len(heldout):
            raise PointfieldError(f"{self.path}: trained with --holdout-every 0, so it has no held-out views to score; "
                                  "its training PSNR is in metrics.json")
        # Not median depth: nothing scores it, and with gsplat it costs a second pass.
        render = partial(self.render, outputs=("rgb", "depth", "opacity"))
        scores, _ = heldout_scores(render, self.scene, heldout)
        return {"run": str(self.path), "model": self.model_name, **scores}

    def render_path(
        self,
        path: str = "orbit",
        *,
        frames: int | None = None,
        out: str | os.PathLike[str] = "render.gif",
        scene: str | os.PathLike[str] | None = None,
        downscale: int = 1,
        outputs: Sequence[str] = PANELS,
        progress: bool = True,
    ) -> dict[str, Any]:
        """Render a camera ``path`` (orbit, spiral, dataset: :mod:`pointfield.scenes.paths`) into ``out``.

        ``out`` ending in ``.gif`` / ``.mp4`` gets a video of panels, one per output (colour |
        depth | opacity unless ``outputs`` says otherwise), anything else a folder of PNGs, with
        depth maps as ``.npy`` and 16-bit PNG files too (:func:`pointfield.viz.views.write_views`).
        The path goes round the training scene unless ``scene`` (read at ``downscale``) is given.
        ``progress``: a bar over the frames.
        """
        around = self.scene if scene is None else open_scene(scene, downscale)
        return render_path(self.render, around, path, frames=frames, out=out, outputs=outputs, progress=progress)


def render_path(
    render: Callable[[Cameras, Sequence[str]], list[View]], scene: Scene, path: str = "orbit", *,
    frames: int | None = None, out: str | os.PathLike[str] = "render.gif", outputs: Sequence[str] = PANELS,
    progress: bool = True,
) -> dict[str, Any]:
    """Render camera ``path`` around ``scene`` with ``render(cameras, outputs) -> views`` into ``out``.

    What :meth:`SceneRun.render_path` does, for anything that renders cameras (a splat file too).
    Depth and opacity are rendered whatever ``outputs`` says: the pictures' depth range comes
    from them (:func:`~pointfield.scenes.heldout.depth_range`) and fades with opacity. The frames
    are rendered one at a time, so that ``progress`` can show a bar over them.
    """
    from tqdm.auto import tqdm

    out = Path(out)
    if not outputs:
        raise PointfieldError(f"no render outputs asked for; choose from {', '.join(OUTPUTS)}")
    check_outputs(outputs)  # before anything is rendered
    check_views_output(out)
    cameras = path_cameras(scene, path, frames)
    rendered = tuple(dict.fromkeys([*outputs, "depth", "opacity"]))
    views = [as_numpy(render(cameras[index], rendered)[0])
             for index in tqdm(range(len(cameras)), desc="rendering", unit="frame", disable=not progress)]
    near, far = depth_range(scene, views)
    write_views(views, out, near, far, outputs)
    return {"out": str(out), "frames": len(views), "path": path, "outputs": list(outputs)}
