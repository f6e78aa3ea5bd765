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

Both are radiance fields (:class:`~pointfield.fields.field.RadianceField`): called on a
:class:`~pointfield.fields.rays.RayBundle`, they return a
:class:`~pointfield.fields.field.FieldOutput` with one
:class:`~pointfield.fields.rendering.RenderedRays` per pass (coarse first, the final render
last); training adds a photometric loss per pass.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

from pointfield.fields.encodings.fourier import DIRECTION_FREQUENCIES, POSITION_FREQUENCIES, PositionalEncoding
from pointfield.fields.field import FieldOutput, RadianceField
from pointfield.fields.rays import RayBundle, RaySamples
from pointfield.fields.rendering import render_rays
from pointfield.fields.sampling.stratified import hierarchical_samples, stratified_samples


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


class TinyNeRF(RadianceField):
    """The lesson's TinyNeRF: a 4 x 128 field rendered with ``samples`` stratified samples per ray."""

    def __init__(self, samples: int = 64):
        super().__init__()
        self.samples = int(samples)
        self.field = RadianceMLP(depth=4, width=128, skips=(), color_width=64)

    def forward(
        self,
        rays: RayBundle,
        background: torch.Tensor | None = None,
        jitter: bool = False,
        generator: torch.Generator | None = None,
    ) -> FieldOutput:
        """Render ``rays``: one pass."""
        t = stratified_samples(rays.near, rays.far, self.samples, jitter=jitter, generator=generator)
        samples = RaySamples.from_points(t, rays.far)
        return FieldOutput([render_rays(self.field, rays, samples, background)], samples=len(samples))


class NeRF(RadianceField):
    """NeRF: coarse and fine 8 x 256 fields with a skip, hierarchical sampling between them."""

    def __init__(self, coarse_samples: int = 64, fine_samples: int = 128):
        super().__init__()
        self.coarse_samples = int(coarse_samples)
        self.fine_samples = int(fine_samples)
        self.coarse = RadianceMLP(depth=8, width=256, skips=(4,), color_width=128)
        self.fine = RadianceMLP(depth=8, width=256, skips=(4,), color_width=128)

    def forward(
        self,
        rays: RayBundle,
        background: torch.Tensor | None = None,
        jitter: bool = False,
        generator: torch.Generator | None = None,
    ) -> FieldOutput:
        """Render ``rays``: passes ``[coarse, fine]``."""
        t_coarse = stratified_samples(rays.near, rays.far, self.coarse_samples, jitter=jitter, generator=generator)
        coarse_samples = RaySamples.from_points(t_coarse, rays.far)
        coarse = render_rays(self.coarse, rays, coarse_samples, background)
        t_fine = hierarchical_samples(
            t_coarse, coarse.weights, rays.near, rays.far, self.fine_samples, jitter=jitter, generator=generator
        )
        fine_samples = RaySamples.from_points(t_fine, rays.far)
        fine = render_rays(self.fine, rays, fine_samples, background)
        return FieldOutput([coarse, fine], samples=len(coarse_samples) + len(fine_samples))
