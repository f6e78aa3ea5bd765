"""Truncated signed distance fusion (Curless and Levoy 1996) of depth maps, in PyTorch, on any device.

A grid of voxels over a box, each holding a running mean of its signed distance to the surfaces
the depth maps saw, truncated to ``[-1, 1]`` in units of ``truncation``, and of their colour. For
a voxel at world point ``x`` and a view with z-depth map ``D``::

    (u, v), z = project(x)                      where it falls in the image, its depth along the axis
    sdf      = D(u, v) - z                      positive in front of the surface, negative behind
    observed = D(u, v) > 0 and sdf >= -truncation    (far behind a surface stays unknown)
    F <- (W F + min(1, sdf / truncation)) / (W + 1),  W <- W + 1
    colour sum += c(u, v), count += 1          only where |sdf| < truncation (near the surface);
                                                c: the colour of the pixel (u, v) falls in

``D(u, v)`` is interpolated bilinearly between the four pixel centres around ``(u, v)``; the
nearest pixel's depth is used where one of the four saw nothing or they differ by more than a
tenth of the nearest depth (:data:`OCCLUSION_STEP`: an occlusion boundary, where interpolating
would invent a surface between two). The nearest pixel alone is what Curless and Levoy and open3d
use, and it biases the surface inwards wherever pixels are wider than voxels: a voxel compares its
depth with the depth at the centre of the pixel it falls in, which on a face seen at a grazing
angle differs from the depth on the voxel's own ray by several voxels either way; in front, such
a reading is clamped to 1 and counted, behind it passes ``-truncation`` and is dropped, so the
zero level sinks (by half a voxel on bench_geometry's cube: 100 x 100 views, 256^3; Chamfer of its
exact depth 0.195 % of the diagonal with the nearest pixel, 0.094 % interpolated).

A pixel with no depth (D = 0: nothing opaque there) observes nothing. Counting it as empty space
would carve floaters, but at a silhouette, where a voxel just inside an object projects onto a
background pixel, it carves the object too (false inner surfaces); a floater is removed anyway by
the views that see the surface behind it (their sdf is positive there).

Sparse in voxel blocks. Only voxels near a surface matter, so the grid is split into blocks of
``BLOCK``^3 voxels, and only *allocated* blocks are stored (Niessner et al. 2013's voxel hashing,
as open3d's ScalableTSDFVolume does; here the block table is a small dense array since the box is
known). :meth:`TSDFVolume.allocate` allocates every block that the band ``[D - truncation, D +
truncation]`` behind a pixel passes through; :meth:`TSDFVolume.integrate` updates the allocated
voxels that the view sees. Allocating every view before integrating any makes the result
independent of view order (a block first reached by the last view is still carved by the others);
:func:`fuse` does that. Allocated voxels are stored compactly -- ``(M,)`` rows of F, W, colour sum
and count, 24 bytes each; a voxel's place follows from its block's -- so fusing is a few passes of
elementwise work over the blocks a view reaches (lego at 256^3: about a tenth of the grid), never
over the whole grid. The passes are written for one CPU thread as much as for a GPU: a view's
voxels are projected a block at a time (a pinhole projection is linear in homogeneous
coordinates, so a voxel's pixel is its block's plus a fixed offset's), rows are read and written
a block at a time, and pixels are gathered by ``index_select`` with int32 indices, several times
faster on one thread than boolean masks and advanced indexing (``benchmarks/bench_tsdf.py``
measures it against the per-voxel code it replaced and against open3d).

The surface is the zero level of F: :meth:`TSDFVolume.dense` scatters the rows into a dense grid
for marching cubes (:mod:`pointfield.geometry.meshes`), where voxels no view observed have F = 1
(empty) and W = 0; that grid, 5 bytes a voxel, is what bounds the resolution (640 MB at 512^3).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import torch

from pointfield.errors import PointfieldError
from pointfield.scenes.cameras import Cameras, pixel_centers

OCCLUSION_STEP = 0.1
"""The largest relative step between four neighbouring depths that is interpolated (module docstring)."""
BLOCK = 8
"""Voxels along a side of one allocation block."""
BLOCK_VOXELS = BLOCK**3
BYTES_PER_VOXEL = 4 + 1
"""Of the dense grid extracted for marching cubes: F (float32) and whether observed (bool)."""
BYTES_PER_ALLOCATED_VOXEL = 4 + 4 + 16
"""Of an allocated voxel's row: F, W, colour sum and count (float32); where it lies follows from its block."""
GROWTH = 1.5
"""The row buffers grow by this factor at least when blocks are added, so that adding blocks frame
by frame copies the rows a bounded number of times rather than once a frame."""


