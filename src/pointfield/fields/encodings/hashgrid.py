"""Multi-resolution hash encoding (Müller et al. 2022, "Instant Neural Graphics Primitives").

A point ``x`` in the unit cube ``[0, 1]^3`` is encoded by L grids of trainable feature vectors,
one per level, with resolutions growing geometrically::

    N_l = floor(N_min * b^l),   b = exp((ln N_max - ln N_min) / (L - 1)),   l = 0 .. L-1

On level l the point falls in the cell of the grid of ``N_l`` cells per side whose corner
``i = floor(x N_l)``; its feature is the trilinear interpolation of the ``F`` features stored
at the cell's 8 vertices (vertex coordinates in ``0 .. N_l``). The encoding is the L features
concatenated: ``(N, L * F)``.

Each level stores at most ``T = 2^log2_table_size`` vectors. A vertex ``(x, y, z)`` is found by

- **direct indexing** on the coarse levels whose grid fits: ``x + S y + S^2 z`` with ``S`` the
  next power of two >= ``N_l + 1`` (collision-free; the power of two wastes a little memory but
  makes the index the bitwise XOR ``x ^ S y ^ S^2 z``, the same formula as hashing);
- **spatial hashing** on the others: ``(x * 1 ^ y * 2654435761 ^ z * 805459861) mod T``
  (the paper's XOR of coordinate-times-prime; T a power of two, so ``mod`` is a bit mask).

So every level computes ``(x p_0 ^ y p_1 ^ z p_2) & mask`` with its own ``p`` and ``mask``: one
vectorised formula for all levels. Products wrap modulo 2^32 as in the CUDA original (only the
low ``log2_table_size`` <= 24 bits survive the mask, and those do not depend on whether the
product is taken in 32 or 64 bits).

Implementations of one encoding, tested against each other (values and gradients):

- :func:`hash_encode` -- the vectorised formula: per corner, all levels and points at once
  (level-major ``(L, N)`` so that each level's gather stays inside its slice of the table).
  :class:`HashEncoding` runs it through ``torch.compile`` where a compiler is available.
- :class:`_HashGridFunction` -- the same forward eagerly, with a hand-written backward that
  scatters ``w * dL/dfeature`` into the table (positions get no gradient: they are not
  optimised); the fallback without a compiler.
- :func:`reference_hash_encoding` -- slow and obviously correct: a Python loop over levels and
  the 8 corners, the textbook index formulas, ordinary indexing and autograd.

On a CPU the gather and, above all, the gradient scatter dominate: ``L * 8`` random reads and
writes per point. benchmarks/bench_hashgrid.py measures each implementation.
"""

from __future__ import annotations

import itertools
import math

import torch
from torch import nn

from pointfield.compiling import BACKENDS, CompiledOrEager

PRIMES = (1, 2654435761, 805459861)
"""The paper's per-axis primes; the x prime is 1 for cache coherence along x."""

def level_resolutions(levels: int, min_resolution: int, max_resolution: int) -> list[int]:
    """``N_l = floor(N_min b^l)`` with ``b = (N_max / N_min)^(1 / (L - 1))`` for ``l < levels``."""
    if levels < 1 or min_resolution < 1 or max_resolution < min_resolution:
        raise ValueError(
            f"need levels >= 1 and 1 <= min_resolution <= max_resolution, got {levels}, "
            f"{min_resolution}, {max_resolution}"
        )
    if levels == 1:
        return [int(min_resolution)]
    growth = math.exp((math.log(max_resolution) - math.log(min_resolution)) / (levels - 1))
    # A hair of tolerance so that e.g. 16 * 2^(k) does not floor to 2^(k+4) - 1.
    return [int(math.floor(min_resolution * growth**level + 1e-6)) for level in range(levels)]


def level_layout(resolutions: list[int], log2_table_size: int) -> list[tuple[int, tuple[int, int, int], int]]:
    """Per level ``(table entries, (p_0, p_1, p_2), mask)``: direct indexing where it fits, else hashing."""
    table_size = 1 << log2_table_size
    layout = []
    for resolution in resolutions:
        side = 1 << math.ceil(math.log2(resolution + 1))  # power of two >= vertices per side
        if side**3 <= table_size:
            layout.append((side**3, (1, side, side * side), side**3 - 1))
        else:
            layout.append((table_size, PRIMES, table_size - 1))
    return layout


