"""The fast radiance field: a hash-grid field and the sampler its scene needs (Instant-NGP).

Plain PyTorch, so it runs on any device with no CUDA build; ``--model ngp`` of
``pointfield nerf train``. The pieces, in the order a ray meets them:

1. **Where to look** -- two samplers, chosen per scene
   (:func:`~pointfield.fields.scene_box.scene_bounds`):

   - *bounded* scenes (objects in a box, like the NeRF-synthetic ones): an
     :class:`~pointfield.fields.sampling.occupancy.OccupancyGrid` over the box remembers where
     density has been seen, and :func:`~pointfield.fields.sampling.occupancy.march_rays` steps
     through the box at a fixed ``step_size``, keeping only samples in occupied cells, packed
     (rays of different lengths cost what they need);
   - *unbounded* real captures: positions are contracted into a ball of radius 2
     (mip-NeRF 360, :func:`~pointfield.fields.encodings.contraction.contract`) and a
     :class:`~pointfield.fields.sampling.proposal.ProposalSampler` of two small density-only
     hash grids places the samples (nerfacto), trained by the interlevel loss.

2. **Early ray termination** (bounded scenes): a first pass evaluates only density, without
   gradients, and drops the samples behind which a ray has transmittance below
   ``EARLY_STOP_TRANSMITTANCE``; the full field runs on what is left.

3. **The field** (:class:`NGPField`): multiresolution hash encoding -> a 64-wide density MLP
   whose first output is the density (through a truncated exponential) and the other 15 a
   geometry feature -> with the view direction in spherical harmonics (4 bands, 16 values: the
   "degree 4" of tiny-cuda-nn), a 64-wide colour MLP -> sigmoid RGB.

4. **Compositing** the packed samples: :func:`~pointfield.fields.rendering.composite`.

Training draws as many rays per step as keep it near ``target_samples`` samples, as instant-ngp
does (a :class:`~pointfield.fields.field.RayBudget`): few rays while the occupancy grid is still
full, many once empty space is skipped.
"""

from __future__ import annotations

import math

import torch
from torch import nn
from torch.nn import functional as F

from pointfield.fields.activations import trunc_exp
from pointfield.fields.encodings.contraction import box_to_unit, contract
from pointfield.fields.encodings.hashgrid import HashEncoding
from pointfield.fields.encodings.spherical_harmonics import sh_basis
from pointfield.fields.field import PROBE_COST, FieldOutput, RadianceField, checked_box
from pointfield.fields.rays import RayBundle, RaySamples, SceneExtent
from pointfield.fields.rendering import composite, render_rays, transmittance_from_optical_depth
from pointfield.fields.sampling.occupancy import OccupancyGrid, march_rays
from pointfield.fields.sampling.proposal import ProposalSampler, interlevel_loss, proposal_anneal

DIRECTION_SH_DEGREE = 3  # bands l = 0..3: 16 values, tiny-cuda-nn's "degree 4"
GEOMETRY_FEATURES = 15
EARLY_STOP_TRANSMITTANCE = 1e-4

CUDA_OPTIONS = {"levels": 16, "features_per_level": 2, "log2_table_size": 19, "steps_across_box": 1024,
                "grid_resolution": 128, "target_samples": 1 << 18}
"""The instant-ngp paper's hash grid and marching (16 levels of 2 features, a 2^19 table, 1,024
steps across the box, a 128^3 occupancy grid, 2^18 samples a step), which ``nerf train`` uses on
CUDA devices, with the steps no finer than a quarter of a pixel
(:func:`~pointfield.fields.scene_box.steps_a_pixel_allows`). A GPU pays per byte, not per random
access (see :class:`InstantNGP`): on one H100, lego at 800 x 800 reached 35.3 dB held out after
115 s of training and 36.4 dB after 233 s with these, where the CPU's defaults stopped at 31.2
dB (benchmarks/previous-runs.md, "The GPU leases", third lease)."""