def grid_shape(low, high, resolution: int) -> tuple[tuple[int, int, int], float]:
    """Voxels along x, y, z and the voxel size: cubes, ``resolution`` along the box's longest side."""
    extent = np.asarray(high, np.float64) - np.asarray(low, np.float64)
    if resolution < 2 or np.any(extent <= 0):
        raise PointfieldError(f"a TSDF grid needs a resolution of 2 or more and a box with volume, got {resolution}, {extent}")
    voxel = float(extent.max()) / resolution
    shape = tuple(max(2, math.ceil(e / voxel)) for e in extent)
    return shape, voxel


def grid_bytes(shape) -> int:
    """Bytes of the dense grid that meshing a TSDF of this shape needs."""
    return int(np.prod(shape)) * BYTES_PER_VOXEL


def _block_offsets(device) -> torch.Tensor:
    """``(BLOCK^3, 3)`` int64 ``(i, j, k)`` of the voxels of a block, in row order ``(i * BLOCK + j) * BLOCK + k``."""
    steps = torch.arange(BLOCK, device=device)
    return torch.stack(torch.meshgrid(steps, steps, steps, indexing="ij"), -1).reshape(-1, 3)


@dataclass
class TSDFVolume:
    """A sparse TSDF grid over the box ``low``..``high`` (module docstring); build with :meth:`create`.

    Rows ``(M, ...)`` describe the allocated voxels, block by block (block ``b`` of
    :attr:`block_rows` holds rows ``b * BLOCK^3`` to ``(b + 1) * BLOCK^3``, its voxel ``(i, j, k)``
    at row ``b * BLOCK^3 + (i * BLOCK + j) * BLOCK + k``). They live at the front of buffers with
    room to spare (:data:`GROWTH`); :attr:`tsdf`, :attr:`weight` and :attr:`color_sum` are views of
    the ``M`` rows in use.
    """

    low: torch.Tensor
    voxel: float
    truncation: float
    shape: tuple[int, int, int]
    memory_limit: int | None
    block_rows: torch.Tensor
    """``(X / BLOCK, Y / BLOCK, Z / BLOCK)`` int64, rounded up: each block's position in the rows, -1 if not allocated."""
    block_coords: torch.Tensor
    """``(M / BLOCK^3, 3)`` int64: the grid position (in blocks) of each allocated block, in row order."""
    rows: int
    """``M``, the allocated voxels."""
    buffers: tuple[torch.Tensor, torch.Tensor, torch.Tensor]
    """F ``(capacity,)``, W ``(capacity,)`` and colour sum and count ``(capacity, 4)``, float32; the first
    :attr:`rows` are in use. Three arrays, not one of rows: a block of each is a contiguous run to copy."""

    @classmethod
    def create(cls, low, high, resolution: int, *, truncation_voxels: float = 4.0, device=None,
               memory_limit: int | None = None) -> TSDFVolume:
        """An empty grid; refuses (naming the memory it would need) one whose mesh needs more than ``memory_limit`` bytes."""
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
        blocks = tuple(math.ceil(size / BLOCK) for size in shape)
        return cls(
            low=torch.as_tensor(np.asarray(low, np.float64), dtype=torch.float32, device=device),
            voxel=voxel,
            truncation=truncation_voxels * voxel,
            shape=shape,
            memory_limit=memory_limit,
            block_rows=torch.full(blocks, -1, dtype=torch.long, device=device),
            block_coords=torch.zeros(0, 3, dtype=torch.long, device=device),
            rows=0,
            buffers=(torch.zeros(0, device=device), torch.zeros(0, device=device), torch.zeros(0, 4, device=device)),
        )

    @property
    def device(self) -> torch.device:
        return self.block_rows.device

    @property
    def tsdf(self) -> torch.Tensor:
        """``(M,)`` truncated signed distance, in units of ``truncation`` (a view: writes go to the grid)."""
        return self.buffers[0][:self.rows]

    @property
    def weight(self) -> torch.Tensor:
        """``(M,)`` how many views observed the voxel."""
        return self.buffers[1][:self.rows]

    @property
    def color_sum(self) -> torch.Tensor:
        """``(M, 4)`` the colours seen near the surface summed, and (last) how many."""
        return self.buffers[2][:self.rows]

    @property
    def indices(self) -> torch.Tensor:
        """``(M, 3)`` int64 grid indices of the rows (may lie past :attr:`shape` in the last blocks along an axis)."""
        return (self.block_coords[:, None, :] * BLOCK + _block_offsets(self.device)).reshape(-1, 3)

    @property
    def centres(self) -> torch.Tensor:
        """``(M, 3)`` world coordinates of the voxels' centres."""
        return self.low + (self.indices.float() + 0.5) * self.voxel

    @property
    def allocated_fraction(self) -> float:
        """The fraction of the grid's blocks that are allocated."""
        return float((self.block_rows >= 0).float().mean())

    @torch.no_grad()
    def allocate(self, depth: torch.Tensor, cameras: Cameras, index: int, pixel_stride: int = 1) -> torch.Tensor:
        """Allocate the blocks within ``truncation`` of the surface of one view's z-depth ``(H, W)``;
        return the flat indices (into :attr:`block_rows`) of those blocks.

        Samples each pixel's ray through the band ``z = D +- truncation`` in steps of at most half
        a block, so the band cannot pass through a block without a sample in it (but for a
        sliver at the block's corner). ``pixel_stride`` samples the band off the surface on every
        so many pixels' rays along each axis (:func:`allocation_stride` keeps them half a block
        apart on a surface facing the camera); the surface ``z = D`` itself is still sampled on
        every pixel's ray, so that each block the surface passes through is allocated, a corner
        at a grazing angle included.

        For a pinhole camera the sample at z-depth ``z`` on pixel ``(u, v)``'s ray is ``C + z R q``
        with ``q = ((u - cx) / fx, (v - cy) / fy, 1)``: its block, ``floor((C - low) / b + z R q / b)``
        for a block of side ``b``, is one multiply-add per sample from ``R q / b`` found once per pixel.
        """
        depth = depth.to(self.device, torch.float32).contiguous()  # viewed flat below
        camera = cameras[[index]].to(self.device, torch.float32)
        height, width = depth.shape
        seen = depth > 0
        if not seen.any():
            return torch.zeros(0, dtype=torch.long, device=self.device)
        steps = math.ceil(self.truncation / (self.voxel * BLOCK / 2))
        block_side = self.voxel * BLOCK
        shape = torch.tensor(self.block_rows.shape, device=self.device)
        # Marks go to one more entry than there are blocks: the samples outside the grid, or on a pixel with no depth.
        marked = torch.zeros(self.block_rows.numel() + 1, dtype=torch.bool, device=self.device)
        if _is_pinhole(camera):
            fx, fy, cx, cy = (float(v[0]) for v in (camera.fx, camera.fy, camera.cx, camera.cy))
            centres = pixel_centers(width, height, device=self.device).view(height, width, 2)
            local = torch.stack([(centres[..., 0] - cx) / fx, (centres[..., 1] - cy) / fy,
                                 torch.ones(height, width, device=self.device)], -1)
            per_depth = local @ (camera.rotations[0].T / block_side)
            corner = (camera.centers[0] - self.low) / block_side
            # Flat block numbers in float: exact below 2^24 blocks (a grid of 2^33 voxels), else in float64.
            kind = torch.float32 if len(marked) < 2**24 else torch.float64
            _, by, bz = self.block_rows.shape
            flat_of = torch.tensor([by * bz, bz, 1], dtype=kind, device=self.device)
            every = (per_depth.view(-1, 3), depth.view(-1), seen.view(-1))
            band = every if pixel_stride == 1 else tuple(
                a[::pixel_stride, ::pixel_stride].reshape(-1, *a.shape[2:]) for a in (per_depth, depth, seen))
            for step in range(-steps, steps + 1):
                direction, at, valid = every if step == 0 else band
                block = torch.floor(torch.addcmul(corner, (at + step * self.truncation / steps)[:, None], direction))
                valid = valid & ((block >= 0) & (block < shape)).all(dim=1)
                flat = torch.where(valid, block.to(kind) @ flat_of, len(marked) - 1)
                marked.index_fill_(0, flat.long(), True)
        else:
            rays = camera.rays_through(0, pixel_centers(width, height, device=self.device)[seen])
            sparse = torch.zeros_like(seen)
            sparse[::pixel_stride, ::pixel_stride] = True
            sparse = sparse[seen]
            surface_depth = depth[seen]
            band = (rays, surface_depth) if pixel_stride == 1 else (rays[sparse], surface_depth[sparse])
            for step in range(-steps, steps + 1):
                ray, at = (rays, surface_depth) if step == 0 else band
                block = torch.floor((ray.at((at + step * self.truncation / steps) / ray.axis_cosine) - self.low) / block_side)
                block = block[((block >= 0) & (block < shape)).all(dim=1)].long()
                marked[(block[:, 0] * shape[1] + block[:, 1]) * shape[2] + block[:, 2]] = True
        marked = marked[:-1]
        new = marked & (self.block_rows.view(-1) < 0)
        if new.any():
            self._add_blocks(torch.nonzero(new)[:, 0])
        return torch.nonzero(marked)[:, 0]

    def _add_blocks(self, flat_blocks: torch.Tensor) -> None:
        count = len(flat_blocks)
        rows = self.rows + count * BLOCK_VOXELS
        if self.memory_limit is not None and rows * BYTES_PER_ALLOCATED_VOXEL > self.memory_limit:
            raise PointfieldError(
                f"the TSDF's allocated voxels would need {rows * BYTES_PER_ALLOCATED_VOXEL / 2**30:.1f} GiB, more "
                f"than the {self.memory_limit / 2**30:.1f} GiB allowed; pass a lower --resolution or a smaller --crop box"
            )
        if rows > len(self.buffers[0]):
            capacity = max(rows, int(len(self.buffers[0]) * GROWTH))
            if self.memory_limit is not None:
                capacity = max(rows, min(capacity, self.memory_limit // BYTES_PER_ALLOCATED_VOXEL))
            grown = tuple(torch.empty((capacity,) + old.shape[1:], device=self.device) for old in self.buffers)
            for new, old in zip(grown, self.buffers):
                new[:self.rows] = old[:self.rows]
            self.buffers = grown
        # A new voxel: F = 1 (empty), never observed, no colour.
        for buffer, value in zip(self.buffers, (1.0, 0.0, 0.0)):
            buffer[self.rows:rows] = value
        first_block = self.rows // BLOCK_VOXELS
        self.block_rows.view(-1)[flat_blocks] = torch.arange(first_block, first_block + count, device=self.device)
        _, by, bz = self.block_rows.shape
        blocks = torch.stack([flat_blocks // (by * bz), (flat_blocks // bz) % by, flat_blocks % bz], dim=-1)
        self.block_coords = torch.cat([self.block_coords, blocks])
        self.rows = rows

    @torch.no_grad()
    def integrate(self, depth: torch.Tensor, rgb: torch.Tensor, cameras: Cameras, index: int, *,
                  touched_only: bool = False, pixel_stride: int = 1, interpolate: bool = True) -> None:
        """Fuse one view: z-depth ``(H, W)`` (0 = nothing seen), colour ``(H, W, 3)``, camera ``index``.

        Allocates the view's own blocks first (nothing new after :meth:`allocate`), then updates
        every allocated voxel the view observes (:meth:`blocks_in_view`). ``touched_only``: update
        only the blocks within ``truncation`` of this view's own surface, as open3d's
        ScalableTSDFVolume and VoxelBlockGrid do -- far less work where many views see one room
        from inside, but a block another view allocated, which this one sees as empty space in
        front of its surface, is not carved by it. ``pixel_stride``: :meth:`allocate`'s.
        ``interpolate=False``: the depth of the pixel a voxel falls in, as Curless and Levoy and
        open3d read it -- what the module docstring's bias needs is pixels wider than voxels, and
        a sensor's 640 x 480 depth at room scale has pixels narrower than centimetre voxels.

        The work is a few elementwise passes over ``(K, BLOCK^3)`` (K blocks): a pinhole projection
        is linear in homogeneous coordinates, so each voxel's ``(fx x + cx z, fy y + cy z, z)`` is
        its block's first voxel's plus its offset's within the block (one add each), and the
        rows are read and written back a block at a time (contiguous runs of BLOCK^3).
        """
        touched = self.allocate(depth, cameras, index, pixel_stride)
        camera = cameras[[index]].to(self.device, torch.float32)
        depth = depth.to(self.device, torch.float32)
        height, width = depth.shape
        if touched_only:
            blocks = self.block_rows.view(-1)[touched]
        else:
            blocks = self.blocks_in_view(camera, float(depth.max()) + self.truncation)
        if len(blocks) == 0:
            return
        u, v, z = self._project_blocks(camera, blocks)
        inside = (z > 0) & (u >= 0) & (u < width) & (v >= 0) & (v < height)
        # Outside the image, the pixel is one past the last, whose depth is 0 (nothing seen) and colour
        # and count 0; gathers by index_select with int32 indices (several times faster than indexing).
        outside = height * width
        pixel = torch.where(inside, v.int() * width + u.int(), outside).view(-1)
        if interpolate:
            pixels = torch.stack([u, v], -1).view(-1, 2)
            seen = torch.where(inside.view(-1), interpolated_depth(depth, pixels), 0.0).view_as(z)
        else:
            seen = torch.cat([depth.reshape(-1), depth.new_zeros(1)]).index_select(0, pixel).view_as(z)
        sdf = seen - z
        observed = (seen > 0) & (sdf >= -self.truncation)
        tsdf_rows, weight_rows, colour_rows = (b[:self.rows].view(len(self.block_coords), -1) for b in self.buffers)
        tsdf, weight = tsdf_rows.index_select(0, blocks), weight_rows.index_select(0, blocks)
        fused = (tsdf * weight + (sdf / self.truncation).clamp(max=1.0)) / (weight + 1)
        tsdf_rows.index_copy_(0, blocks, torch.where(observed, fused, tsdf))
        weight_rows.index_add_(0, blocks, observed.float())
        # Colour where the voxel is near the surface: the pixel's colour and a count of 1, elsewhere nothing.
        near = observed & (sdf < self.truncation)
        palette = torch.zeros(outside + 1, 4, device=self.device)
        palette[:-1, :3] = rgb.to(self.device, torch.float32).reshape(-1, 3)
        palette[:-1, 3] = 1.0
        colour = palette.index_select(0, torch.where(near.view(-1), pixel, outside))
        colour_rows.index_add_(0, blocks, colour.view(len(blocks), -1))  # 10x a gather, add and copy of the rows

    def _project_blocks(self, camera: Cameras, blocks: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Continuous pixel ``u``, ``v`` and z-depth, each ``(K, BLOCK^3)``, of the voxels of ``blocks`` (rows order) in one camera."""
        offsets = _block_offsets(self.device).float() * self.voxel
        first = self.low + (self.block_coords[blocks] * BLOCK).float() * self.voxel + 0.5 * self.voxel
        if not _is_pinhole(camera):
            pixels, z = _project(camera, (first[:, None, :] + offsets).reshape(-1, 3))
            return pixels[:, 0].view(len(blocks), -1), pixels[:, 1].view(len(blocks), -1), z.view(len(blocks), -1)
        fx, fy, cx, cy = (float(v[0]) for v in (camera.fx, camera.fy, camera.cx, camera.cy))
        intrinsic = torch.tensor([[fx, 0.0, 0.0], [0.0, fy, 0.0], [cx, cy, 1.0]], device=self.device)
        # World to homogeneous pixel coordinates (fx x + cx z, fy y + cy z, z) of camera coordinates (x, y, z).
        to_pixels = camera.rotations[0] @ intrinsic
        base = (first - camera.centers[0]) @ to_pixels
        step = offsets @ to_pixels
        z = base[:, 2:] + step[:, 2]
        return (base[:, :1] + step[:, 0]) / z, (base[:, 1:2] + step[:, 1]) / z, z

    def blocks_in_view(self, camera: Cameras, far: float) -> torch.Tensor:
        """``(K,)`` the allocated blocks (by position in the rows) that one pinhole ``camera`` may observe closer than ``far``.

        A block is left out when its bounding sphere (centre ``c``, radius ``r`` = half the block's
        diagonal) lies wholly outside one of the view's half-spaces: behind the camera, past
        ``far`` along the axis, or beyond an image edge -- the plane through the camera centre and
        that edge, e.g. ``u >= 0  <=>  fx X + cx Z >= 0`` in camera coordinates. Every voxel of
        such a block projects outside the image or lies farther than any depth plus the
        truncation, so :meth:`integrate` would leave it as it is: culling changes no value, only
        the work, which then follows the blocks in view rather than every block allocated (a
        room scanned by a moving camera sees a fraction of it at a time). Cameras with
        distortion keep every block.
        """
        count = self.rows // BLOCK_VOXELS
        every = torch.arange(count, device=self.device)
        if count == 0 or not _is_pinhole(camera):
            return every
        centre = self.low + (self.block_coords * BLOCK).float() * self.voxel + BLOCK / 2 * self.voxel
        radius = math.sqrt(3) * BLOCK * self.voxel / 2
        local = (centre - camera.centers[0]) @ camera.rotations[0]
        fx, fy, cx, cy = (float(v[0]) for v in (camera.fx, camera.fy, camera.cx, camera.cy))
        width, height = float(camera.width[0]), float(camera.height[0])
        normals = torch.tensor([[fx, 0, cx], [-fx, 0, width - cx], [0, fy, cy], [0, -fy, height - cy], [0, 0, 1]],
                               dtype=local.dtype, device=self.device)
        normals = normals / normals.norm(dim=1, keepdim=True)
        keep = ((local @ normals.T) >= -radius).all(dim=1) & (local[:, 2] <= far + radius)
        return torch.nonzero(keep)[:, 0]

    def dense(self) -> tuple[np.ndarray, np.ndarray]:
        """The grid as arrays of :attr:`shape`: F (float32, 1 where unobserved) and whether observed.

        Block by block: a grid of whole blocks, seen as ``(X / BLOCK, BLOCK, Y / BLOCK, BLOCK, Z /
        BLOCK, BLOCK)``, takes each allocated block's rows at its place; then it is cut to :attr:`shape`.
        """
        bx, by, bz = self.block_rows.shape
        x, y, z = self.block_coords.cpu().numpy().T
        grids = []
        for rows, empty in ((self.tsdf, 1.0), (self.weight > 0, False)):
            values = rows.cpu().numpy().reshape(-1, BLOCK, BLOCK, BLOCK)
            grid = np.full((bx * BLOCK, by * BLOCK, bz * BLOCK), empty, values.dtype)
            grid.reshape(bx, BLOCK, by, BLOCK, bz, BLOCK)[x, :, y, :, z, :] = values
            grids.append(np.ascontiguousarray(grid[: self.shape[0], : self.shape[1], : self.shape[2]]))
        return grids[0], grids[1]

    def colors_at(self, points: torch.Tensor) -> torch.Tensor:
        """``(K, 3)`` mean colour of the voxel holding each world point (grey where no view saw one)."""
        index = torch.floor((points.to(self.device, torch.float32) - self.low) / self.voxel).long()
        for axis, size in enumerate(self.shape):
            index[:, axis] = index[:, axis].clamp(0, size - 1)
        block = index // BLOCK
        block_row = self.block_rows[block[:, 0], block[:, 1], block[:, 2]]
        local = index % BLOCK
        rows = block_row * BLOCK_VOXELS + (local[:, 0] * BLOCK + local[:, 1]) * BLOCK + local[:, 2]
        summed = torch.where((block_row >= 0)[:, None], self.color_sum[rows.clamp_min(0)], 0.0)
        count = summed[:, 3:]
        return torch.where(count > 0, summed[:, :3] / count.clamp_min(1), torch.full_like(summed[:, :3], 0.5))


def _is_pinhole(camera: Cameras) -> bool:
    """Whether one camera projects as a pinhole (no fisheye, no distortion): the fast paths' condition."""
    return camera.model != "OPENCV_FISHEYE" and not bool(camera.distortion.any())


def allocation_stride(voxel: float, focal: float, far: float) -> int:
    """The largest pixel stride whose rays, at depth ``far`` on a surface facing the camera, land at
    most half a block apart: ``stride * far / focal <= BLOCK * voxel / 2`` (at least 1)."""
    return max(1, int(BLOCK * voxel / 2 * focal / far))


def fuse(volume: TSDFVolume, views: Iterable[tuple[torch.Tensor, torch.Tensor]], cameras: Cameras) -> TSDFVolume:
    """Allocate the blocks of every view, then integrate every view; ``views`` yields (z-depth, colour) per camera."""
    views = list(views)
    for index, (depth, _) in enumerate(views):
        volume.allocate(depth, cameras, index)
    for index, (depth, rgb) in enumerate(views):
        volume.integrate(depth, rgb, cameras, index)
    return volume


def pixels_under(camera: Cameras, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Where world ``points`` ``(P, 3)`` land in one camera's image: the flat index ``row * W + column``
    ``(P,)`` of the pixel holding each (0 where none does), whether one does (in the image, in front
    of the camera), and each point's z-depth."""
    pixels, z = _project(camera, points)
    pixel, inside = _nearest_pixel(pixels, z, int(camera.width[0]), int(camera.height[0]))
    return pixel, inside, z


def _nearest_pixel(pixels: torch.Tensor, z: torch.Tensor, width: int, height: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The flat index of the pixel holding each continuous pixel position (0 where none does), and whether one does."""
    column = torch.floor(pixels[:, 0]).nan_to_num(-1)
    row = torch.floor(pixels[:, 1]).nan_to_num(-1)
    inside = (column >= 0) & (column < width) & (row >= 0) & (row < height) & (z > 0)
    return torch.where(inside, row * width + column, 0).long(), inside


def interpolated_depth(depth: torch.Tensor, pixels: torch.Tensor) -> torch.Tensor:
    """``(P,)`` depth of map ``depth`` ``(H, W)`` at continuous ``pixels`` ``(P, 2)``, bilinear between
    the four pixel centres around each (centres at ``+ 0.5``; held constant past the image's outer
    centres); the depth of the nearest of the four -- the pixel the position falls in -- where one
    of them is 0 or they differ by more than :data:`OCCLUSION_STEP` of it (module docstring).
    """
    height, width = depth.shape
    x = (pixels[:, 0] - 0.5).nan_to_num(0.0).clamp(0, width - 1)
    y = (pixels[:, 1] - 0.5).nan_to_num(0.0).clamp(0, height - 1)
    left = torch.floor(x).clamp(max=max(width - 2, 0))
    top = torch.floor(y).clamp(max=max(height - 2, 0))
    across, down = (x - left).clamp(max=1), (y - top).clamp(max=1)
    flat = depth.reshape(-1)
    top_left = (top * width + left).int()  # index_select with int32 indices: several times faster than indexing
    step_right, step_down = int(width > 1), width * int(height > 1)
    d00, d01 = flat.index_select(0, top_left), flat.index_select(0, top_left + step_right)
    d10, d11 = flat.index_select(0, top_left + step_down), flat.index_select(0, top_left + step_down + step_right)
    interpolated = torch.lerp(torch.lerp(d00, d01, across), torch.lerp(d10, d11, across), down)
    lowest = torch.minimum(torch.minimum(d00, d01), torch.minimum(d10, d11))
    highest = torch.maximum(torch.maximum(d00, d01), torch.maximum(d10, d11))
    at_nearest = torch.where(down < 0.5, torch.where(across < 0.5, d00, d01), torch.where(across < 0.5, d10, d11))
    smooth = (lowest > 0) & (highest - lowest <= OCCLUSION_STEP * at_nearest)
    return torch.where(smooth, interpolated, at_nearest)


def _project(camera: Cameras, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Pixels ``(P, 2)`` and z-depths ``(P,)`` of world points in one camera; a direct path for a pinhole."""
    if camera.model == "OPENCV_FISHEYE" or bool(camera.distortion.any()):
        pixels, z = camera.project(points)
        return pixels[0], z[0]
    camera_points = (points - camera.centers[0]) @ camera.rotations[0]
    z = camera_points[:, 2]
    inverse_z = 1.0 / z
    pixels = torch.stack([camera.fx[0] * camera_points[:, 0] * inverse_z + camera.cx[0],
                          camera.fy[0] * camera_points[:, 1] * inverse_z + camera.cy[0]], dim=-1)
    return pixels, z