class HashEncoding(nn.Module):
    """Instant-NGP's multiresolution hash encoding: ``(N, 3)`` in ``[0, 1]^3`` -> ``(N, L F)``.

    ``levels`` L, ``features_per_level`` F, ``log2_table_size`` T (at most 2^T vectors per
    level), resolutions from ``min_resolution`` to ``max_resolution`` (see the module
    docstring). Features start uniform in ``[-1e-4, 1e-4]`` as in the paper. Points outside the
    unit cube are clamped onto it.

    ``backend``: "compiled" runs :func:`hash_encode` through ``torch.compile``, which fuses the
    index arithmetic, the gather and (in backward) the scatter into one loop each instead of a
    dozen passes over ``(L, N)`` temporaries; it needs a C++ compiler (CPU) or Triton (CUDA) and
    compiles once (10-40 s, then cached on disk). "eager" is the hand-written
    :class:`_HashGridFunction`. Which is faster depends on the table: the compiled backward
    scatters with atomic adds, which win on cache-sized tables and lose on the paper's 2^19
    entries (benchmarks/bench_hashgrid.py measures both). "auto" (default) compiles where a
    compiler is available and falls back to eager, with a warning, if compilation fails.

    Positions that need a gradient (the SDF field's normals, whose eikonal term is
    differentiated again) take plain autograd through :func:`hash_encode`, eagerly, whatever the
    backend: the hand-written backward gives positions none, and compiled graphs have no double
    backward.
    """

    def __init__(
        self,
        levels: int = 16,
        features_per_level: int = 2,
        log2_table_size: int = 19,
        min_resolution: int = 16,
        max_resolution: int = 2048,
        backend: str = "auto",
    ):
        super().__init__()
        if not 1 <= log2_table_size <= 24:
            raise ValueError(f"log2_table_size must be in 1..24, got {log2_table_size}")
        if features_per_level < 1:
            raise ValueError(f"features_per_level must be >= 1, got {features_per_level}")
        if backend not in BACKENDS:
            raise ValueError(f"unknown hash-grid backend {backend!r}; choose one of {', '.join(BACKENDS)}")
        self.levels = int(levels)
        self.features_per_level = int(features_per_level)
        self.log2_table_size = int(log2_table_size)
        self.backend = backend
        self.resolutions = level_resolutions(levels, min_resolution, max_resolution)
        layout = level_layout(self.resolutions, log2_table_size)
        self.level_sizes = [size for size, _, _ in layout]
        offsets = [0] + list(itertools.accumulate(self.level_sizes))[:-1]
        self.register_buffer("_resolution", torch.tensor(self.resolutions, dtype=torch.float32), persistent=False)
        self.register_buffer("_primes", torch.tensor([p for _, p, _ in layout], dtype=torch.int64), persistent=False)
        self.register_buffer("_mask", torch.tensor([m for _, _, m in layout], dtype=torch.int64), persistent=False)
        self.register_buffer("_offset", torch.tensor(offsets, dtype=torch.int64), persistent=False)
        self.table = nn.Parameter(torch.empty(sum(self.level_sizes), self.features_per_level).uniform_(-1e-4, 1e-4))

    @property
    def output_dim(self) -> int:
        return self.levels * self.features_per_level

    def forward(self, positions: torch.Tensor) -> torch.Tensor:
        """Encode ``positions`` ``(..., 3)`` in ``[0, 1]^3``: ``(..., L F)``."""
        shape = positions.shape[:-1]
        flat = positions.reshape(-1, 3).to(self.table.dtype)
        arguments = (flat, self.table, self._resolution.to(self.table.dtype), self._primes, self._mask, self._offset)
        if torch.is_grad_enabled() and flat.requires_grad:
            # A gradient with respect to the positions (an SDF's normals and eikonal term, which
            # differentiate it again): plain autograd through the formula, eagerly. The
            # hand-written backward gives positions none, and torch.compile has no double backward.
            return hash_encode(*arguments).permute(1, 0, 2).reshape(*shape, self.output_dim)
        # Without a backward to come there is nothing to keep: the plain formula serves eagerly.
        eager = _HashGridFunction.apply if torch.is_grad_enabled() and self.table.requires_grad else hash_encode
        if flat.shape[0] == 0:
            features = eager(*arguments)
        else:
            features = _FUSED_HASH_ENCODE(self.backend, flat.device, *arguments, eager=eager)
        return features.permute(1, 0, 2).reshape(*shape, self.output_dim)


