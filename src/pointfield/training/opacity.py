"""Training opacity, not only colour, on images with alpha: random backgrounds, or an alpha loss.

A scene image with alpha ``a``, composited on the scene's background ``B`` (:meth:`Scene.image`),
is ``c = rgb a + B (1 - a)``. Trained only against ``c``, a model may render a surface the colour
of ``B`` as transparent at no cost (white parts of an object on a white background come out
half-transparent), and faint haze in empty space costs little. Two cures:

- **random backgrounds** (fields, by default; as Instant-NGP does): a fresh random colour ``b``
  behind each ray at every step, with the target moved onto the same colour,

      c' = c + (b - B)(1 - a) = rgb a + b (1 - a),

  so the render composited on ``b`` and the target agree only where the opacity is ``a``;
- **the alpha loss** (splats, by default, weight :data:`DEFAULT_ALPHA_LOSS`; fields when asked):
  ``weight * mean |rendered opacity - a|`` over the step's rays or pixels added to the loss.

Why random backgrounds for fields and the alpha loss for splats, with the figures and the
commands that measured them: docs/geometry.md, "Opacity, not only colour". Evaluation and
rendering keep the scene's background. Photos without alpha train on colour alone.
"""

from __future__ import annotations

import numpy as np
import torch

from pointfield.scenes.scene import Scene

DEFAULT_ALPHA_LOSS = 0.1
"""Weight of ``mean |rendered opacity - alpha|`` where the images have alpha (``--alpha-loss``)."""


def has_alpha(scene: Scene, frames) -> bool:
    """Whether the training images ``frames`` of ``scene`` have alpha."""
    return len(frames) > 0 and scene.alpha(int(frames[0])) is not None


def alpha_loss_weight(setting: float | None, scene: Scene, frames, default: float = DEFAULT_ALPHA_LOSS) -> float:
    """The alpha loss's weight: ``setting`` (None: ``default``) where the training images have alpha, else 0."""
    if not has_alpha(scene, frames):
        return 0.0
    return float(default if setting is None else setting)


def uses_random_background(setting: bool | None, scene: Scene, frames) -> bool:
    """Whether a field trains on random backgrounds: ``setting`` (None: where the images have alpha)."""
    return has_alpha(scene, frames) and (setting is None or bool(setting))


def transparency_of(scene: Scene, frames) -> torch.Tensor | None:
    """``(sum of H W,)`` float32 ``1 - alpha`` of every pixel of ``frames`` (row-major, frame after frame),
    or None when the images have no alpha."""
    alphas = [scene.alpha(int(index)) for index in frames]
    if any(alpha is None for alpha in alphas):
        return None
    return torch.from_numpy(np.concatenate([1 - alpha.reshape(-1) for alpha in alphas]).astype(np.float32))


def recomposite(colors: torch.Tensor, transparency: torch.Tensor, scene_background: torch.Tensor,
                background: torch.Tensor) -> torch.Tensor:
    """Colours ``(..., 3)`` composited on ``scene_background`` moved onto ``background`` (module docstring).

    ``transparency`` is ``1 - alpha``, shaped like ``colors`` without the last axis.
    """
    return colors + (background - scene_background) * transparency[..., None]
