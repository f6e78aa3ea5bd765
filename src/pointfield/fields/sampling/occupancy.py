"""Empty-space skipping for bounded scenes: Instant-NGP's occupancy grid and ray marcher.

An :class:`OccupancyGrid` over the scene box remembers where density has been seen;
:func:`march_rays` steps through the box at a fixed ``step_size`` and keeps only the steps
whose midpoint lies in an occupied cell, as packed :class:`~pointfield.fields.rays.RaySamples`
(empty space costs nothing but a bit lookup). The occupancy test of every candidate step is one
dense expression (:func:`occupied_candidates`) that :mod:`~pointfield.compiling` may fuse.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from pointfield.compiling import CompiledOrEager
from pointfield.fields.rays import RayBundle, RaySamples, ray_box_intersection


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
    rays: RayBundle,
    grid: OccupancyGrid,
    step_size: float,
    jitter: bool = False,
    generator: torch.Generator | None = None,
    backend: str = "auto",
) -> RaySamples:
    """Fixed-size steps through the grid's box, keeping those whose midpoint is in an occupied cell.

    Returns packed samples (``num_rays = len(rays)``). Each ray is marched over
    ``[max(near, box entry), min(far, box exit))`` in steps of
    ``step_size`` (the first step shifted by ``u step_size``, ``u ~ U[0, 1)`` per ray, when
    ``jitter``, so that training sees every depth): ray r has ``ceil(length_r / step_size)``
    candidates, tested by :func:`occupied_candidates` and compacted to the occupied ones.
    ``backend`` (:mod:`~pointfield.compiling`) says whether that test is compiled.
    """
    origins, directions = rays.origins, rays.directions
    enter, leave = ray_box_intersection(origins, directions, grid.box)
    start, stop = torch.maximum(enter, rays.near), torch.minimum(leave, rays.far)
    counts = torch.ceil((stop - start).clamp_min(0) / step_size).long()
    longest = int(counts.max()) if counts.numel() else 0
    if longest == 0:
        empty = origins.new_zeros(0)
        return RaySamples(empty, empty, empty.long(), len(rays))
    if jitter:
        start = start + torch.rand(origins.shape[0], generator=generator).to(origins.device) * step_size
    to_cells = grid.cells_per_unit
    first_cells = (origins + (start + 0.5 * step_size)[:, None] * directions - grid.box[0]) * to_cells
    stride_cells = step_size * directions * to_cells
    steps = torch.arange(longest, device=origins.device)
    with torch.no_grad():  # a boolean test has no gradient; one grad mode means one compiled kernel
        keep = _FUSED_OCCUPIED_CANDIDATES(backend, origins.device, first_cells, stride_cells, counts, steps,
                                          grid.occupied, grid.resolution)
    ray_indices, k = keep.nonzero(as_tuple=True)
    t_starts = start[ray_indices] + k * step_size
    t_ends = torch.minimum(t_starts + step_size, stop[ray_indices])
    valid = t_ends > t_starts  # the jittered last step can fall past the exit
    return RaySamples(t_starts[valid], t_ends[valid], ray_indices[valid], len(rays))
