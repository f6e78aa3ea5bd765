"""NeRF models: TinyNeRF (the lesson's small MLP) and NeRF (Mildenhall et al. 2020).

Both are built from one field, :class:`RadianceMLP`, the network of the paper's figure 7::

    gamma(x) (63) -> [Linear(width) + ReLU] x depth   (gamma(x) concatenated again after the
                  |                                     layers listed in ``skips``)
                  +-> Linear(1) -> softplus                  = density sigma >= 0
                  +-> Linear(width) -> concat gamma(d) (27) -> Linear(color_width) + ReLU
                                                          -> Linear(3) -> sigmoid = colour in [0, 1]

so density depends on position only and colour on position and view direction.

- :class:`TinyNeRF`: depth 4, width 128, colour head 64 wide, no skip; one pass of
  ``samples`` stratified samples per ray (64).
- :class:`NeRF`: depth 8, width 256, skip after layer 4, colour head 128 wide; a *coarse*
  network on 64 stratified samples and a *fine* network on those plus 128 samples drawn from
  the coarse weights (hierarchical sampling); both are trained, the fine one renders.

Density uses softplus rather than the paper's ReLU (as mip-NeRF does): a ReLU that starts
negative everywhere has zero gradient and never recovers, which small CPU runs hit.

Calling a model on rays returns a list of :class:`~pointfield.fields.rendering.RenderedRays`,
one per pass (coarse first, the final render last); training adds a photometric loss per pass.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import nn
from torch.nn import functional as F

from pointfield.fields.encodings import DIRECTION_FREQUENCIES, POSITION_FREQUENCIES, PositionalEncoding
from pointfield.fields.rendering import RenderedRays, render_rays
from pointfield.fields.sampling import hierarchical_samples, stratified_samples


class RadianceMLP(nn.Module):
    """A NeRF field: ``(positions (..., 3), unit directions (..., 3)) -> (sigma (...), rgb (..., 3))``."""

    def __init__(
        self,
        depth: int = 8,
        width: int = 256,
        skips: tuple[int, ...] = (4,),
        color_width: int = 128,
        position_frequencies: int = POSITION_FREQUENCIES,
        direction_frequencies: int = DIRECTION_FREQUENCIES,
    ):
        super().__init__()
        self.encode_position = PositionalEncoding(position_frequencies)
        self.encode_direction = PositionalEncoding(direction_frequencies)
        self.skips = tuple(skips)
        position_dim = self.encode_position.output_dim(3)
        direction_dim = self.encode_direction.output_dim(3)
        layers = []
        for index in range(depth):
            in_dim = position_dim if index == 0 else width
            if index in {skip + 1 for skip in self.skips}:
                in_dim += position_dim  # the skip: gamma(x) again after layer ``skip``
            layers.append(nn.Linear(in_dim, width))
        self.trunk = nn.ModuleList(layers)
        self.density_head = nn.Linear(width, 1)
        self.feature = nn.Linear(width, width)
        self.color_hidden = nn.Linear(width + direction_dim, color_width)
        self.color_head = nn.Linear(color_width, 3)

    def forward(self, positions: torch.Tensor, directions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        encoded = self.encode_position(positions)
        hidden = encoded
        for index, layer in enumerate(self.trunk):
            if index in {skip + 1 for skip in self.skips}:
                hidden = torch.cat([hidden, encoded], dim=-1)
            hidden = F.relu(layer(hidden))
        sigma = F.softplus(self.density_head(hidden)[..., 0])
        features = torch.cat([self.feature(hidden), self.encode_direction(directions)], dim=-1)
        rgb = torch.sigmoid(self.color_head(F.relu(self.color_hidden(features))))
        return sigma, rgb


class TinyNeRF(nn.Module):
    """The lesson's TinyNeRF: a 4 x 128 field rendered with ``samples`` stratified samples per ray."""

    def __init__(self, samples: int = 64):
        super().__init__()
        self.samples = int(samples)
        self.field = RadianceMLP(depth=4, width=128, skips=(), color_width=64)

    def forward(
        self,
        origins: torch.Tensor,
        directions: torch.Tensor,
        near: torch.Tensor,
        far: torch.Tensor,
        background: torch.Tensor | None = None,
        jitter: bool = False,
        generator: torch.Generator | None = None,
    ) -> list[RenderedRays]:
        """Render rays ``(R, 3)`` between ``near`` and ``far`` ``(R,)``: a one-element list."""
        t = stratified_samples(near, far, self.samples, jitter=jitter, generator=generator)
        return [render_rays(self.field, origins, directions, t, far, background)]


class NeRF(nn.Module):
    """NeRF: coarse and fine 8 x 256 fields with a skip, hierarchical sampling between them."""

    def __init__(self, coarse_samples: int = 64, fine_samples: int = 128):
        super().__init__()
        self.coarse_samples = int(coarse_samples)
        self.fine_samples = int(fine_samples)
        self.coarse = RadianceMLP(depth=8, width=256, skips=(4,), color_width=128)
        self.fine = RadianceMLP(depth=8, width=256, skips=(4,), color_width=128)

    def forward(
        self,
        origins: torch.Tensor,
        directions: torch.Tensor,
        near: torch.Tensor,
        far: torch.Tensor,
        background: torch.Tensor | None = None,
        jitter: bool = False,
        generator: torch.Generator | None = None,
    ) -> list[RenderedRays]:
        """Render rays ``(R, 3)`` between ``near`` and ``far`` ``(R,)``: ``[coarse, fine]``."""
        t_coarse = stratified_samples(near, far, self.coarse_samples, jitter=jitter, generator=generator)
        coarse = render_rays(self.coarse, origins, directions, t_coarse, far, background)
        t_fine = hierarchical_samples(
            t_coarse, coarse.weights, near, far, self.fine_samples, jitter=jitter, generator=generator
        )
        fine = render_rays(self.fine, origins, directions, t_fine, far, background)
        return [coarse, fine]


def _instant_ngp(**options: Any) -> nn.Module:
    from pointfield.fields.ngp import InstantNGP

    return InstantNGP(**options)


MODELS: dict[str, Any] = {"tiny": TinyNeRF, "nerf": NeRF, "ngp": _instant_ngp}
"""``--model`` name -> class."""


def build_model(name: str, **options: Any) -> nn.Module:
    """The model called ``name`` ("tiny", "nerf" or "ngp"), with constructor ``options``."""
    if name not in MODELS:
        raise ValueError(f"unknown NeRF model {name!r}; choose one of {', '.join(MODELS)}")
    return MODELS[name](**options)


@torch.no_grad()
def render_in_chunks(
    model: nn.Module,
    origins: torch.Tensor,
    directions: torch.Tensor,
    near: torch.Tensor,
    far: torch.Tensor,
    background: torch.Tensor | None = None,
    chunk: int = 4096,
) -> dict[str, torch.Tensor]:
    """The final pass's ``color`` ``(R, 3)``, ``depth`` ``(R,)``, ``opacity`` ``(R,)`` for many rays.

    Renders ``chunk`` rays at a time without gradients and without jitter, so memory stays
    bounded and the result is repeatable.
    """
    parts: dict[str, list[torch.Tensor]] = {"color": [], "depth": [], "opacity": []}
    for start in range(0, origins.shape[0], chunk):
        end = start + chunk
        rendered = model(origins[start:end], directions[start:end], near[start:end], far[start:end], background)[-1]
        parts["color"].append(rendered.color)
        parts["depth"].append(rendered.depth)
        parts["opacity"].append(rendered.opacity)
    return {name: torch.cat(values) for name, values in parts.items()}
