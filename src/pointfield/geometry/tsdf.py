"""Truncated signed distance fusion (Curless and Levoy 1996) of depth maps, in PyTorch, on any device.

A dense grid of voxels over a box, each holding a running weighted mean of its signed distance
to the surfaces the depth maps saw, truncated to ``[-1, 1]`` in units of ``truncation``, and of
their colour. For a voxel at world point ``x`` and a view with z-depth map ``D``:

    (u, v), z = project(x)                      the pixel it falls in and its depth along the axis
    sdf      = D(u, v) - z                      positive in front of the surface, negative behind
    observed = D(u, v) > 0 and sdf >= -truncation    (far behind a surface stays unknown)
    F <- (W F + min(1, sdf / truncation)) / (W + 1),  C <- (W C + c(u, v)) / (W + 1),  W <- W + 1

A pixel with no depth (D = 0: nothing opaque there) observes nothing. Counting it as empty space
would carve floaters, but at a silhouette, where a voxel just inside an object projects onto a
background pixel, it carves the object too (false inner surfaces); a floater is removed anyway by
the views that see the surface behind it (their sdf is positive there). Colour is kept as each
voxel's colour sum and count, ``C = sum / count``.

The surface is the zero level of F (:mod:`pointfield.geometry.meshes` runs marching cubes on it);
voxels no view observed keep F = 1 (empty) and W = 0. The grid is processed in chunks of voxels,
so the only large tensors are the grid's own: 4 + 4 + 16 bytes a voxel (F, W, colour sum and
count, float32), 3.2 GB at 512^3 -- :func:`grid_bytes` says how much before anything is allocated.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from pointfield.errors import PointfieldError
from pointfield.scenes.cameras import Cameras

BYTES_PER_VOXEL = 4 + 4 + 16
CHUNK_VOXELS = 1 << 20


def grid_shape(low, high, resolution: int) -> tuple[tuple[int, int, int], float]:
    """Voxels along x, y, z and the voxel size: cubes, ``resolution`` along the box's longest side."""
    extent = np.asarray(high, np.float64) - np.asarray(low, np.float64)
    if resolution < 2 or np.any(extent <= 0):
        raise PointfieldError(f"a TSDF grid needs a resolution of 2 or more and a box with volume, got {resolution}, {extent}")
    voxel = float(extent.max()) / resolution
    shape = tuple(max(2, math.ceil(e / voxel)) for e in extent)
    return shape, voxel


def grid_bytes(shape) -> int:
    return int(np.prod(shape)) * BYTES_PER_VOXEL


@dataclass
class TSDFVolume:
    """A dense TSDF grid over the box ``low``..``high`` (module docstring); build with :meth:`create`."""

    low: torch.Tensor
    voxel: float
    truncation: float
    tsdf: torch.Tensor
    weight: torch.Tensor
    color_sum: torch.Tensor
    """``(X, Y, Z, 4)``: the colours seen summed, and (last) how many views saw a surface."""

    @classmethod
    def create(cls, low, high, resolution: int, *, truncation_voxels: float = 4.0, device=None,
               memory_limit: int | None = None) -> TSDFVolume:
        """An empty grid; refuses (naming the memory it would need) one larger than ``memory_limit`` bytes."""
        shape, voxel = grid_shape(low, high, resolution)
        needed = grid_bytes(shape)
        if memory_limit is not None and needed > memory_limit:
            fits = int(resolution * (memory_limit / needed) ** (1 / 3))
            raise PointfieldError(
                f"a {resolution}^3 TSDF grid ({shape[0]}x{shape[1]}x{shape[2]} voxels) needs "
                f"{needed / 2**30:.1f} GiB, more than the {memory_limit / 2**30:.1f} GiB allowed; "
                f"pass --resolution {fits} or less, or a smaller --crop box"
            )
        device = torch.device(device or "cpu")
        return cls(
            low=torch.as_tensor(np.asarray(low, np.float64), dtype=torch.float32, device=device),
            voxel=voxel,
            truncation=truncation_voxels * voxel,
            tsdf=torch.ones(shape, device=device),
            weight=torch.zeros(shape, device=device),
            color_sum=torch.zeros(*shape, 4, device=device),
        )

    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(self.tsdf.shape)

    def colors_at(self, points: torch.Tensor) -> torch.Tensor:
        """``(K, 3)`` mean colour of the voxel holding each world point (grey where no view saw one)."""
        index = torch.floor((points.to(self.low) - self.low) / self.voxel).long()
        for axis, size in enumerate(self.shape):
            index[:, axis] = index[:, axis].clamp(0, size - 1)
        summed = self.color_sum[index[:, 0], index[:, 1], index[:, 2]]
        count = summed[:, 3:]
        return torch.where(count > 0, summed[:, :3] / count.clamp_min(1), torch.full_like(summed[:, :3], 0.5))

    def voxel_centres(self, flat_indices: torch.Tensor) -> torch.Tensor:
        """World coordinates ``(K, 3)`` of the voxels with these flat (C-order) indices."""
        _, ny, nz = self.shape
        i = flat_indices // (ny * nz)
        j = (flat_indices // nz) % ny
        k = flat_indices % nz
        return self.low + (torch.stack([i, j, k], dim=-1).float() + 0.5) * self.voxel

    @torch.no_grad()
    def integrate(self, depth: torch.Tensor, rgb: torch.Tensor, cameras: Cameras, index: int) -> None:
        """Fuse one view: z-depth ``(H, W)`` (0 = nothing seen), colour ``(H, W, 3)``, camera ``index``."""
        camera = cameras[[index]].to(self.tsdf.device, torch.float32)
        depth = depth.to(self.tsdf.device, torch.float32)
        rgb = rgb.to(self.tsdf.device, torch.float32)
        height, width = depth.shape
        flat_tsdf, flat_weight = self.tsdf.view(-1), self.weight.view(-1)
        flat_color = self.color_sum.view(-1, 4)
        for start in range(0, flat_tsdf.numel(), CHUNK_VOXELS):
            indices = torch.arange(start, min(start + CHUNK_VOXELS, flat_tsdf.numel()), device=self.tsdf.device)
            pixels, z = camera.project(self.voxel_centres(indices))
            pixels, z = pixels[0], z[0]
            column = torch.floor(pixels[:, 0]).nan_to_num(-1).long()
            row = torch.floor(pixels[:, 1]).nan_to_num(-1).long()
            inside = (column >= 0) & (column < width) & (row >= 0) & (row < height) & (z > 0)
            if not inside.any():
                continue
            indices, column, row, z = indices[inside], column[inside], row[inside], z[inside]
            seen = depth[row, column]
            sdf = seen - z
            observed = (seen > 0) & (sdf >= -self.truncation)
            if not observed.any():
                continue
            indices, sdf = indices[observed], sdf[observed]
            colour = rgb[row[observed], column[observed]]
            weight = flat_weight[indices]
            flat_tsdf[indices] = (flat_tsdf[indices] * weight + (sdf / self.truncation).clamp(max=1.0)) / (weight + 1)
            flat_color[indices] += torch.cat([colour, torch.ones_like(colour[:, :1])], 1)
            flat_weight[indices] = weight + 1
