"""The block-wise TSDF update gives what the per-voxel formulas of geometry/tsdf.py's docstring give.

:func:`plain_integrate` is the update as pointfield wrote it before it went block by block (commit
b0b6844): every voxel's world centre projected on its own through ``Cameras.project``, its pixel
found by ``floor``, F, W and the colour read and written row by row. The fast path
(:meth:`TSDFVolume.integrate`) projects a block's first voxel and adds each voxel's offset in
homogeneous pixel coordinates, reads whole blocks of rows and gathers with int32 indices: the same
numbers but for float rounding, which moves a voxel that lies on a pixel's edge to the next pixel.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from pointfield.geometry.meshes import mesh_from_volume
from pointfield.geometry.tsdf import BLOCK_VOXELS, TSDFVolume, allocation_stride, interpolated_depth
from pointfield.scenes import synthetic_scene


def plain_integrate(volume: TSDFVolume, depth, rgb, cameras, index: int, blocks: torch.Tensor, interpolate: bool):
    """One view fused into the voxels of ``blocks`` (positions in the rows), voxel by voxel."""
    camera = cameras[[index]].to(volume.device, torch.float32)
    height, width = depth.shape
    rows = (blocks[:, None] * BLOCK_VOXELS + torch.arange(BLOCK_VOXELS)).reshape(-1)
    pixels, z = camera.project(volume.centres[rows])
    pixels, z = pixels[0], z[0]
    column, row = torch.floor(pixels[:, 0]).nan_to_num(-1), torch.floor(pixels[:, 1]).nan_to_num(-1)
    inside = (column >= 0) & (column < width) & (row >= 0) & (row < height) & (z > 0)
    pixel = torch.where(inside, row * width + column, 0).long()
    seen = interpolated_depth(depth, pixels) if interpolate else torch.where(inside, depth.reshape(-1)[pixel], 0.0)
    sdf = seen - z
    observed = inside & (seen > 0) & (sdf >= -volume.truncation)
    tsdf, weight = volume.tsdf[rows], volume.weight[rows]
    fused = (tsdf * weight + (sdf / volume.truncation).clamp(max=1.0)) / (weight + 1)
    volume.tsdf[rows] = torch.where(observed, fused, tsdf)
    volume.weight[rows] = weight + observed
    near = observed & (sdf < volume.truncation)
    volume.color_sum[rows] += torch.cat([rgb.reshape(-1, 3)[pixel], torch.ones(len(rows), 1)], 1) * near[:, None]


@pytest.mark.parametrize("touched_only, interpolate", [(True, False), (False, True)],
                         ids=["as scene from-rgbd fuses", "as nerf export --mesh fuses"])
def test_block_wise_fusion_equals_the_per_voxel_formulas(touched_only, interpolate):
    scene = synthetic_scene("cube", views=12, size=96)
    views = [(torch.from_numpy(scene.depth(i)).float(), torch.from_numpy(scene.image(i)).float())
             for i in range(len(scene))]
    fast, plain = (TSDFVolume.create([-1, -1, -1], [1, 1, 1], 80) for _ in range(2))
    stride = allocation_stride(fast.voxel, float(scene.cameras.fx[0]), 6.0) if touched_only else 1
    for index, (depth, rgb) in enumerate(views):
        fast.integrate(depth, rgb, scene.cameras, index, touched_only=touched_only, pixel_stride=stride,
                       interpolate=interpolate)
        touched = plain.allocate(depth, scene.cameras, index, stride)
        every = torch.arange(plain.rows // BLOCK_VOXELS)  # culling blocks out of view changes no voxel (test_rgbd)
        blocks = plain.block_rows.view(-1)[touched] if touched_only else every
        plain_integrate(plain, depth, rgb, scene.cameras, index, blocks, interpolate)

    assert torch.equal(fast.block_rows, plain.block_rows)  # the same blocks, in the same rows
    assert 0.1 < float((fast.weight > 0).float().mean())  # the test means something: many voxels were observed
    assert_equal_but_on_pixel_edges(fast.tsdf, plain.tsdf, 1e-4)
    assert_equal_but_on_pixel_edges(fast.weight, plain.weight, 0.0)
    assert_equal_but_on_pixel_edges(fast.color_sum, plain.color_sum, 1e-4)
    fast_mesh, plain_mesh = mesh_from_volume(fast), mesh_from_volume(plain)
    assert abs(len(fast_mesh.points) - len(plain_mesh.points)) <= 1e-3 * len(plain_mesh.points)
    distance, nearest = cKDTree(plain_mesh.points).query(fast_mesh.points)
    assert np.quantile(distance, 0.999) < 1e-4 and distance.max() < fast.voxel / 2
    assert np.mean(np.all(fast_mesh.fields["colors"] == plain_mesh.fields["colors"][nearest], axis=1)) > 0.999


def assert_equal_but_on_pixel_edges(fast: torch.Tensor, plain: torch.Tensor, tolerance: float) -> None:
    """All but one row in 10,000 within ``tolerance``: the ones that rounding moved to the next pixel may read another depth."""
    off = (fast - plain).abs().reshape(len(fast), -1).amax(dim=1) > tolerance
    assert float(off.float().mean()) <= 1e-4, f"{int(off.sum())} of {len(off)} rows differ by more than {tolerance}"

def test_dense_grid_puts_every_row_at_its_voxel():
    volume = TSDFVolume.create([0, 0, 0], [1, 0.5, 0.3], 20)  # 20 x 10 x 6 voxels: blocks past the grid's edge
    volume._add_blocks(torch.tensor([0, 4, 5]))
    volume.tsdf[:] = torch.arange(volume.rows, dtype=torch.float32) / volume.rows
    volume.weight[::3] = 1.0
    tsdf, observed = volume.dense()
    assert tsdf.shape == observed.shape == (20, 10, 6)
    indices = volume.indices.numpy()
    inside = (indices < np.array(volume.shape)).all(axis=1)
    where = tuple(indices[inside].T)
    np.testing.assert_array_equal(tsdf[where], volume.tsdf.numpy()[inside])
    np.testing.assert_array_equal(observed[where], volume.weight.numpy()[inside] > 0)
    assert (tsdf == 1).sum() == tsdf.size - inside.sum()  # every voxel of no block is empty


def test_a_distorted_camera_allocates_the_blocks_a_pinhole_one_does_on_a_non_square_map():
    """Distorted cameras keep the per-ray path; with distortion too small to move a pixel (1e-9), it
    must mark the pinhole path's blocks, on a map whose height is not its width (the fox's 60 x 33)."""
    from pointfield.scenes.cameras import Cameras

    scene = synthetic_scene("cube", views=4, size=64)
    cameras = scene.cameras[[0]]
    depth = torch.from_numpy(scene.depth(0)).float()[2:62, 15:48]  # 60 x 33, the principal point kept inside
    shift = dict(cx=cameras.cx - 15, cy=cameras.cy - 2, width=33, height=60)
    pinhole = Cameras(cameras.camera_to_world, cameras.fx, cameras.fy, **shift)
    distorted = Cameras(cameras.camera_to_world, cameras.fx, cameras.fy, **shift, model="OPENCV",
                        distortion=[[1e-9, 0.0, 0.0, 0.0, 0.0]])
    blocks = [TSDFVolume.create([-1, -1, -1], [1, 1, 1], 64).allocate(depth, camera, 0, 1)
              for camera in (pinhole, distorted)]
    assert len(blocks[0]) > 0 and torch.equal(blocks[0], blocks[1])