def _corners(positions, resolution, primes, mask, offset):
    """Yield, for each of the 8 cell corners, table rows ``(L, N)`` and trilinear weights ``(L, N)``.

    ``positions`` ``(N, 3)``; per-level ``resolution`` ``(L,)`` float, ``primes`` ``(L, 3)``,
    ``mask`` and ``offset`` ``(L,)`` int64. Corner ``(dx, dy, dz)`` of the cell with lower
    vertex ``i = floor(x N_l)`` is vertex ``i + (dx, dy, dz)``, weighted by
    ``prod_axis (f if d else 1 - f)`` with ``f = x N_l - i``.
    """
    scaled = positions.clamp(0, 1).T[None] * resolution[:, None, None]  # (L, 3, N)
    cell = torch.minimum(scaled.floor(), resolution[:, None, None] - 1).clamp_min(0)
    upper_weight = scaled - cell
    lower_weight = 1 - upper_weight
    lower = cell.to(torch.int64) * primes[:, :, None]  # vertex coordinate times prime, per axis
    upper = lower + primes[:, :, None]  # (i + 1) p = i p + p
    for dx in (0, 1):
        x_term, x_weight = (upper if dx else lower)[:, 0], (upper_weight if dx else lower_weight)[:, 0]
        for dy in (0, 1):
            xy_term = x_term ^ (upper if dy else lower)[:, 1]
            xy_weight = x_weight * (upper_weight if dy else lower_weight)[:, 1]
            for dz in (0, 1):
                rows = ((xy_term ^ (upper if dz else lower)[:, 2]) & mask[:, None]) + offset[:, None]
                yield rows, xy_weight * (upper_weight if dz else lower_weight)[:, 2]


def hash_encode(positions, table, resolution, primes, mask, offset) -> torch.Tensor:
    """Level-major features ``(L, N, F)``: ``sum_corners weight * table[row]`` (autograd-friendly).

    The form ``torch.compile`` fuses; see :func:`_corners` for the arguments.
    """
    levels, count = resolution.shape[0], positions.shape[0]
    features = table.new_zeros(levels, count, table.shape[1])
    for rows, weights in _corners(positions, resolution, primes, mask, offset):
        features = features + weights[..., None] * table[rows]
    return features


class _HashGridFunction(torch.autograd.Function):
    """Eager :func:`hash_encode` with a hand-written backward that scatters into the table.

    Forward gathers each corner's rows with ``index_select`` and keeps rows and weights;
    backward adds ``weight * dL/dfeature`` into a zero table with ``index_add_`` (int64 rows:
    int32 ones take a much slower path). Autograd through ``table[rows]`` would instead sort
    the indices for a deterministic ``index_put``, several times slower on a CPU.
    """

    @staticmethod
    def forward(ctx, positions, table, resolution, primes, mask, offset):
        levels, count, width = resolution.shape[0], positions.shape[0], table.shape[1]
        features = table.new_zeros(levels, count, width)
        saved_rows, saved_weights = [], []
        for rows, weights in _corners(positions, resolution, primes, mask, offset):
            gathered = table.index_select(0, rows.reshape(-1)).view(levels, count, width)
            features.addcmul_(weights[..., None], gathered)
            saved_rows.append(rows)
            saved_weights.append(weights)
        ctx.save_for_backward(torch.stack(saved_rows), torch.stack(saved_weights))
        ctx.table_shape = table.shape
        return features

    @staticmethod
    def backward(ctx, grad_features):
        rows, weights = ctx.saved_tensors  # (8, L, N) each
        grad_table = grad_features.new_zeros(ctx.table_shape)
        for corner in range(8):
            contribution = (weights[corner][..., None] * grad_features).reshape(-1, ctx.table_shape[1])
            grad_table.index_add_(0, rows[corner].reshape(-1), contribution)
        return None, grad_table, None, None, None, None


_FUSED_HASH_ENCODE = CompiledOrEager(hash_encode, "the hash encoding")


def reference_hash_encoding(encoding: HashEncoding, positions: torch.Tensor) -> torch.Tensor:
    """The encoding computed the slow, obvious way: loops over levels and corners, autograd.

    Same result as ``encoding(positions)`` for ``(N, 3)`` points in ``[0, 1]^3``; gradients reach
    ``encoding.table`` through plain indexing.
    """
    table_size = 1 << encoding.log2_table_size
    outputs = []
    start = 0
    for resolution, size in zip(encoding.resolutions, encoding.level_sizes):
        level_table = encoding.table[start : start + size]
        start += size
        scaled = positions.clamp(0, 1).to(encoding.table.dtype) * resolution
        cell = scaled.floor().clamp(0, resolution - 1)
        fraction = scaled - cell
        cell = cell.long()
        side = 1 << math.ceil(math.log2(resolution + 1))
        direct = side**3 <= table_size
        level_feature = 0
        for dx in (0, 1):
            for dy in (0, 1):
                for dz in (0, 1):
                    x, y, z = cell[:, 0] + dx, cell[:, 1] + dy, cell[:, 2] + dz
                    if direct:
                        row = x + side * y + side * side * z
                    else:
                        row = ((x * PRIMES[0]) ^ (y * PRIMES[1]) ^ (z * PRIMES[2])) % table_size
                    weight = (
                        (fraction[:, 0] if dx else 1 - fraction[:, 0])
                        * (fraction[:, 1] if dy else 1 - fraction[:, 1])
                        * (fraction[:, 2] if dz else 1 - fraction[:, 2])
                    )
                    level_feature = level_feature + weight[:, None] * level_table[row]
        outputs.append(level_feature)
    return torch.cat(outputs, dim=-1)
