"""TSDF fusion: pointfield's (PyTorch) against open3d's on the same depth maps.

The depth maps are the synthetic cube's exact ones (``scene make cube``: an analytic surface, so
the true surface is known), fused over [-1, 1]^3 at ``--resolution`` voxels a side with a
truncation of 4 voxels by both, then meshed by each library's marching cubes. Reported, from one
run with the two interleaved (:func:`harness.interleaved`): depth maps fused per second at 100 x
100 and at 800 x 800, and each mesh's distance to the true cube surface (median and 95th
percentile of its vertices' distances, in voxels) -- the ceiling of the method on perfect depth.

The peer is open3d's ``UniformTSDFVolume`` (dense, like pointfield's). The issue names its
``ScalableTSDFVolume``; in the open3d-cpu 0.20 wheel here that one extracts nothing, even from a
single flat depth map that ``UniformTSDFVolume`` fuses to 1,024 points (checked by
:func:`scalable_volume_works`, whose answer the record keeps).

Part of issue 14. Run: ``make bench-tsdf`` (= ``python benchmarks/bench_tsdf.py``); the record goes to
``benchmarks/records/tsdf.json``.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
import torch
from harness import Record, interleaved

BOX = ([-1.0, -1.0, -1.0], [1.0, 1.0, 1.0])
TRUNCATION_VOXELS = 4.0


def cube_views(views: int, size: int):
    from pointfield.scenes import synthetic_scene

    scene = synthetic_scene("cube", views=views, size=size)
    depths = [scene.depth(i).astype(np.float32) for i in range(views)]
    colours = [scene.image(i).astype(np.float32) for i in range(views)]
    return scene.cameras, depths, colours


def fuse_pointfield(cameras, depths, colours, resolution: int):
    from pointfield.geometry.tsdf import TSDFVolume

    volume = TSDFVolume.create(*BOX, resolution, truncation_voxels=TRUNCATION_VOXELS)
    for index, (depth, colour) in enumerate(zip(depths, colours)):
        volume.integrate(torch.from_numpy(depth), torch.from_numpy(colour), cameras, index)
    return volume


def _rgbd(depth: np.ndarray, colour: np.ndarray):
    import open3d as o3d

    return o3d.geometry.RGBDImage.create_from_color_and_depth(
        o3d.geometry.Image(np.ascontiguousarray((colour * 255).astype(np.uint8))),
        o3d.geometry.Image(np.ascontiguousarray(depth)),
        depth_scale=1.0, depth_trunc=100.0, convert_rgb_to_intensity=False,
    )


def fuse_open3d(cameras, depths, colours, resolution: int):
    import open3d as o3d

    length = BOX[1][0] - BOX[0][0]
    volume = o3d.pipelines.integration.UniformTSDFVolume(
        length=length, resolution=resolution, sdf_trunc=TRUNCATION_VOXELS * length / resolution,
        color_type=o3d.pipelines.integration.TSDFVolumeColorType.RGB8, origin=np.array(BOX[0]),
    )
    world_to_camera = cameras.world_to_camera().double().numpy()
    for index, (depth, colour) in enumerate(zip(depths, colours)):
        height, width = depth.shape
        intrinsic = o3d.camera.PinholeCameraIntrinsic(
            width, height, float(cameras.fx[index]), float(cameras.fy[index]),
            float(cameras.cx[index]) - 0.5, float(cameras.cy[index]) - 0.5,  # open3d: pixel centres at integers
        )
        volume.integrate(_rgbd(depth, colour), intrinsic, world_to_camera[index])
    return volume


def scalable_volume_works() -> bool:
    """Whether open3d's ScalableTSDFVolume fuses one flat depth map into any point at all."""
    import open3d as o3d

    volume = o3d.pipelines.integration.ScalableTSDFVolume(
        voxel_length=0.02, sdf_trunc=0.08, color_type=o3d.pipelines.integration.TSDFVolumeColorType.RGB8)
    intrinsic = o3d.camera.PinholeCameraIntrinsic(100, 100, 100.0, 100.0, 49.5, 49.5)
    volume.integrate(_rgbd(np.full((100, 100), 2.0, np.float32), np.full((100, 100, 3), 0.5, np.float32)),
                     intrinsic, np.eye(4))
    return len(volume.extract_point_cloud().points) > 0


def cube_distance_in_voxels(vertices: np.ndarray, resolution: int) -> tuple[float, float]:
    voxel = (BOX[1][0] - BOX[0][0]) / resolution
    distance = np.abs(np.abs(vertices).max(axis=1) - 0.5) / voxel
    return float(np.median(distance)), float(np.percentile(distance, 95))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=int, default=256, help="voxels along a side (default 256)")
    parser.add_argument("--repeats", type=int, default=2, help="timed rounds per contender (default 2)")
    args = parser.parse_args()
    import open3d as o3d

    from pointfield.geometry.meshes import mesh_from_volume

    record = Record("tsdf", "TSDF fusion against open3d on the same depth maps", issue="14",
                    about="The synthetic cube's exact depth maps fused over [-1, 1]^3 at "
                          f"{args.resolution}^3, truncation 4 voxels, by pointfield (PyTorch, dense, "
                          f"CPU) and open3d {o3d.__version__}'s UniformTSDFVolume, interleaved in one "
                          "run; meshes from each one's marching cubes, compared with the true cube surface.")
    works = scalable_volume_works()
    record.figures["open3d_scalable_volume_works"] = works
    record.note(f"open3d ScalableTSDFVolume fuses a flat depth map into points here: {works}.")
    rows = []
    for views, size in ((24, 100), (8, 800)):
        cameras, depths, colours = cube_views(views, size)
        timings = interleaved({
            "pointfield": lambda c=cameras, d=depths, k=colours: fuse_pointfield(c, d, k, args.resolution),
            "open3d": lambda c=cameras, d=depths, k=colours: fuse_open3d(c, d, k, args.resolution),
        }, repeats=args.repeats)
        ours = mesh_from_volume(fuse_pointfield(cameras, depths, colours, args.resolution)).points
        theirs = np.asarray(fuse_open3d(cameras, depths, colours, args.resolution).extract_triangle_mesh().vertices)
        for name, vertices in (("pointfield", ours), ("open3d", theirs)):
            median, p95 = cube_distance_in_voxels(vertices, args.resolution) if len(vertices) else (np.nan, np.nan)
            rows.append([f"{size}x{size}", views, name, f"{views / timings[name].median:.2f}",
                         f"{timings[name].median:.2f}", f"{timings[name].spread:.2f}", f"{median:.2f}", f"{p95:.2f}"])
        record.figures[f"{size}"] = {name: timings[name].as_dict() for name in timings}
        ratio = timings["open3d"].median / timings["pointfield"].median
        record.note(f"{size}x{size}: pointfield fuses at {ratio:.2f}x open3d's speed "
                    f"({timings['pointfield'].median:.2f} s against {timings['open3d'].median:.2f} s for {views} maps).")
    record.table(["depth maps", "views", "library", "maps per s", "median s", "spread",
                  "median distance (voxels)", "95th pct distance (voxels)"], rows,
                 title=f"Fusing the cube's exact depth at {args.resolution}^3 (2 cores)")
    return record.finish()


if __name__ == "__main__":
    sys.exit(main())
