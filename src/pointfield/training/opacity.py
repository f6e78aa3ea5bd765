"""Training opacity, not only colour, on images with alpha: random backgrounds, or an alpha loss.

A scene image with alpha ``a``, composited on the scene's background ``B`` (:meth:`Scene.image`),
is ``c = rgb a + B (1 - a)``. Trained only against ``c``, a model may render a surface the colour
of ``B`` as transparent at no cost (white parts of an object on a white background come out
half-transparent), and faint haze in empty space costs little. Two cures:

- **random backgrounds** (fields, by default), trained in expectation. Instant-NGP draws a fresh
  random colour ``b``, uniform in [0, 1], behind each ray at every step and composites the target
  on it too; only a render whose opacity ``A`` is ``a`` then matches every ``b``. With the
  premultiplied colours ``C`` (render) and ``C*`` (image), the squared error of one channel is
  ``(C - C* + b (a - A))^2``, whose mean over backgrounds of mean ``m`` and variance ``v`` is

      (C + m (1 - A) - C* - m (1 - a))^2 + v (A - a)^2,

  the error over the constant background ``m`` plus ``v`` times the squared opacity error. For
  Instant-NGP's draw, ``m = 1/2`` and ``v = 1/12``. pointfield computes this mean exactly: the
  render and the target over grey (:func:`recomposite`), plus :func:`random_background_loss`;
  the same objective as drawn colours, without their sampling noise;
- **the alpha loss** (splats, by default, weight :data:`DEFAULT_ALPHA_LOSS`; fields when asked):
  ``weight * mean |rendered opacity - a|`` over the step's rays or pixels added to the loss.

Why random backgrounds for fields (and why in expectation, over grey), and the alpha loss for
splats, with the figures and the commands that measured them: docs/geometry.md, "Opacity, not
only colour". Evaluation and rendering keep the scene's background. Photos without alpha train
on colour alone.
"""

from __future__ import annotations

import torch

from pointfield.scenes.scene import Scene

DEFAULT_ALPHA_LOSS = 0.1
"""Weight of ``mean |rendered opacity - alpha|`` where the images have alpha (``--alpha-loss``)."""

BACKGROUND_MEAN = 0.5
"""Per-channel mean of the random backgrounds: that of a colour uniform in [0, 1]."""

BACKGROUND_VARIANCE = 1 / 12
"""Per-channel variance of the random backgrounds: that of a colour uniform in [0, 1]."""


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


def random_background_loss(opacity: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """``BACKGROUND_VARIANCE * mean (opacity - alpha)^2``: what random backgrounds add, in expectation,
    to the mean squared colour error over :data:`BACKGROUND_MEAN` (module docstring).

    ``opacity`` and ``alpha`` are shaped alike (one value per ray or pixel).
    """
    return BACKGROUND_VARIANCE * torch.mean((opacity - alpha) ** 2)


def recomposite(colors: torch.Tensor, transparency: torch.Tensor, scene_background: torch.Tensor,
                background: torch.Tensor) -> torch.Tensor:
    """Colours ``(..., 3)`` composited on ``scene_background`` moved onto ``background`` (module docstring).

    ``transparency`` is ``1 - alpha``, shaped like ``colors`` without the last axis.
    """
    return colors + (background - scene_background) * transparency[..., None]
