"""Point Transformer V3 (Wu et al., CVPR 2024): attention in patches of a space-filling-curve order.

PTv3 drops the neighbour searches of earlier point transformers. The cloud is voxelised; its
voxels are *serialized* (sorted along a space-filling curve, so that neighbours in the order are
mostly neighbours in space); attention runs inside fixed-size patches of that order; and each
block uses another curve, so that what a patch cannot see in one block it sees in the next::

    points (N, 3 + C) ─ Linear ─ pool into voxels of side ``voxel``           level 0 (M0 voxels)
      ─ stage 0: blocks ─ grid pool (stride 2) ─ stage 1 ─ pool ─ stage 2 ─ pool ─ stage 3
      ─ unpool + skip ─ decoder stage 2 ─ unpool ─ decoder 1 ─ unpool ─ decoder 0
      ─ unpool to the points + their own embedding ─ Linear ─> scores (N, classes)

    block(x) = x + xCPE(x);  x = x + Attention_patch(LN(x));  x = x + MLP(LN(x))

where xCPE, the conditional position encoding, is a 3x3x3 sparse convolution over the voxel's
27 neighbours, a Linear and a LayerNorm. Everything is on packed voxels of the whole batch — a
``(M, C)`` feature matrix with each voxel's cloud index — held by :class:`Voxels`, one per
level, as Pointcept's ``Point`` dict carries a level through the network.

Sizes (the defaults, kept small enough to train on two CPU cores):

==========  =========  =========  =====  ======  ===========================================
level       voxel      channels   heads  blocks  in the unit-ball crops of a 2 m, 5 cm recipe
==========  =========  =========  =====  ======  ===========================================
0           s          32 / 64    2 / 4  1 / 1   s = 0.025 (the data's own 5 cm grid)
1           2 s        64 / 64    4 / 4  1 / 1
2           4 s        128 / 128  8 / 8  2 / 1
3           8 s        256        16     1
==========  =========  =========  =====  ======  ===========================================

(encoder / decoder; head dimension 16 everywhere, MLP ratio 4, patches of 64 voxels.) Pointcept's
PTv3 has five stages of (32, 64, 128, 256, 512) channels, (2, 2, 2, 6, 2) blocks and patches
of 1024; on a CPU that is hours per epoch. What else differs, and why:

- the input is voxelised inside the model (points sharing a voxel are max-pooled into it and
  each gets its own score back through the last unpooling, from its own embedding), because
  augmentation turns and scales the crops off the data's grid, and prediction must give every
  point its own label;
- LayerNorm everywhere (Pointcept: BatchNorm in the stem, pooling and unpooling), so that a
  cloud's scores do not depend on the other clouds of its batch and evaluation equals training;
- the stem is a Linear and a 3x3x3 sparse convolution, not a 5x5x5 one (125 neighbours);
- the serialization orders are shuffled only in training (Pointcept shuffles at every call):
  evaluation is deterministic, and a shuffled scan gets the same labels;
- the curve cycles over every block of the network, not within each stage, since one-block
  stages would otherwise all use the first curve;
- no flash attention: :func:`torch.nn.functional.scaled_dot_product_attention` picks the best
  kernel the device has.

Conventions. Grid coordinates are non-negative int64, at most :data:`MAX_COORDINATE` per axis
(16 bits: a crop may span 65,536 voxels); keys pack ``(cloud, x, y, z)`` into one int64.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, field

import torch
import torch.nn.functional as F
from torch import nn

from pointfield.errors import PointfieldError

ORDERS = ("z", "z-trans", "hilbert", "hilbert-trans")
DEPTH = 16  # bits per axis of the curves' codes; fixed, so a cloud's order does not depend on its batch
MAX_COORDINATE = (1 << DEPTH) - 1
# Neighbour keys shift coordinates by 1 (so that -1 is representable): 17 bits per axis.
_AXIS_BITS = DEPTH + 1
NEIGHBOUR_OFFSETS = torch.tensor(list(itertools.product((-1, 0, 1), repeat=3)), dtype=torch.int64)  # (27, 3)


# ---------------------------------------------------------------------------------------------
# Serialization: space-filling curves on integer grid coordinates
# ---------------------------------------------------------------------------------------------


def z_order_code(grid: torch.Tensor, depth: int = DEPTH) -> torch.Tensor:
    """Morton codes of ``grid`` (M, 3) int64: the bits of x, y, z interleaved, x's the highest.

    ``code = Σ_b (x_b << 3b+2) | (y_b << 3b+1) | (z_b << 3b)`` over bits b < depth.

        >>> z_order_code(torch.tensor([[0, 0, 1], [0, 1, 0], [1, 0, 0], [1, 1, 1]])).tolist()
        [1, 2, 4, 7]
    """
    code = torch.zeros(len(grid), dtype=torch.int64, device=grid.device)
    for bit in range(depth):
        for axis in range(3):
            code |= ((grid[:, axis] >> bit) & 1) << (3 * bit + 2 - axis)
    return code


def hilbert_code(grid: torch.Tensor, depth: int = DEPTH) -> torch.Tensor:
    """Hilbert-curve codes of ``grid`` (M, 3) int64 on a ``2^depth`` cube: cells with consecutive
    codes share a face.

    Skilling's algorithm ("Programming the Hilbert curve", 2004), vectorised over the cells:
    undo the curve's rotations and reflections level by level, Gray-code the result, then
    interleave the bits as :func:`z_order_code` does.

        >>> cube = torch.tensor(list(itertools.product(range(2), repeat=3)))
        >>> cube[hilbert_code(cube, 1).argsort()].tolist()
        [[0, 0, 0], [0, 0, 1], [0, 1, 1], [0, 1, 0], [1, 1, 0], [1, 1, 1], [1, 0, 1], [1, 0, 0]]
    """
    x = [grid[:, axis].clone() for axis in range(3)]
    q = 1 << (depth - 1)
    while q > 1:  # inverse undo
        p = q - 1
        for axis in range(3):
            high = (x[axis] & q) != 0
            swap = (x[0] ^ x[axis]) & p
            if axis == 0:
                x[0] = torch.where(high, x[0] ^ p, x[0])
            else:
                x[0], x[axis] = torch.where(high, x[0] ^ p, x[0] ^ swap), torch.where(high, x[axis], x[axis] ^ swap)
        q >>= 1
    for axis in (1, 2):  # Gray encode
        x[axis] = x[axis] ^ x[axis - 1]
    flip = torch.zeros_like(x[0])
    q = 1 << (depth - 1)
    while q > 1:
        flip = torch.where((x[2] & q) != 0, flip ^ (q - 1), flip)
        q >>= 1
    return z_order_code(torch.stack([axis ^ flip for axis in x], dim=1), depth)


def serialization_code(grid: torch.Tensor, order: str, depth: int = DEPTH) -> torch.Tensor:
    """``(M,)`` codes of ``grid`` (M, 3) along curve ``order``, one of :data:`ORDERS`; the
    "-trans" variants swap x and y first, so that their patches are elongated the other way."""
    if order not in ORDERS:
        raise PointfieldError(f"unknown serialization order {order!r}: expected one of {', '.join(ORDERS)}")
    if order.endswith("-trans"):
        grid = grid[:, [1, 0, 2]]
    return z_order_code(grid, depth) if order.startswith("z") else hilbert_code(grid, depth)


def serialize(grid: torch.Tensor, batch: torch.Tensor, order: str) -> tuple[torch.Tensor, torch.Tensor]:
    """The serialized order of packed voxels and its inverse: ``(order (M,), inverse (M,))``.

    ``grid`` (M, 3) int64, ``batch`` (M,) the cloud of each voxel. Voxels are sorted by cloud,
    then by curve code: ``grid[order]`` walks each cloud along the curve, and
    ``serialized[inverse]`` puts a serialized tensor back in storage order. Codes of distinct
    voxels differ, so the order does not depend on the order of storage.
    """
    code = (batch << (3 * DEPTH)) | serialization_code(grid, order)
    order_ = torch.argsort(code)
    inverse = torch.empty_like(order_)
    inverse[order_] = torch.arange(len(order_), device=order_.device)
    return order_, inverse


# ---------------------------------------------------------------------------------------------
# Voxel neighbours and the sparse convolution as a gather
# ---------------------------------------------------------------------------------------------


def voxel_keys(grid: torch.Tensor, batch: torch.Tensor) -> torch.Tensor:
    """One int64 per ``(cloud, x, y, z)``, coordinates shifted by 1 so that -1 has a key too."""
    shifted = grid + 1
    return ((batch << (3 * _AXIS_BITS)) | (shifted[..., 0] << (2 * _AXIS_BITS)) | (shifted[..., 1] << _AXIS_BITS)
            | shifted[..., 2])


def voxel_neighbours(grid: torch.Tensor, batch: torch.Tensor) -> torch.Tensor:
    """``(M, 27)`` index of each voxel's neighbour at every offset of :data:`NEIGHBOUR_OFFSETS`
    (x, y, z each in -1, 0, 1; column 13 is the voxel itself), M where the cell is empty.

    The voxels' keys are sorted once; each neighbour's key is then found by binary search
    (``searchsorted``): ``M · 27 · log M`` work, no hash table. Voxels must be distinct.
    """
    keys = voxel_keys(grid, batch)
    sorted_keys, by_key = torch.sort(keys)
    wanted = voxel_keys(grid[:, None, :] + NEIGHBOUR_OFFSETS.to(grid.device), batch[:, None])  # (M, 27)
    position = torch.searchsorted(sorted_keys, wanted).clamp_max(len(keys) - 1)
    found = sorted_keys[position] == wanted
    return torch.where(found, by_key[position], len(keys))


class _GatherNeighbours(torch.autograd.Function):
    """``out[i, k] = x[n(i, k)]`` (0 where the cell is empty), with a backward that gathers too.

    The neighbour relation is symmetric: ``n(i, k) = j`` exactly when ``n(j, 26 - k) = i``
    (offset k negated is offset 26 - k in :data:`NEIGHBOUR_OFFSETS`' order). So the gradient
    ``dx_j = Σ_{(i, k): n(i, k) = j} dout[i, k]`` is ``Σ_k dout[n(j, 26 - k), k]``: a gather
    and a sum, where autograd's own backward of indexing is a scatter-add (``index_put`` with
    accumulation), several times slower on a CPU. :meth:`reference` is the plain indexing.
    """

    @staticmethod
    def forward(ctx, x: torch.Tensor, neighbours: torch.Tensor) -> torch.Tensor:
        ctx.save_for_backward(neighbours)
        return _GatherNeighbours.reference(x, neighbours)

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        (neighbours,) = ctx.saved_tensors
        count = len(neighbours)
        mirrored = neighbours.flip(1)  # column k: the neighbour at offset -k
        found = mirrored < count
        flat = torch.where(found, mirrored * 27 + torch.arange(27, device=grad.device), 0)
        rows = grad.reshape(count * 27, -1).index_select(0, flat.reshape(-1)).view(count, 27, -1)
        # The sum over k, empty cells weighted 0, as one batched product: no (M, 27, C) temporary.
        return torch.bmm(found.to(grad.dtype)[:, None, :], rows)[:, 0], None

    @staticmethod
    def reference(x: torch.Tensor, neighbours: torch.Tensor) -> torch.Tensor:
        padded = torch.cat([x, x.new_zeros(1, x.shape[1])])  # row M: the empty cell
        return padded.index_select(0, neighbours.reshape(-1)).view(*neighbours.shape, x.shape[1])


def gather_neighbours(x: torch.Tensor, neighbours: torch.Tensor) -> torch.Tensor:
    """``(M, 27, C)``: the features ``x`` (M, C) of every voxel's 27 neighbours (0 for empty cells)."""
    return _GatherNeighbours.apply(x, neighbours)


