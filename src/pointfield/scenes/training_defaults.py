"""The defaults a new scene run takes from its scene and device: held-out views and image size.

A folder of posed photos (``scene from-images``) has no test split and photos larger than any
model trains well on in minutes. ``nerf train`` and ``splat train`` decide both for the user,
as nerfstudio does, say so at the start, and write what they chose into the run's
``config.json`` (its ``holdout_every`` and ``downscale``, and why, under ``scene_defaults``),
so that ``eval``, ``render`` and a resumed run see the same scene:

- **held-out views**: a scene without a "test" or "val" split holds every
  :data:`HOLDOUT_EVERY`-th view out (nerfstudio's ``eval_mode="fraction"`` of 0.875 keeps the
  same share); ``--holdout-every N`` chooses another stride, ``--holdout-every 0`` trains on
  every view and reports training PSNR only.
- **image size** (``--downscale auto``, the default): the smallest power-of-two factor that
  brings the longest image side to at most :func:`longest_side_for` the device and model --
  1600 on a GPU (nerfstudio's rule), on a CPU :data:`CPU_LONGEST_SIDE` for a radiance field and
  :data:`CPU_SPLAT_LONGEST_SIDE` for splats (docs/photos.md gives the measurements). The factors are those of the ``images_2``, ``images_4``, ``images_8`` folders
  that ``scene from-images`` writes; the images are area-downscaled on load
  (:meth:`~pointfield.scenes.Scene.downscaled`). An explicit ``--downscale N`` wins.
"""

from __future__ import annotations

from typing import Any

import torch

from pointfield.scenes.formats import read_scene
from pointfield.scenes.scene import Scene, SceneError

HOLDOUT_EVERY = 8
"""Every 8th view is held out of a scene that has no test or val split (nerfstudio's default share)."""
CPU_LONGEST_SIDE = 480
"""The longest image side ``--downscale auto`` trains at on a CPU: between the fox's full 1920 px
(21 splat steps in 245 s on 2 cores) and 240 px (26.3 dB held out in 300 s with ngp); a step's
cost follows the pixels (docs/photos.md says why, and what was not measured)."""
CPU_SPLAT_LONGEST_SIDE = 240
"""The longest image side splats train at on a CPU: a splat step rasterizes the whole view, so its
cost follows the pixels (0.63 s a step at 479 x 270 on 2 quiet cores, the fox). At 480 px the
fox's splats scored 23.40 dB held out after 802 steps in nine minutes; at 240 px they reach the
default 3,000 steps in that time (benchmarks/bench_photos.py). A radiance field's step costs the
same at any size (a batch of rays), so it keeps :data:`CPU_LONGEST_SIDE`."""
GPU_LONGEST_SIDE = 1600
"""The longest image side ``--downscale auto`` trains at on a GPU: nerfstudio's rule."""
MAX_FACTOR = 64


def longest_side_for(device: torch.device, task: str = "nerf") -> int:
    """:data:`GPU_LONGEST_SIDE` on CUDA; elsewhere :data:`CPU_SPLAT_LONGEST_SIDE` for ``task`` "splat",
    else :data:`CPU_LONGEST_SIDE`."""
    if torch.device(device).type == "cuda":
        return GPU_LONGEST_SIDE
    return CPU_SPLAT_LONGEST_SIDE if task == "splat" else CPU_LONGEST_SIDE


def auto_downscale(scene: Scene, device: torch.device, task: str = "nerf") -> tuple[int, str]:
    """The power-of-two factor that brings ``scene``'s longest image side to the limit for the device and
    ``task`` ("nerf" or "splat", :func:`longest_side_for`), and why.

    Raises :class:`SceneError` for a scene without images: there is nothing to size.
    """
    where = scene.metadata.get("path", "scene")
    if not any(frame.has_image for frame in scene.frames):
        raise SceneError(f"{where}: --downscale auto sizes the scene's images, and it has none; "
                         "pass --downscale N")
    longest = int(max(int(scene.cameras.width.max()), int(scene.cameras.height.max())))
    limit = longest_side_for(device, task)
    factor = 1
    while longest / factor > limit and factor < MAX_FACTOR:
        factor *= 2
    kind = ("a GPU" if torch.device(device).type == "cuda"
            else "a CPU for splats" if task == "splat" else "a CPU")
    return factor, (f"longest image side {longest} -> {longest // factor} px (auto: at most {limit} px on {kind}; "
                    "--downscale N chooses)")


def has_heldout_split(scene: Scene) -> bool:
    """Whether ``scene`` has a "test" or "val" split with images of its own."""
    return any(scene.frames[int(i)].has_image for name in ("test", "val") for i in scene.splits.get(name, []))


def choose_scene_defaults(config: dict[str, Any], device: torch.device, say: bool = True) -> dict[str, Any]:
    """Settle a new run's ``downscale`` ("auto") and ``holdout_every`` (None) in ``config``, in place.

    Why each was chosen goes into ``config["scene_defaults"]`` (``{setting: reason}``) and, when
    ``say``, is printed with the value, one line each. A config already settled (a resumed run's) is left as it is.
    Returns ``config["scene_defaults"]`` (empty when nothing was left to choose).
    """
    chosen: dict[str, Any] = {}
    undecided = config.get("downscale") == "auto" or config.get("holdout_every") is None
    if undecided and config.get("scene") is not None:
        scene = read_scene(config["scene"])
        if config.get("downscale") == "auto":
            config["downscale"], chosen["downscale"] = auto_downscale(scene, device, config.get("task", "nerf"))
        if config.get("holdout_every") is None and not has_heldout_split(scene):
            config["holdout_every"] = HOLDOUT_EVERY
            chosen["holdout_every"] = (f"no test or val split: every {HOLDOUT_EVERY}th view held out "
                                       "(--holdout-every 0 trains on all of them)")
    elif config.get("downscale") == "auto":  # the built-in cube: sized by --cube-size
        config["downscale"] = 1
    if chosen:
        config["scene_defaults"] = chosen
        if say:
            for name, why in chosen.items():
                print(f"pointfield: --{name.replace('_', '-')} {config[name]}: {why}", flush=True)
    return chosen
