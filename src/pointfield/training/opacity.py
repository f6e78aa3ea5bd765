"""Random backgrounds behind the transparent pixels of training images, so that opacity is learnt.

A scene image with alpha ``a``, composited on the scene's background ``B`` (:meth:`Scene.image`),
is ``c = rgb a + B (1 - a)``. Trained only against ``c``, a model may render a surface the colour
of ``B`` as transparent at no cost (white parts of an object on a white background come out
half-transparent), and faint haze in empty space costs little. With a fresh random colour ``b``
behind each ray (fields, as Instant-NGP does) or each image (splats) at every step, the target

    c' = c + (b - B)(1 - a) = rgb a + b (1 - a)

and the render composited on ``b`` agree only where the model's opacity is ``a``. Evaluation and
rendering keep the scene's background. It applies where the images have alpha: objects on a
transparent background (NeRF-synthetic, ``scene make``); photos without alpha train as before.
"""

from __future__ import annotations

import numpy as np
import torch

from pointfield.scenes.scene import Scene


def transparency_of(scene: Scene, frames) -> torch.Tensor | None:
    """``(sum of H W,)`` float32 ``1 - alpha`` of every pixel of ``frames`` (row-major, frame after frame),
    or None when the images have no alpha."""
    alphas = [scene.alpha(int(index)) for index in frames]
    if any(alpha is None for alpha in alphas):
        return None
    return torch.from_numpy(np.concatenate([1 - alpha.reshape(-1) for alpha in alphas]).astype(np.float32))


def uses_random_background(setting: bool | None, scene: Scene, frames) -> bool:
    """``setting`` if given, else whether the training images have alpha ("auto")."""
    if setting is not None:
        return bool(setting)
    return len(frames) > 0 and scene.alpha(int(frames[0])) is not None


def recomposite(colors: torch.Tensor, transparency: torch.Tensor, scene_background: torch.Tensor,
                background: torch.Tensor) -> torch.Tensor:
    """Colours ``(..., 3)`` composited on ``scene_background`` moved onto ``background`` (module docstring).

    ``transparency`` is ``1 - alpha``, shaped like ``colors`` without the last axis.
    """
    return colors + (background - scene_background) * transparency[..., None]