class NGPField(nn.Module):
    """Hash-grid radiance field on unit-cube coordinates: ``(u (N, 3), d (N, 3)) -> (sigma (N,), rgb (N, 3))``.

    ``u`` are positions already mapped into ``[0, 1]^3`` (by the box or by the contraction);
    ``d`` unit view directions. Hash-grid options: ``levels``, ``features_per_level``,
    ``log2_table_size``, ``min_resolution``, ``max_resolution``, ``backend``. Density is
    ``trunc_exp(x + density_offset)`` of the density MLP's first output x, in inverse world units.
    """

    def __init__(
        self,
        levels: int = 16,
        features_per_level: int = 2,
        log2_table_size: int = 19,
        min_resolution: int = 16,
        max_resolution: int = 2048,
        hidden: int = 64,
        backend: str = "auto",
        density_offset: float = -1.0,
    ):
        super().__init__()
        self.density_offset = float(density_offset)
        self.encoding = HashEncoding(
            levels, features_per_level, log2_table_size, min_resolution, max_resolution, backend=backend
        )
        self.density_mlp = nn.Sequential(
            nn.Linear(self.encoding.output_dim, hidden), nn.ReLU(), nn.Linear(hidden, 1 + GEOMETRY_FEATURES)
        )
        direction_dim = (DIRECTION_SH_DEGREE + 1) ** 2
        self.color_mlp = nn.Sequential(
            nn.Linear(direction_dim + GEOMETRY_FEATURES, hidden), nn.ReLU(),
            nn.Linear(hidden, hidden), nn.ReLU(),
            nn.Linear(hidden, 3),
        )

    def trunk(self, unit_positions: torch.Tensor) -> torch.Tensor:
        """The density MLP's output ``(N, 16)``: density (before activation), then geometry features."""
        return self.density_mlp(self.encoding(unit_positions))

    def density_of(self, trunk: torch.Tensor) -> torch.Tensor:
        """Density ``(N,)`` from :meth:`trunk`'s output."""
        # exp(x + offset): with the MLP's output near 0 at first, the offset sets the untrained
        # field's density (nerfacto's -1 for scenes scaled to about a unit ball).
        return trunc_exp(trunk[..., 0] + self.density_offset)

    def density(self, unit_positions: torch.Tensor) -> torch.Tensor:
        """Density ``sigma >= 0`` at ``(N, 3)`` unit-cube positions: ``(N,)``."""
        return self.density_of(self.trunk(unit_positions))

    def color(self, trunk: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
        """RGB ``(N, 3)`` from the density MLP's output ``trunk`` ``(N, 16)`` and unit ``directions``."""
        view = sh_basis(directions, DIRECTION_SH_DEGREE)
        return torch.sigmoid(self.color_mlp(torch.cat([view, trunk[..., 1:]], dim=-1)))

    def forward(self, unit_positions: torch.Tensor, directions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        trunk = self.trunk(unit_positions)
        return self.density_of(trunk), self.color(trunk, directions)


class InstantNGP(RadianceField):
    """The ``ngp`` model: :class:`NGPField` with the sampler its scene needs (module docstring).

    ``box``: ``(2, 3)`` world min/max of the region to reconstruct. ``unbounded``: contract
    space around the box instead of marching through it (real captures). ``steps_across_box``:
    the marching step is the box diagonal over this. ``target_samples``: samples per training
    step that the ray count adapts to. ``initial_optical_depth``: the untrained field's density
    times the box side (bounded scenes; unbounded ones start at nerfacto's ``exp(x - 1)``). The
    remaining options go to :class:`NGPField`.

    The hash-grid defaults differ from the paper's (16 levels of 2 features, 2^19 entries,
    N_max 2048) because a CPU pays per random memory access, not per byte: 8 levels of 4
    features give the same 32 inputs to the MLP for half the gathers and scatters, and a 2^17
    table stays closer to the caches. ``pointfield nerf train`` sets ``max_resolution`` from the
    image size (:func:`~pointfield.fields.scene_box.default_max_resolution`), and on CUDA devices
    the paper's grid (:data:`CUDA_OPTIONS`).

    A :class:`~pointfield.fields.field.RadianceField`: one render pass; the proposal networks'
    interlevel loss as the auxiliary loss (unbounded scenes, training); hooks
    :meth:`before_step` (occupancy updates, the proposal anneal) and :meth:`warm_up`.
    """

    def __init__(
        self,
        box=((-1.5, -1.5, -1.5), (1.5, 1.5, 1.5)),
        unbounded: bool = False,
        steps_across_box: int = 256,
        grid_resolution: int = 64,
        target_samples: int = 1 << 16,
        levels: int = 8,
        features_per_level: int = 4,
        log2_table_size: int = 17,
        min_resolution: int = 16,
        max_resolution: int = 512,
        hidden: int = 64,
        backend: str = "auto",
        proposal_samples: tuple[int, ...] = (128, 64),
        field_samples: int = 48,
        initial_optical_depth: float = 1.2,
    ):
        super().__init__()
        box = checked_box(box)
        self.register_buffer("box", box.clone())
        self.unbounded = bool(unbounded)
        self.backend = backend  # of the fused kernels: hash encodings and the marcher's occupancy test
        self.target_samples = int(target_samples)
        self.step_size = float(torch.linalg.norm(box[1] - box[0])) / float(steps_across_box)
        self.radius = 0.5 * float(torch.linalg.norm(box[1] - box[0]))  # of the ball the contraction keeps
        if unbounded:
            density_offset = -1.0  # nerfacto's, for its contracted space
        else:
            # Scale-free start: an untrained field is equally thick across any box (by default
            # 1 - e^-1.2, about 70 % opaque). Too thin a start lets the colour MLP saturate
            # before density forms, and the run never recovers.
            side = float((box[1] - box[0]).mean())
            density_offset = math.log(initial_optical_depth / side)
        self.field = NGPField(levels, features_per_level, log2_table_size, min_resolution, max_resolution,
                              hidden, backend, density_offset)
        if self.unbounded:
            self.grid = None
            # Samples linear in distance across the region of interest, then linear in disparity.
            self.proposal = ProposalSampler(proposal_samples=tuple(proposal_samples), final_samples=field_samples,
                                            linear_until=self.radius, backend=backend)
        else:
            self.grid = OccupancyGrid(box, grid_resolution)
            self.proposal = None
        self._anneal = proposal_anneal(0)  # the proposal weights' exponent; before_step advances it

    @property
    def extent(self) -> SceneExtent:
        """The region this field covers, which bounds every ray rendered through it (:class:`SceneExtent`)."""
        return SceneExtent(self.box.tolist(), self.unbounded)

    # -- coordinates ---------------------------------------------------------------------------------

    def to_unit(self, positions: torch.Tensor) -> torch.Tensor:
        """World positions -> the field's ``[0, 1]^3`` coordinates (box map or contraction)."""
        if self.unbounded:
            return contract(positions, 0.5 * (self.box[0] + self.box[1]), self.radius)
        return box_to_unit(positions, self.box)

    def density_at(self, positions: torch.Tensor) -> torch.Tensor:
        """Density at world ``positions`` ``(N, 3)``: ``(N,)``."""
        return self.field.density(self.to_unit(positions))

    # -- training hooks ---------------------------------------------------------------------------

    def warm_up(self, samples: int = 4096) -> None:
        """Run every network once, with and without gradients, so lazily compiled kernels are built.

        ``torch.compile`` builds the hash-grid kernels and the marcher's occupancy test on first
        use (seconds, or tens of seconds without a disk cache); doing it here keeps that
        one-time cost out of the training clock. Leaves parameters and gradients as they were.
        """
        device = self.box.device
        generator = torch.Generator().manual_seed(0)
        unit = torch.rand((samples, 3), generator=generator).to(device)
        directions = F.normalize(torch.randn((samples, 3), generator=generator), dim=-1).to(device)
        encoders = [self.field.encoding] + ([] if self.proposal is None else
                                            [network.encoding for network in self.proposal.proposal_networks])
        for encoder in encoders:
            with torch.no_grad():
                encoder(unit)
            encoder(unit).sum().backward()
        with torch.no_grad():
            self.field(unit, directions)
            if self.grid is not None:  # rays through the box's centre, from outside it
                origins = self.box.mean(dim=0) - 2 * self.radius * directions
                near, far = torch.zeros(samples, device=device), torch.full((samples,), 4 * self.radius, device=device)
                march_rays(RayBundle(origins, directions, near, far), self.grid, self.step_size,
                           backend=self.backend)
        self.zero_grad(set_to_none=True)

    def before_step(self, step: int, generator: torch.Generator | None = None) -> None:
        """Before training step ``step``: refresh the occupancy grid (bounded), advance the proposal anneal."""
        self._anneal = proposal_anneal(int(step))
        if self.grid is not None:
            self.grid.update(self.density_at, step, self.step_size, generator)

    # -- rendering ----------------------------------------------------------------------------------

    def forward(
        self,
        rays: RayBundle,
        background: torch.Tensor | None = None,
        jitter: bool = False,
        generator: torch.Generator | None = None,
    ) -> FieldOutput:
        """Render ``rays``: one pass; ``samples`` counts density-only probes at ``PROBE_COST``."""
        if self.unbounded:
            return self._render_unbounded(rays, background, jitter, generator)
        return self._render_bounded(rays, background, jitter, generator)

    def _unit_field(self, positions: torch.Tensor, directions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The field on world positions: ``(sigma, rgb)``."""
        return self.field(self.to_unit(positions), directions)

    def _render_bounded(self, rays, background, jitter, generator) -> FieldOutput:
        samples = march_rays(rays, self.grid, self.step_size, jitter, generator, self.backend)
        probed = len(samples)
        positions = self.to_unit(samples.positions(rays))
        # Early termination: a density-only pass without gradients finds where each ray has
        # become opaque; the samples behind cannot change the pixel and are dropped.
        with torch.no_grad():
            trunk = self.field.trunk(positions)
            sigmas = self.field.density_of(trunk)
            keep = transmittance_from_optical_depth(sigmas * samples.deltas,
                                                    samples.ray_indices) > EARLY_STOP_TRANSMITTANCE
        samples, positions = samples.select(keep), positions[keep]
        view_directions = samples.view_directions(rays)
        if torch.is_grad_enabled():  # training: the kept samples again, now with gradients
            sigmas, colors = self.field(positions, view_directions)
        else:  # rendering: the probe's density and features serve; only colour is missing
            sigmas, colors = sigmas[keep], self.field.color(trunk[keep], view_directions)
        rendered = composite(sigmas, colors, samples, background)
        return FieldOutput([rendered], samples=len(samples) + PROBE_COST * probed)

    def _render_unbounded(self, rays, background, jitter, generator) -> FieldOutput:
        # The rays' own near and far: SceneExtent.near_far of this model's extent runs them from
        # the near plane to where the contracted space ends.
        anneal = self._anneal if self.training else 1.0
        edges, rounds = self.proposal(rays, self.to_unit, jitter=jitter, generator=generator, anneal=anneal)
        samples = RaySamples.from_bin_edges(edges).packed()
        rendered = render_rays(self._unit_field, rays, samples, background)
        auxiliary = None
        if torch.is_grad_enabled() and self.training:
            auxiliary = interlevel_loss(edges, rendered.weights.reshape(edges.shape[0], -1), rounds)
        probed = sum(round_edges.shape[0] * (round_edges.shape[1] - 1) for round_edges, _ in rounds)
        return FieldOutput([rendered], auxiliary, len(samples) + PROBE_COST * probed)
