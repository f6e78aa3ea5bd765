"""The fast radiance field: a hash grid, an occupancy grid and packed ray marching (Instant-NGP).

Plain PyTorch, so it runs on any device with no CUDA build; ``--model ngp`` of
``pointfield nerf train``. The pieces, in the order a ray meets them:

1. **Where to look** -- two samplers, chosen per scene (:func:`scene_bounds`):

   - *bounded* scenes (objects in a box, like the NeRF-synthetic ones): an
     :class:`OccupancyGrid` over the box remembers where density has been seen, and
     :func:`march_rays` steps through the box at a fixed ``step_size``, keeping only samples
     in occupied cells (empty space costs nothing but a bit lookup);
   - *unbounded* real captures: positions are contracted into a ball of radius 2
     (mip-NeRF 360) and a :class:`~pointfield.fields.proposal.ProposalSampler` of two small
     density-only hash grids places the samples (nerfacto), trained by the interlevel loss.

2. **Packed samples** (:class:`PackedSamples`): every kept sample is one row of flat tensors
   with the index of its ray, so rays of different lengths cost what they need.

3. **Early ray termination**: a first pass evaluates only density, without gradients, and
   drops the samples behind which a ray has transmittance below ``1e-4``; the full field runs
   on what is left.

4. **The field** (:class:`NGPField`): multiresolution hash encoding -> a 64-wide density MLP
   whose first output is the density (through a truncated exponential) and the other 15 a
   geometry feature -> with the view direction in spherical harmonics (4 bands, 16 values: the
   "degree 4" of tiny-cuda-nn), a 64-wide colour MLP -> sigmoid RGB.

5. **Compositing packed samples** (:func:`composite_packed`): the same emission-absorption sum
   as :mod:`pointfield.fields.rendering`, with each ray's exclusive cumulative optical depth
   taken from one global cumulative sum (in float64, so long batches do not lose precision).

The number of rays per training step adapts so that each step processes about
``target_samples`` samples, as instant-ngp does: few rays while the occupancy grid is still
full, many once empty space is skipped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from pointfield.compiling import CompiledOrEager
from pointfield.fields.hashgrid import HashEncoding
from pointfield.fields.rendering import RenderedRays
from pointfield.splats.sh import sh_basis

DIRECTION_SH_DEGREE = 3  # bands l = 0..3: 16 values, tiny-cuda-nn's "degree 4"
GEOMETRY_FEATURES = 15
EARLY_STOP_TRANSMITTANCE = 1e-4
PROBE_COST = 0.25
"""Cost of a sample evaluated for density only (the early-termination pass, the proposal
networks), relative to one through the whole field with gradients: it counts towards the
per-step sample budget at this weight."""
UNBOUNDED_FAR = 1e3
"""Unbounded scenes are sampled out to this many radii of the region of interest."""
OPAQUE_OPTICAL_DEPTH = 800.0
"""Packed transmittance clamps each sample's optical depth to this: ``exp(-800)`` is 0 even in float64."""


class _TruncatedExp(torch.autograd.Function):
    """``exp(x)`` whose gradient uses ``exp(min(x, 15))``: a density that cannot blow up training."""

    @staticmethod
    def forward(ctx, x):
        ctx.save_for_backward(x)
        return torch.exp(x)

    @staticmethod
    def backward(ctx, grad):
        (x,) = ctx.saved_tensors
        return grad * torch.exp(x.clamp(max=15))


def trunc_exp(x: torch.Tensor) -> torch.Tensor:
    """Truncated exponential (Instant-NGP / nerfacto): ``exp(x)`` forward, gradient clamped at x = 15."""
    return _TruncatedExp.apply(x)


# -- the field -----------------------------------------------------------------------------------


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


# -- where to look: boxes, the occupancy grid, marching ----------------------------------------------


def box_to_unit(positions: torch.Tensor, box: torch.Tensor) -> torch.Tensor:
    """Positions ``(..., 3)`` in the ``(2, 3)`` min/max ``box`` mapped affinely onto ``[0, 1]^3``."""
    return (positions - box[0]) / (box[1] - box[0])