class NeighbourConv(nn.Module):
    """A 3x3x3 submanifold sparse convolution: ``y_i = b + Σ_k W_k x_{n(i, k)}`` over the 27
    neighbour offsets k, empty cells contributing 0; outputs only at the input voxels.

    ``x`` (M, in_channels), ``neighbours`` (M, 27) from :func:`voxel_neighbours` -> (M,
    out_channels). The 27 gathered rows are one ``(M, 27 · C)`` matrix, so the whole
    convolution is a single matrix product (spconv's SubMConv3d, without a compiled kernel).
    """

    def __init__(self, in_channels: int, out_channels: int):
        super().__init__()
        self.linear = nn.Linear(27 * in_channels, out_channels)

    def forward(self, x: torch.Tensor, neighbours: torch.Tensor) -> torch.Tensor:
        return self.linear(gather_neighbours(x, neighbours).reshape(len(x), -1))


# ---------------------------------------------------------------------------------------------
# The structure carried through the network
# ---------------------------------------------------------------------------------------------


@dataclass
class Voxels:
    """One level of the network: packed voxels of every cloud of the batch.

    ``grid`` (M, 3) int64 distinct per cloud, ``batch`` (M,) the cloud of each voxel,
    ``features`` (M, C), ``neighbours`` (M, 27) (:func:`voxel_neighbours`), ``parent`` (M_finer,)
    the voxel of this level holding each voxel (or point) of the finer level, for unpooling.
    Patches of each serialization order are computed when a block first asks for them.
    """

    grid: torch.Tensor
    batch: torch.Tensor
    features: torch.Tensor
    parent: torch.Tensor
    neighbours: torch.Tensor = field(init=False)
    _patches: dict[tuple[str, int], tuple[torch.Tensor, torch.Tensor, torch.Tensor]] = field(
        init=False, default_factory=dict)

    def __post_init__(self):
        self.neighbours = voxel_neighbours(self.grid, self.batch)

    def patches(self, order: str, size: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(index (P·K,), keys (P, K), outputs (P·K,))`` for patches of ``K = size`` voxels.

        ``index`` lists the voxels patch by patch along the curve ``order``; each cloud's last
        patch is filled up, as Pointcept does, with the voxels just before it (a full patch of
        context; their outputs are kept from the patch they belong to). ``keys`` says which
        entries may be attended to: all of them, except in a cloud smaller than one patch, whose
        filling entries are masked. ``outputs`` marks the entries whose result is kept: each
        voxel exactly once.
        """
        if (order, size) not in self._patches:
            self._patches[order, size] = self._make_patches(order, size)
        return self._patches[order, size]

    def _make_patches(self, order: str, size: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        serial, _ = serialize(self.grid, self.batch, order)
        counts = torch.bincount(self.batch)
        counts = counts[counts > 0]
        starts = torch.cumsum(counts, 0) - counts
        padded = (counts + size - 1) // size * size
        cloud = torch.repeat_interleave(torch.arange(len(counts), device=counts.device), padded)
        local = torch.arange(len(cloud), device=counts.device) - (torch.cumsum(padded, 0) - padded)[cloud]
        count = counts[cloud]
        kept = local < count
        small = count < size
        source = torch.where(kept, local, torch.where(small, count - 1, local - size))
        index = serial[starts[cloud] + source]
        keys = (kept | ~small).view(-1, size)
        return index, keys, kept


def grid_pool(
    grid: torch.Tensor, batch: torch.Tensor, features: torch.Tensor, stride: int = 2
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Strided voxel pooling: ``(grid (M', 3), batch (M',), features (M', C), parent (M,))``.

    A child at ``g`` belongs to the parent at ``g // stride`` of its cloud; a parent's feature is
    the channel-wise max over its children (``scatter_reduce`` "amax"). Parents are sorted by
    key, so their order does not depend on the children's.
    """
    coarse = torch.div(grid, stride, rounding_mode="floor")
    unique, parent = torch.unique(voxel_keys(coarse, batch), return_inverse=True)
    pooled = features.new_zeros(len(unique), features.shape[1]).scatter_reduce(
        0, parent[:, None].expand_as(features), features, "amax", include_self=False)
    axis = (1 << _AXIS_BITS) - 1
    decoded = torch.stack([(unique >> (2 * _AXIS_BITS)) & axis, (unique >> _AXIS_BITS) & axis, unique & axis], 1)
    return decoded - 1, unique >> (3 * _AXIS_BITS), pooled, parent


# ---------------------------------------------------------------------------------------------
# Layers
# ---------------------------------------------------------------------------------------------


class DropPath(nn.Module):
    """Stochastic depth: in training, a residual branch is dropped for a whole cloud with
    probability ``rate`` (and kept ones scaled by ``1 / (1 - rate)``)."""

    def __init__(self, rate: float = 0.0):
        super().__init__()
        self.rate = rate

    def forward(self, x: torch.Tensor, batch: torch.Tensor) -> torch.Tensor:
        if not self.training or self.rate == 0.0:
            return x
        keep = torch.rand(int(batch.max()) + 1, device=x.device) >= self.rate
        return x * (keep[batch, None].to(x.dtype) / (1.0 - self.rate))

    def extra_repr(self) -> str:
        return f"rate={self.rate}"


class PatchAttention(nn.Module):
    """Multi-head self-attention within each patch: ``softmax(q kᵀ / √d) v`` over the K voxels
    of a patch, d = channels / heads. ``x`` (M, C) -> (M, C)."""

    def __init__(self, channels: int, heads: int):
        super().__init__()
        if channels % heads:
            raise ValueError(f"{channels} channels do not split into {heads} heads")
        self.heads = heads
        self.qkv = nn.Linear(channels, 3 * channels)
        self.proj = nn.Linear(channels, channels)

    def forward(self, x: torch.Tensor, patches: tuple[torch.Tensor, torch.Tensor, torch.Tensor]) -> torch.Tensor:
        index, keys, kept = patches
        count, size = keys.shape
        qkv = self.qkv(x).index_select(0, index).view(count, size, 3, self.heads, -1).permute(2, 0, 3, 1, 4)  # (3, P, H, K, d)
        out = F.scaled_dot_product_attention(qkv[0], qkv[1], qkv[2], attn_mask=keys[:, None, None, :])
        out = out.transpose(1, 2).reshape(count * size, -1)
        result = torch.empty_like(x).index_copy_(0, index[kept], out[kept])
        return self.proj(result)


class Block(nn.Module):
    """PTv3's block, pre-norm: ``x += xCPE(x)``, ``x += Attention(LN(x))``, ``x += MLP(LN(x))``.

    xCPE is :class:`NeighbourConv` (3x3x3), Linear, LayerNorm; the MLP is Linear ``C -> 4C``,
    GELU, Linear ``4C -> C``.
    """

    def __init__(self, channels: int, heads: int, patch: int, drop_path: float = 0.0, mlp_ratio: int = 4):
        super().__init__()
        self.patch = patch
        self.cpe_conv = NeighbourConv(channels, channels)
        self.cpe = nn.Sequential(nn.Linear(channels, channels), nn.LayerNorm(channels))
        self.norm1, self.norm2 = nn.LayerNorm(channels), nn.LayerNorm(channels)
        self.attention = PatchAttention(channels, heads)
        self.mlp = nn.Sequential(nn.Linear(channels, mlp_ratio * channels), nn.GELU(),
                                 nn.Linear(mlp_ratio * channels, channels))
        self.drop_path = DropPath(drop_path)

    def forward(self, voxels: Voxels, order: str) -> torch.Tensor:
        x = voxels.features
        x = x + self.cpe(self.cpe_conv(x, voxels.neighbours))
        x = x + self.drop_path(self.attention(self.norm1(x), voxels.patches(order, self.patch)), voxels.batch)
        return x + self.drop_path(self.mlp(self.norm2(x)), voxels.batch)


def _linear_norm_gelu(in_channels: int, out_channels: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(in_channels, out_channels), nn.LayerNorm(out_channels), nn.GELU())


class GridPooling(nn.Module):
    """Linear to the coarser width, then :func:`grid_pool` (max over children), LayerNorm, GELU."""

    def __init__(self, in_channels: int, out_channels: int, stride: int = 2):
        super().__init__()
        self.stride = stride
        self.proj = nn.Linear(in_channels, out_channels)
        self.norm = nn.Sequential(nn.LayerNorm(out_channels), nn.GELU())

    def forward(self, voxels: Voxels) -> Voxels:
        grid, batch, pooled, parent = grid_pool(voxels.grid, voxels.batch, self.proj(voxels.features), self.stride)
        return Voxels(grid, batch, self.norm(pooled), parent)


class GridUnpooling(nn.Module):
    """Each finer voxel takes its parent's feature back, plus its own skip feature:
    ``f = LNGELU(W_c c)[parent] + LNGELU(W_s s)`` (Pointcept's SerializedUnpooling)."""

    def __init__(self, coarse_channels: int, skip_channels: int, out_channels: int):
        super().__init__()
        self.proj = _linear_norm_gelu(coarse_channels, out_channels)
        self.proj_skip = _linear_norm_gelu(skip_channels, out_channels)

    def forward(self, coarse: torch.Tensor, parent: torch.Tensor, skip: torch.Tensor) -> torch.Tensor:
        return self.proj(coarse)[parent] + self.proj_skip(skip)


# ---------------------------------------------------------------------------------------------
# The segmenter
# ---------------------------------------------------------------------------------------------


class PTv3Segmenter(nn.Module):
    """Point Transformer V3 for per-point labels: ``(B, N, 3) -> (B, N, num_classes)`` scores.

    ``voxel``: the side of the level-0 voxels, in the units of ``points`` (the scene task sets
    it to the data's grid over the crop radius: crops reach the model in the unit ball).
    ``channels``, ``heads``, ``depths``: per encoder stage; ``decoder_channels``,
    ``decoder_heads``, ``decoder_depths``: per decoder stage, finest first (one fewer than the
    encoder's). ``patch``: voxels per attention patch. ``drop_path``: the largest stochastic
    depth rate, reached linearly by the encoder's last block. ``orders``: the curves, cycled
    over the blocks (and shuffled per step in training). Sizes and their default values are in
    the module doc.
    """

    def __init__(
        self,
        num_classes: int,
        in_channels: int = 0,
        voxel: float = 0.025,
        channels: Sequence[int] = (32, 64, 128, 256),
        heads: Sequence[int] = (2, 4, 8, 16),
        depths: Sequence[int] = (1, 1, 2, 1),
        decoder_channels: Sequence[int] = (64, 64, 128),
        decoder_heads: Sequence[int] = (4, 4, 8),
        decoder_depths: Sequence[int] = (1, 1, 1),
        patch: int = 64,
        drop_path: float = 0.0,
        orders: Sequence[str] = ORDERS,
    ):
        super().__init__()
        stages = len(channels)
        if not len(heads) == len(depths) == stages or not len(decoder_channels) == len(decoder_heads) == len(
                decoder_depths) == stages - 1:
            raise ValueError("PTv3 needs heads and depths per encoder stage, and one decoder stage fewer")
        if not voxel > 0 or patch < 1:
            raise ValueError(f"PTv3 needs a positive voxel and patch size, got {voxel} and {patch}")
        unknown = [o for o in orders if o not in ORDERS]
        if unknown or not orders:
            raise ValueError(f"unknown serialization orders {unknown}: expected some of {', '.join(ORDERS)}")
        self.voxel, self.orders, self.patch = voxel, tuple(orders), patch
        self.embed = _linear_norm_gelu(3 + in_channels, channels[0])
        self.stem = NeighbourConv(channels[0], channels[0])
        self.stem_norm = nn.Sequential(nn.LayerNorm(channels[0]), nn.GELU())
        rates = torch.linspace(0, drop_path, sum(depths)).tolist()
        self.encoder, self.pooling = nn.ModuleList(), nn.ModuleList()
        for stage in range(stages):
            first = sum(depths[:stage])
            self.encoder.append(nn.ModuleList(
                Block(channels[stage], heads[stage], patch, rates[first + i]) for i in range(depths[stage])))
            if stage + 1 < stages:
                self.pooling.append(GridPooling(channels[stage], channels[stage + 1]))
        self.decoder, self.unpooling = nn.ModuleList(), nn.ModuleList()
        for stage in range(stages - 1):
            coarse = channels[-1] if stage == stages - 2 else decoder_channels[stage + 1]
            self.unpooling.append(GridUnpooling(coarse, channels[stage], decoder_channels[stage]))
            self.decoder.append(nn.ModuleList(
                Block(decoder_channels[stage], decoder_heads[stage], patch) for _ in range(decoder_depths[stage])))
        self.to_points = GridUnpooling(decoder_channels[0], channels[0], decoder_channels[0])
        self.head = nn.Linear(decoder_channels[0], num_classes)

    def forward(
        self,
        points: torch.Tensor,
        features: torch.Tensor | None = None,
        mask: torch.Tensor | None = None,
        with_regulariser: bool = False,
    ) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        batch_size, count = points.shape[:2]
        if mask is None:
            mask = torch.ones(batch_size, count, dtype=torch.bool, device=points.device)
        inputs = points if features is None else torch.cat([points, features], dim=-1)
        cloud = torch.arange(batch_size, device=points.device)[:, None].expand(-1, count)[mask]
        embedded = self.embed(inputs[mask])  # (N, C0), the real points packed
        level = self._voxelise(points[mask], cloud, embedded)
        level.features = self.stem_norm(self.stem(level.features, level.neighbours))
        orders = [self.orders[i] for i in torch.randperm(len(self.orders))] if self.training else self.orders
        used = itertools.count()
        levels = []
        for stage, blocks in enumerate(self.encoder):
            if stage:
                level = self.pooling[stage - 1](level)
            for block in blocks:
                level.features = block(level, orders[next(used) % len(orders)])
            levels.append(level)
        features = level.features
        for stage in reversed(range(len(self.decoder))):
            finer = levels[stage]  # its encoder features are the skip, then replaced by the decoder's
            finer.features = self.unpooling[stage](features, levels[stage + 1].parent, finer.features)
            for block in self.decoder[stage]:
                finer.features = block(finer, orders[next(used) % len(orders)])
            features = finer.features
        per_point = self.to_points(features, levels[0].parent, embedded)
        logits = points.new_zeros(batch_size, count, self.head.out_features)
        logits[mask] = self.head(per_point).to(logits.dtype)
        return (logits, points.new_zeros(())) if with_regulariser else logits

    def _voxelise(self, xyz: torch.Tensor, cloud: torch.Tensor, embedded: torch.Tensor) -> Voxels:
        """Level 0: the points' voxels of side ``voxel``, each cloud's corner at grid 0."""
        cell = torch.floor(xyz / self.voxel).to(torch.int64)
        corner = torch.full((int(cloud.max()) + 1, 3), torch.iinfo(torch.int64).max, device=xyz.device)
        corner = corner.scatter_reduce(0, cloud[:, None].expand(-1, 3), cell, "amin")
        cell = cell - corner[cloud]
        if int(cell.max()) > MAX_COORDINATE:
            raise PointfieldError(f"PTv3: a cloud spans {int(cell.max()) + 1} voxels of {self.voxel:g}; at most "
                                  f"{MAX_COORDINATE + 1} fit the serialization codes: use a larger voxel")
        grid, batch, pooled, parent = grid_pool(cell, cloud, embedded, stride=1)
        return Voxels(grid, batch, pooled, parent)
