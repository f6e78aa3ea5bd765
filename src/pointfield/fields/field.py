"""The contract between radiance-field models and the code that trains and renders them.

Every model (:class:`~pointfield.fields.nerf.TinyNeRF`, :class:`~pointfield.fields.nerf.NeRF`,
:class:`~pointfield.fields.ngp.InstantNGP`) is a :class:`RadianceField`: called on a
:class:`~pointfield.fields.rays.RayBundle`, it returns a :class:`FieldOutput` -- every render
pass, an optional extra loss, and what the call cost. The training loop calls two hooks
(:meth:`RadianceField.before_step`, :meth:`RadianceField.warm_up`) that do nothing unless a model
needs them, and owns a :class:`RayBudget` for models that ask for a sample budget
(``target_samples``) rather than a fixed batch of rays. Nothing else passes between them: no
state left on the model for the loop to find.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from pointfield.fields.rays import RayBundle
from pointfield.fields.rendering import RenderedRays

PROBE_COST = 0.25
"""Cost of a sample evaluated for density only (an early-termination pass, the proposal
networks), relative to one through the whole field with gradients: it counts towards
:attr:`FieldOutput.samples` at this weight."""


@dataclass
class FieldOutput:
    """What a :class:`RadianceField` gives for a batch of rays.

    ``passes``: every render pass, the final one last (NeRF: ``[coarse, fine]``); training puts
    a colour loss on each. ``auxiliary_loss``: a loss to add to training's (e.g. the proposal
    networks' interlevel loss), or None. ``samples``: the call's cost in samples through the
    whole field, density-only probes counted at :data:`PROBE_COST` each (for a :class:`RayBudget`).
    """

    passes: list[RenderedRays]
    auxiliary_loss: torch.Tensor | None = None
    samples: float = 0.0

    @property
    def final(self) -> RenderedRays:
        """The last pass: the render."""
        return self.passes[-1]


class RadianceField(nn.Module):
    """Base of the NeRF models: ``model(rays, background, jitter, generator) -> FieldOutput``.

    ``target_samples``: None for a fixed batch of rays per training step; a number asks the
    training loop to draw as many rays as keep a step near that many samples (a :class:`RayBudget`).
    """

    target_samples: int | None = None

    def before_step(self, step: int, generator: torch.Generator | None) -> None:
        """Called by training before step ``step`` (e.g. to refresh an occupancy grid). Default: nothing."""

    def warm_up(self) -> None:
        """Called once before training's clock starts (e.g. to build compiled kernels). Default: nothing."""

    def forward(
        self,
        rays: RayBundle,
        background: torch.Tensor | None = None,
        jitter: bool = False,
        generator: torch.Generator | None = None,
    ) -> FieldOutput:
        """Render ``rays`` over ``background`` (``(3,)`` or ``(R, 3)``; None: black).

        ``jitter``: random sample placement (training); without it renders are repeatable.
        """
        raise NotImplementedError


class RayBudget:
    """How many rays the next training step draws so that it costs about ``target_samples`` samples.

    As instant-ngp does: few rays while empty space is not yet skipped, many once it is. After a
    step of ``rays_used`` rays that cost ``samples_cost`` samples (:attr:`FieldOutput.samples`),
    ``next = next / 2 + rays_used target / max(cost, 1) / 2`` -- smoothed, so that one odd batch
    does not swing it -- starting at 1024 and kept within ``[smallest, largest]``. ``largest``
    defaults to 16,384 rays, or ``target_samples / 4`` where that is more: a GPU asked for
    instant-ngp's 2^18 samples gets the rays to spend them once empty space is skipped (about 5
    samples a ray on lego), where a fixed 16,384 held an H200 to about 82,000 samples a step.

    Example::

        >>> budget = RayBudget(4096)
        >>> budget.rays()
        1024
        >>> budget.update(1024, 8192.0)  # twice the target: halve the rays, half-way
        >>> budget.rays()
        768
    """

    def __init__(self, target_samples: int, smallest: int = 256, largest: int | None = None):
        self.target_samples = int(target_samples)
        self.smallest = int(smallest)
        self.largest = max(1 << 14, self.target_samples // 4) if largest is None else int(largest)
        self._next = 1024

    def rays(self) -> int:
        """Rays for the next step."""
        return int(min(max(self._next, self.smallest), self.largest))

    def update(self, rays_used: int, samples_cost: float) -> None:
        """Record that a step of ``rays_used`` rays cost ``samples_cost`` samples."""
        wanted = rays_used * self.target_samples / max(samples_cost, 1)
        self._next = int(0.5 * self._next + 0.5 * wanted)

    def __repr__(self) -> str:
        return (f"RayBudget(target_samples={self.target_samples}, smallest={self.smallest}, "
                f"largest={self.largest})")


def checked_box(box) -> torch.Tensor:
    """A scene box ``((x0, y0, z0), (x1, y1, z1))`` as float32 ``(2, 3)``; ValueError unless min < max on every axis."""
    box = torch.as_tensor(box, dtype=torch.float32).reshape(2, 3)
    if not bool((box[1] > box[0]).all()):
        raise ValueError(f"scene box must have min < max on every axis, got {box.tolist()}")
    return box


@torch.no_grad()
def render_in_chunks(
    model: RadianceField,
    rays: RayBundle,
    background: torch.Tensor | None = None,
    chunk: int = 4096,
) -> dict[str, torch.Tensor]:
    """The final pass's ``"rgb"`` ``(R, 3)``, ``"depth"``, ``"median_depth"`` and ``"opacity"`` ``(R,)``.

    Renders ``chunk`` rays at a time without gradients and without jitter, so memory stays
    bounded and the result is repeatable. ``median_depth`` is
    :attr:`~pointfield.fields.rendering.RenderedRays.median_depth`.
    """
    parts: dict[str, list[torch.Tensor]] = {"rgb": [], "depth": [], "median_depth": [], "opacity": []}
    for start in range(0, len(rays), chunk):
        rendered = model(rays[start:start + chunk], background).final
        parts["rgb"].append(rendered.color)
        parts["depth"].append(rendered.depth)
        parts["median_depth"].append(rendered.median_depth)
        parts["opacity"].append(rendered.opacity)
    return {name: torch.cat(values) for name, values in parts.items()}