def ray_box_intersection(
    origins: torch.Tensor, directions: torch.Tensor, box: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Distances ``(R,)`` at which rays enter and leave the ``(2, 3)`` box (slab method).

    A ray that misses gets ``enter >= leave``.
    """
    safe = torch.where(directions.abs() < 1e-12, torch.full_like(directions, 1e-12), directions)
    t_low = (box[0] - origins) / safe
    t_high = (box[1] - origins) / safe
    enter = torch.minimum(t_low, t_high).amax(dim=-1)
    leave = torch.maximum(t_low, t_high).amin(dim=-1)
    return enter, leave


class OccupancyGrid(nn.Module):
    """Which cells of a ``resolution^3`` grid over ``box`` hold density: Instant-NGP's skip structure.

    Each cell keeps an exponential moving maximum of the density seen at random points inside
    it, ``density <- max(decay * density, sigma(random point in cell))``, refreshed every
    ``update_every`` steps: all cells during the first ``warmup_steps``, afterwards a random
    ``update_fraction`` of them (so updates stay a small share of training). A cell is occupied
    when its density would make a marching step at least ``occupancy_alpha`` opaque
    (``1 - exp(-density step_size) >= occupancy_alpha``), or exceeds the grid's mean if that is
    lower (so a grid where density is still low everywhere keeps its best cells).
    """

    def __init__(
        self,
        box: torch.Tensor,
        resolution: int = 64,
        decay: float = 0.95,
        occupancy_alpha: float = 0.01,
        update_every: int = 16,
        warmup_steps: int = 256,
        update_fraction: float = 0.25,
    ):
        super().__init__()
        self.resolution = int(resolution)
        self.decay, self.occupancy_alpha = float(decay), float(occupancy_alpha)
        self.update_every, self.warmup_steps = int(update_every), int(warmup_steps)
        self.update_fraction = float(update_fraction)
        self.register_buffer("box", torch.as_tensor(box, dtype=torch.float32).reshape(2, 3).clone())
        cells = self.resolution**3
        self.register_buffer("density", torch.zeros(cells))
        # Everything starts occupied: nothing is known to be empty before the first update.
        self.register_buffer("occupied", torch.ones(cells, dtype=torch.bool))

    @property
    def cells_per_unit(self) -> torch.Tensor:
        """``(3,)`` cells per world unit along each axis: world offsets from ``box[0]`` times this are cell coordinates."""
        return self.resolution / (self.box[1] - self.box[0])

    def occupied_at(self, positions: torch.Tensor) -> torch.Tensor:
        """Boolean ``(...)``: the world point ``(..., 3)`` lies inside the box in an occupied cell."""
        cells = (positions - self.box[0]) * self.cells_per_unit
        inside = ((cells >= 0) & (cells < self.resolution)).all(dim=-1)
        return occupied_in_cells(self.occupied, self.resolution, cells) & inside


    @torch.no_grad()
    def update(self, density_at, step: int, step_size: float, generator: torch.Generator | None = None,
               chunk: int = 1 << 16) -> bool:
        """Refresh the grid at training ``step`` from ``density_at(world positions (N, 3)) -> (N,)``.

        Returns whether this step updated the grid.
        """
        if step % self.update_every:
            return False
        cells = self.resolution**3
        device = self.density.device
        if step < self.warmup_steps:
            chosen = torch.arange(cells, device=device)
        else:
            count = max(1, int(cells * self.update_fraction))
            chosen = torch.randint(cells, (count,), generator=generator).to(device)
        z = chosen % self.resolution
        y = (chosen // self.resolution) % self.resolution
        x = chosen // (self.resolution * self.resolution)
        jitter = torch.rand((chosen.shape[0], 3), generator=generator).to(device)
        unit = (torch.stack([x, y, z], dim=-1).float() + jitter) / self.resolution
        positions = self.box[0] + unit * (self.box[1] - self.box[0])
        fresh = torch.cat([density_at(part) for part in positions.split(chunk)])
        self.density[chosen] = torch.maximum(self.density[chosen] * self.decay, fresh)
        threshold = -math.log1p(-self.occupancy_alpha) / step_size
        self.occupied.copy_(self.density > min(threshold, float(self.density.mean())))
        return True

    @property
    def occupancy(self) -> float:
        """Share of occupied cells."""
        return float(self.occupied.float().mean())


@dataclass
class PackedSamples:
    """S samples of R rays, flat: sample s covers ``[t_starts[s], t_ends[s])`` of ray ``ray_indices[s]``.

    Samples of one ray are contiguous and in increasing t; rays appear in increasing order.
    """

    ray_indices: torch.Tensor
    t_starts: torch.Tensor
    t_ends: torch.Tensor

    def __len__(self) -> int:
        return self.ray_indices.shape[0]

    def select(self, keep: torch.Tensor) -> PackedSamples:
        return PackedSamples(self.ray_indices[keep], self.t_starts[keep], self.t_ends[keep])

    def midpoints(self, origins: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
        """World positions ``(S, 3)`` of the samples' midpoints."""
        t = 0.5 * (self.t_starts + self.t_ends)
        return origins[self.ray_indices] + t[:, None] * directions[self.ray_indices]


def occupied_in_cells(occupied: torch.Tensor, resolution: int, cells: torch.Tensor) -> torch.Tensor:
    """The flat ``resolution^3`` grid ``occupied`` at cell coordinates ``(..., 3)``.

    A point's cell is the integer part of its coordinates, clamped onto the grid.
    """
    index = cells.clamp(0, resolution - 1e-3).long()
    return occupied[(index[..., 0] * resolution + index[..., 1]) * resolution + index[..., 2]]


def occupied_candidates(
    first_cells: torch.Tensor,
    stride_cells: torch.Tensor,
    counts: torch.Tensor,
    steps: torch.Tensor,
    occupied: torch.Tensor,
    resolution: int,
) -> torch.Tensor:
    """Boolean ``(R, K)``: candidate k of ray r exists (``k < counts[r]``) and lies in an occupied cell.

    Candidate k of ray r sits at ``first_cells[r] + k stride_cells[r]`` in cell coordinates
    (``(R, 3)`` each); ``steps`` is ``arange(K)``, K at least ``counts.max()``; ``occupied`` is
    the flat ``resolution^3`` grid. No inside test: every candidate lies between its ray's
    entry and exit, and the clamp only absorbs rounding at the faces. Rays are laid out
    densely, ``(R, K)``, rather than packed: broadcasting then replaces the per-candidate
    gathers of ray data, and the whole test is one expression that ``torch.compile`` fuses.
    """
    cells = torch.addcmul(first_cells[:, None, :], steps[None, :, None].to(first_cells.dtype), stride_cells[:, None, :])
    return occupied_in_cells(occupied, resolution, cells) & (steps[None, :] < counts[:, None])


_FUSED_OCCUPIED_CANDIDATES = CompiledOrEager(occupied_candidates, "the ray marcher's occupancy test")


def march_rays(
    origins: torch.Tensor,
    directions: torch.Tensor,
    near: torch.Tensor,
    far: torch.Tensor,
    grid: OccupancyGrid,
    step_size: float,
    jitter: bool = False,
    generator: torch.Generator | None = None,
    backend: str = "auto",
) -> PackedSamples:
    """Fixed-size steps through the grid's box, keeping those whose midpoint is in an occupied cell.

    Each ray is marched over ``[max(near, box entry), min(far, box exit))`` in steps of
    ``step_size`` (the first step shifted by ``u step_size``, ``u ~ U[0, 1)`` per ray, when
    ``jitter``, so that training sees every depth): ray r has ``ceil(length_r / step_size)``
    candidates, tested by :func:`occupied_candidates` and compacted to the occupied ones.
    ``backend`` (:mod:`~pointfield.compiling`) says whether that test is compiled.
    """
    enter, leave = ray_box_intersection(origins, directions, grid.box)
    start, stop = torch.maximum(enter, near), torch.minimum(leave, far)
    counts = torch.ceil((stop - start).clamp_min(0) / step_size).long()
    longest = int(counts.max()) if counts.numel() else 0
    if longest == 0:
        empty = origins.new_zeros(0)
        return PackedSamples(empty.long(), empty, empty)
    if jitter:
        start = start + torch.rand(origins.shape[0], generator=generator).to(origins.device) * step_size
    to_cells = grid.cells_per_unit
    first_cells = (origins + (start + 0.5 * step_size)[:, None] * directions - grid.box[0]) * to_cells
    stride_cells = step_size * directions * to_cells
    steps = torch.arange(longest, device=origins.device)
    with torch.no_grad():  # a boolean test has no gradient; one grad mode means one compiled kernel
        keep = _FUSED_OCCUPIED_CANDIDATES(backend, origins.device, first_cells, stride_cells, counts, steps,
                                          grid.occupied, grid.resolution)
    rays, k = keep.nonzero(as_tuple=True)
    t_starts = start[rays] + k * step_size
    t_ends = torch.minimum(t_starts + step_size, stop[rays])
    valid = t_ends > t_starts  # the jittered last step can fall past the exit
    return PackedSamples(rays[valid], t_starts[valid], t_ends[valid])


# -- compositing packed samples --------------------------------------------------------------------


def packed_transmittance(optical_depth: torch.Tensor, ray_indices: torch.Tensor) -> torch.Tensor:
    """``T_s = exp(-sum of optical depth of the earlier samples of s's ray)`` for packed samples.

    ``optical_depth`` ``sigma delta`` ``(S,)``, ``ray_indices`` ``(S,)`` non-decreasing. One global
    cumulative sum (float64) minus its value where each ray's run starts.
    """
    if optical_depth.shape[0] == 0:
        return optical_depth
    # Clamping changes no transmittance (exp(-OPAQUE_OPTICAL_DEPTH) is already 0), but keeps one
    # opaque sample (up to inf) from swamping the global sum: the later samples of every later
    # ray would lose their own small terms to it, or get inf - inf = NaN.
    clamped = optical_depth.double().clamp(max=OPAQUE_OPTICAL_DEPTH)
    inclusive = torch.cumsum(clamped, dim=0)
    exclusive = inclusive - clamped
    first = torch.ones_like(ray_indices, dtype=torch.bool)
    first[1:] = ray_indices[1:] != ray_indices[:-1]
    run = torch.cumsum(first.long(), dim=0) - 1  # which run (ray) each sample is in
    base = exclusive[first][run]
    return torch.exp(-(exclusive - base)).to(optical_depth.dtype)


def composite_packed(
    sigmas: torch.Tensor,
    colors: torch.Tensor,
    samples: PackedSamples,
    rays: int,
    background: torch.Tensor | None = None,
) -> RenderedRays:
    """Composite packed ``sigmas`` ``(S,)`` and ``colors`` ``(S, 3)`` into ``rays`` pixels.

    ``w_s = T_s (1 - exp(-sigma_s delta_s))``; ``C_r = sum_{s in r} w_s c_s + (1 - sum w_s) bg``.
    Returns :class:`RenderedRays` with packed ``weights`` ``(S,)`` and sample midpoints ``t``
    ``(S,)`` (rather than ``(R, K)`` blocks).
    """
    deltas = samples.t_ends - samples.t_starts
    optical_depth = sigmas * deltas
    weights = packed_transmittance(optical_depth, samples.ray_indices) * -torch.expm1(-optical_depth)
    t = 0.5 * (samples.t_starts + samples.t_ends)
    index = samples.ray_indices
    opacity = sigmas.new_zeros(rays).index_add(0, index, weights)
    color = sigmas.new_zeros(rays, 3).index_add(0, index, weights[:, None] * colors)
    depth = sigmas.new_zeros(rays).index_add(0, index, weights * t) / opacity.clamp_min(1e-10)
    if background is not None:
        color = color + (1 - opacity)[:, None] * background
    return RenderedRays(color, depth, opacity, weights, t)


# -- the model ---------------------------------------------------------------------------------------


class InstantNGP(nn.Module):
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
    image size (:func:`default_max_resolution`).

    Called like the other NeRF models -- ``model(origins, directions, near, far, background,
    jitter)`` -> ``[RenderedRays]`` -- plus the training hooks :meth:`before_step` (occupancy
    updates), :meth:`rays_for_next_step` and :meth:`auxiliary_loss`.
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
        box = torch.as_tensor(box, dtype=torch.float32).reshape(2, 3)
        if not bool((box[1] > box[0]).all()):
            raise ValueError(f"scene box must have min < max on every axis, got {box.tolist()}")
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
            from pointfield.fields.proposal import ProposalSampler

            self.grid = None
            # Samples linear in distance across the region of interest, then linear in disparity.
            self.proposal = ProposalSampler(proposal_samples=tuple(proposal_samples), final_samples=field_samples,
                                            linear_until=self.radius, backend=backend)
        else:
            self.grid = OccupancyGrid(box, grid_resolution)
            self.proposal = None
        self._rays_next = 1024
        self._step = 0
        self._auxiliary: torch.Tensor | None = None
        self.last_samples = 0  # samples through the whole field in the last forward
        self.last_cost = 0.0  # and its cost in such samples, density-only probes included

    # -- coordinates ---------------------------------------------------------------------------------

    def to_unit(self, positions: torch.Tensor) -> torch.Tensor:
        """World positions -> the field's ``[0, 1]^3`` coordinates (box map or contraction)."""
        if self.unbounded:
            from pointfield.fields.proposal import contract

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
                march_rays(origins, directions, near, far, self.grid, self.step_size, backend=self.backend)
        self.zero_grad(set_to_none=True)

    def before_step(self, step: int, generator: torch.Generator | None = None) -> None:
        """Refresh the occupancy grid (bounded scenes) before training step ``step``."""
        self._step = int(step)
        if self.grid is not None:
            self.grid.update(self.density_at, step, self.step_size, generator)

    def rays_for_next_step(self, smallest: int = 256, largest: int = 1 << 14) -> int:
        """Rays for the next step so that it processes about ``target_samples`` samples."""
        return int(min(max(self._rays_next, smallest), largest))

    def auxiliary_loss(self) -> torch.Tensor | None:
        """The last training forward's extra loss (the proposal networks' interlevel loss), if any."""
        return self._auxiliary

    # -- rendering ----------------------------------------------------------------------------------

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
        if self.unbounded:
            rendered, samples, probed = self._render_unbounded(origins, directions, near, far, background, jitter,
                                                               generator)
        else:
            rendered, samples, probed = self._render_bounded(origins, directions, near, far, background, jitter,
                                                             generator)
        # Samples only probed for density (no gradient, no colour) cost about a quarter.
        self.last_cost = samples + PROBE_COST * probed
        if torch.is_grad_enabled() and self.training:
            rays = origins.shape[0]
            # Keep the next step near target_samples; smoothed so one odd batch does not swing it.
            cost = self.last_cost
            wanted = rays * self.target_samples / max(cost, 1)
            self._rays_next = int(0.5 * self._rays_next + 0.5 * wanted)
        self.last_samples = samples
        return [rendered]

    def _render_bounded(self, origins, directions, near, far, background, jitter, generator):
        samples = march_rays(origins, directions, near, far, self.grid, self.step_size, jitter, generator,
                             self.backend)
        probed = len(samples)
        positions = self.to_unit(samples.midpoints(origins, directions))
        # Early termination: a density-only pass without gradients finds where each ray has
        # become opaque; the samples behind cannot change the pixel and are dropped.
        with torch.no_grad():
            trunk = self.field.trunk(positions)
            sigmas = self.field.density_of(trunk)
            keep = packed_transmittance(sigmas * (samples.t_ends - samples.t_starts),
                                        samples.ray_indices) > EARLY_STOP_TRANSMITTANCE
        samples, positions = samples.select(keep), positions[keep]
        view_directions = directions[samples.ray_indices]
        if torch.is_grad_enabled():  # training: the kept samples again, now with gradients
            sigmas, colors = self.field(positions, view_directions)
        else:  # rendering: the probe's density and features serve; only colour is missing
            sigmas, colors = sigmas[keep], self.field.color(trunk[keep], view_directions)
        return composite_packed(sigmas, colors, samples, origins.shape[0], background), len(samples), probed

    def _render_unbounded(self, origins, directions, near, far, background, jitter, generator):
        from pointfield.fields.proposal import interlevel_loss, proposal_anneal

        # Out to the distance where the contracted space ends (in float32 terms): real captures'
        # backgrounds lie beyond any near/far bound their poses came with.
        far = torch.full_like(far, UNBOUNDED_FAR * self.radius)
        anneal = proposal_anneal(self._step) if self.training else 1.0
        edges, rounds = self.proposal(origins, directions, near, far, self.to_unit, jitter=jitter,
                                      generator=generator, anneal=anneal)
        rays, count = edges.shape[0], edges.shape[1] - 1
        samples = PackedSamples(
            torch.arange(rays, device=edges.device).repeat_interleave(count),
            edges[:, :-1].reshape(-1), edges[:, 1:].reshape(-1),
        )
        positions = self.to_unit(samples.midpoints(origins, directions))
        sigmas, colors = self.field(positions, directions[samples.ray_indices])
        rendered = composite_packed(sigmas, colors, samples, rays, background)
        if torch.is_grad_enabled() and self.training:
            self._auxiliary = interlevel_loss(edges, rendered.weights.reshape(rays, count), rounds)
        probed = sum(round_edges.shape[0] * (round_edges.shape[1] - 1) for round_edges, _ in rounds)
        return rendered, len(samples), probed


# -- choosing the sampler for a scene ------------------------------------------------------------------


def default_max_resolution(scene, unbounded: bool) -> int:
    """The finest hash-grid level for a scene: twice the image's longer side (four times when unbounded).

    Finer than that, a grid cell is smaller than what one pixel sees of the box; the
    contraction keeps the region of interest in the central half of the cube, hence the 4.
    """
    side = int(max(int(scene.cameras.width.max()), int(scene.cameras.height.max())))
    return max(64, (4 if unbounded else 2) * side)


def scene_bounds(scene, scene_box="auto") -> tuple[list[list[float]], bool]:
    """The ``(2, 3)`` box to reconstruct and whether the scene is unbounded, for ``--scene-box``.

    ``scene_box``: "auto" (default), "bounded", "unbounded", or six numbers
    ``min x, y, z, max x, y, z`` (a bounded box). Automatically, a scene whose images have an
    alpha channel is a synthetic object on a transparent background (bounded); real photos are
    unbounded (contracted, proposal sampler). A bounded box is the scene's ``aabb`` if it has
    one, else the central 98 % of its sparse points, else the cube the cameras look into:
    centred where the optical axes pass closest (for a forward-facing capture, whose axes do not
    meet, half-way between the median near and far bounds ahead of the cameras), half as wide as the median camera's view at
    that distance (``distance * tan(fov / 2)``) plus 10 %. For an unbounded scene the box is
    always that last one -- the region of interest that the contraction leaves undistorted --
    since a capture's ``aabb`` (e.g. instant-ngp's ``aabb_scale``) encloses its background too.
    """

    if not isinstance(scene_box, str):
        values = [float(v) for v in scene_box]
        if len(values) != 6:
            raise ValueError(f"--scene-box needs six numbers (min x y z, max x y z), got {len(values)}")
        return [values[:3], values[3:]], False
    if scene_box not in ("auto", "bounded", "unbounded"):
        raise ValueError(f"--scene-box must be auto, bounded, unbounded or six numbers, got {scene_box!r}")
    if scene_box == "auto":
        first = int(scene.splits.get("train", np.arange(len(scene)))[0])
        unbounded = scene.alpha(first) is None
    else:
        unbounded = scene_box == "unbounded"
    if unbounded:
        box = _box_cameras_look_into(scene.cameras, scene.near_far)
    elif scene.aabb is not None:
        box = np.asarray(scene.aabb, dtype=np.float64)
    elif scene.points is not None and len(scene.points):
        box = np.percentile(np.asarray(scene.points.points, dtype=np.float64), [1, 99], axis=0)
    else:
        box = _box_cameras_look_into(scene.cameras, scene.near_far)
    return box.tolist(), unbounded


def _box_cameras_look_into(cameras, near_far=None):

    centers = cameras.centers.double().numpy()
    focus, pinned = cameras.axes_focus()
    if not pinned and near_far is not None:
        # Nearly parallel axes (a forward-facing capture): look half-way between the median
        # near and far bounds ahead of the cameras instead.
        axis = cameras.rotations[:, :, 2].double().numpy().mean(axis=0)
        middle = float(np.median(np.asarray(near_far, dtype=np.float64).mean(axis=1)))
        focus = centers.mean(axis=0) + middle * axis / np.linalg.norm(axis)
    distance = np.median(np.linalg.norm(centers - focus, axis=1))
    half_fov = np.maximum(np.arctan(cameras.width.double().numpy() / (2 * cameras.fx.double().numpy())),
                          np.arctan(cameras.height.double().numpy() / (2 * cameras.fy.double().numpy())))
    half = 1.1 * distance * np.tan(np.median(half_fov))
    return np.stack([focus - half, focus + half])
