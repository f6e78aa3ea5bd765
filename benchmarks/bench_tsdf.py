"""TSDF fusion: pointfield's (PyTorch, sparse voxel blocks) against open3d's two on the same depth maps.

The depth maps are the synthetic cube's exact ones (``scene make cube``: an analytic surface, so
the true surface is known), fused over [-1, 1]^3 at ``--resolution`` voxels a side with a
truncation of 4 voxels by each, then meshed by each library's marching cubes. Reported, from one
run with the three interleaved (:func:`harness.interleaved`): depth maps fused per second at
100 x 100 and at 800 x 800, and each mesh's distance to the true cube surface (median and 95th
percentile of its vertices' distances, in voxels) -- the ceiling of the method on perfect depth.

A fourth contender is pointfield's fusion with the classic depth lookup, the nearest pixel's
depth instead of the interpolated one (:func:`nearest_pixel_depth`), so that what interpolation
costs in time and gains in accuracy is measured in the same run.

The peers are open3d's ``VoxelBlockGrid`` (its tensor-based, sparse voxel-block TSDF, the
successor of ``ScalableTSDFVolume``) and ``UniformTSDFVolume`` (dense). The issue names the legacy
``ScalableTSDFVolume``; in the open3d-cpu 0.20 wheel here it fuses the cube's 24 depth maps into
nothing (no vertex; :func:`legacy_scalable_vertices` checks it in every run and the record keeps
the count), while ``UniformTSDFVolume`` and ``VoxelBlockGrid`` mesh the same maps.

A second table fuses real sensor frames as ``scene from-rgbd`` does: the first ``--frames`` of the
living room (``../shared/data/rgbd/livingroom1_micro``, 640 x 480) at open3d's own poses for them
(``open3d_trajectory.log``), 1 cm voxels, each frame updating only the blocks near its own surface,
each voxel reading the depth of the pixel it falls in -- pointfield against open3d's VoxelBlockGrid.

``--before COMMIT`` adds pointfield's fusion as it was at that commit (its ``geometry/tsdf.py``,
read with ``git show``) to both tables, so that a change to the fusion is measured against the
code it replaces in the same run: ``--before b0b6844`` is the per-voxel code that the block-wise
one replaced (issue 44: ``scene from-rgbd`` on a busy machine lost to open3d in its fusion).

Part of issue 14. Run: ``make bench-tsdf`` (= ``python benchmarks/bench_tsdf.py``), on one thread as
``OMP_NUM_THREADS=1 python benchmarks/bench_tsdf.py --before b0b6844``; the record goes to
``benchmarks/records/tsdf.json``.
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from unittest import mock

import numpy as np
import torch

from harness import ROOT, Record, interleaved

BOX = ([-1.0, -1.0, -1.0], [1.0, 1.0, 1.0])
TRUNCATION_VOXELS = 4.0
ROOM = ROOT.parent / "shared" / "data" / "rgbd" / "livingroom1_micro"
ROOM_VOXEL = 0.01
"""Metres: ``scene from-rgbd``'s default voxel."""
ROOM_DEPTH_MAX = 3.0


def cube_views(views: int, size: int):
    from pointfield.scenes import synthetic_scene

    scene = synthetic_scene("cube", views=views, size=size)
    depths = [scene.depth(i).astype(np.float32) for i in range(views)]
    colours = [scene.image(i).astype(np.float32) for i in range(views)]
    return scene.cameras, depths, colours


def fuse_pointfield(cameras, depths, colours, resolution: int, device="cpu", tsdf=None):
    """``tsdf``: the module to fuse with (default pointfield's own; :func:`tsdf_at` gives an older one)."""
    if tsdf is None:
        from pointfield.geometry import tsdf

    volume = tsdf.TSDFVolume.create(*BOX, resolution, truncation_voxels=TRUNCATION_VOXELS, device=device)
    return tsdf.fuse(volume, [(torch.from_numpy(d), torch.from_numpy(c)) for d, c in zip(depths, colours)], cameras)


def tsdf_at(commit: str):
    """pointfield's ``geometry/tsdf.py`` as it was at ``commit``, loaded as a module of its own."""
    try:
        source = subprocess.run(["git", "show", f"{commit}:src/pointfield/geometry/tsdf.py"], cwd=ROOT,
                                capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError) as error:
        raise SystemExit(f"--before {commit}: cannot read src/pointfield/geometry/tsdf.py at that commit ({error})") from None
    name = f"tsdf_at_{commit}"
    path = Path(tempfile.mkdtemp()) / f"{name}.py"
    path.write_text(source, encoding="utf-8")
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up by name
    spec.loader.exec_module(module)
    return module


def room_frames(folder: Path, count: int):
    """The first ``count`` frames of the living room as ``scene from-rgbd`` reads them, at open3d's poses, and their box."""
    from pointfield.scenes.cameras import Cameras
    from pointfield.scenes.rgbd import read_colour, read_depth, read_intrinsics, read_log_trajectory, read_rgbd_folder

    sequence = read_rgbd_folder(folder).subset(count)
    camera = read_intrinsics(folder / "camera_primesense.json")
    poses = read_log_trajectory(folder / "open3d_trajectory.log")[:count]
    depths = [read_depth(path, camera, 1000.0, ROOM_DEPTH_MAX) for path in sequence.depth]
    colours = [read_colour(path, camera) for path in sequence.colour]
    rows, columns = np.nonzero(np.ones((camera.height, camera.width), bool))
    local = np.stack([(columns + 0.5 - camera.cx) / camera.fx, (rows + 0.5 - camera.cy) / camera.fy,
                      np.ones(len(rows))], -1)
    world = np.concatenate([(local * d.reshape(-1, 1))[d.reshape(-1) > 0] @ pose[:3, :3].T + pose[:3, 3]
                            for d, pose in zip(depths, poses)])
    pad = 5 * ROOM_VOXEL
    box = (world.min(axis=0) - pad, world.max(axis=0) + pad)
    cameras = Cameras(torch.as_tensor(poses), camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height)
    return cameras, depths, colours, box


def fuse_room_pointfield(cameras, depths, colours, box, tsdf=None):
    """As ``scene from-rgbd`` fuses: only the blocks near each frame's surface, the depth of the pixel a voxel falls in."""
    if tsdf is None:
        from pointfield.geometry import tsdf

    resolution = max(2, math.ceil(float(np.max(box[1] - box[0])) / ROOM_VOXEL))
    volume = tsdf.TSDFVolume.create(*box, resolution, truncation_voxels=TRUNCATION_VOXELS)
    stride = tsdf.allocation_stride(volume.voxel, float(min(cameras.fx[0], cameras.fy[0])), ROOM_DEPTH_MAX)
    for index, (depth, colour) in enumerate(zip(depths, colours)):
        volume.integrate(torch.from_numpy(depth), torch.from_numpy(colour), cameras, index, touched_only=True,
                         pixel_stride=stride, interpolate=False)
    return volume


def fuse_room_open3d(cameras, depths, colours, box):
    """open3d's VoxelBlockGrid on the same frames and poses, as its reconstruction system fuses them."""
    import open3d as o3d
    import open3d.core as o3c

    grid = o3d.t.geometry.VoxelBlockGrid(
        attr_names=("tsdf", "weight", "color"), attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
        attr_channels=((1), (1), (3)), voxel_size=ROOM_VOXEL, block_resolution=8, block_count=50_000,
        device=o3c.Device("CPU:0"))
    world_to_camera = cameras.world_to_camera().double().numpy()
    intrinsic = o3c.Tensor(_intrinsics(cameras, 0))
    for index, (depth, colour) in enumerate(zip(depths, colours)):
        extrinsic = o3c.Tensor(world_to_camera[index])
        depth_image = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(depth.astype(np.float32))))
        colour_image = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(colour.astype(np.float32))))
        blocks = grid.compute_unique_block_coordinates(depth_image, intrinsic, extrinsic, 1.0, ROOM_DEPTH_MAX,
                                                       trunc_voxel_multiplier=TRUNCATION_VOXELS)
        grid.integrate(blocks, depth_image, colour_image, intrinsic, intrinsic, extrinsic, 1.0, ROOM_DEPTH_MAX,
                       trunc_voxel_multiplier=TRUNCATION_VOXELS)
    return grid


@contextmanager
def nearest_pixel_depth() -> Iterator[None]:
    """While the block runs, pointfield's fusion takes each voxel's depth from the pixel it falls in
    (the classic rule: Curless and Levoy, open3d) instead of interpolating between the four pixel
    centres around it (:func:`pointfield.geometry.tsdf.interpolated_depth`): every
    :meth:`~pointfield.geometry.tsdf.TSDFVolume.integrate` runs with ``interpolate=False``, the
    package's own nearest-pixel rule (what ``scene from-rgbd`` uses for sensor depth finer than its
    voxels). Exports always interpolate; this measures what that gains against the other rule."""
    from pointfield.geometry import tsdf

    integrate = tsdf.TSDFVolume.integrate

    def nearest(self, *arguments, **options):
        return integrate(self, *arguments, **{**options, "interpolate": False})

    with mock.patch.object(tsdf.TSDFVolume, "integrate", nearest):
        yield


def fuse_pointfield_nearest(cameras, depths, colours, resolution: int):
    with nearest_pixel_depth():
        return fuse_pointfield(cameras, depths, colours, resolution)


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
        k = _intrinsics(cameras, index)
        intrinsic = o3d.camera.PinholeCameraIntrinsic(width, height, k[0, 0], k[1, 1], k[0, 2], k[1, 2])
        volume.integrate(_rgbd(depth, colour), intrinsic, world_to_camera[index])
    return volume


def _intrinsics(cameras, index: int) -> np.ndarray:
    """The 3 x 3 intrinsic matrix in open3d's convention (pixel centres at integers, not + 0.5)."""
    return np.array([[float(cameras.fx[index]), 0.0, float(cameras.cx[index]) - 0.5],
                     [0.0, float(cameras.fy[index]), float(cameras.cy[index]) - 0.5],
                     [0.0, 0.0, 1.0]])


def fuse_open3d_blocks(cameras, depths, colours, resolution: int):
    """open3d's sparse VoxelBlockGrid: each view allocates the blocks near its surface and fuses those."""
    import open3d as o3d
    import open3d.core as o3c

    voxel = (BOX[1][0] - BOX[0][0]) / resolution
    grid = o3d.t.geometry.VoxelBlockGrid(
        attr_names=("tsdf", "weight", "color"), attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
        attr_channels=((1), (1), (3)), voxel_size=voxel, block_resolution=8, block_count=100_000,
        device=o3c.Device("CPU:0"),
    )
    world_to_camera = cameras.world_to_camera().double().numpy()
    for index, (depth, colour) in enumerate(zip(depths, colours)):
        intrinsic = o3c.Tensor(_intrinsics(cameras, index))
        extrinsic = o3c.Tensor(world_to_camera[index])
        depth_image = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(depth)))
        colour_image = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(colour.astype(np.float32))))
        blocks = grid.compute_unique_block_coordinates(depth_image, intrinsic, extrinsic, 1.0, 100.0,
                                                       trunc_voxel_multiplier=TRUNCATION_VOXELS)
        grid.integrate(blocks, depth_image, colour_image, intrinsic, intrinsic, extrinsic, 1.0, 100.0,
                       trunc_voxel_multiplier=TRUNCATION_VOXELS)
    return grid


def legacy_scalable_vertices(cameras, depths, colours, resolution: int) -> int:
    """Vertices of the mesh open3d's legacy ScalableTSDFVolume makes of the same depth maps."""
    import open3d as o3d

    voxel = (BOX[1][0] - BOX[0][0]) / resolution
    volume = o3d.pipelines.integration.ScalableTSDFVolume(
        voxel_length=voxel, sdf_trunc=TRUNCATION_VOXELS * voxel,
        color_type=o3d.pipelines.integration.TSDFVolumeColorType.RGB8)
    world_to_camera = cameras.world_to_camera().double().numpy()
    for index, (depth, colour) in enumerate(zip(depths, colours)):
        height, width = depth.shape
        k = _intrinsics(cameras, index)
        intrinsic = o3d.camera.PinholeCameraIntrinsic(width, height, k[0, 0], k[1, 1], k[0, 2], k[1, 2])
        volume.integrate(_rgbd(depth, colour), intrinsic, world_to_camera[index])
    return len(volume.extract_triangle_mesh().vertices)


def cube_distance_in_voxels(vertices: np.ndarray, resolution: int) -> tuple[float, float]:
    voxel = (BOX[1][0] - BOX[0][0]) / resolution
    distance = np.abs(np.abs(vertices).max(axis=1) - 0.5) / voxel
    return float(np.median(distance)), float(np.percentile(distance, 95))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=int, default=256, help="voxels along a side (default 256)")
    parser.add_argument("--repeats", type=int, default=2, help="timed rounds per contender (default 2)")
    parser.add_argument("--frames", type=int, default=15, help="living-room frames fused in the second table (default 15; 0: no such table)")
    parser.add_argument("--before", metavar="COMMIT", help="also time pointfield's fusion as it was at this commit")
    args = parser.parse_args()
    before = tsdf_at(args.before) if args.before else None
    earlier = f"pointfield at {args.before}"
    import open3d as o3d

    from pointfield.geometry.meshes import mesh_from_volume

    record = Record("tsdf", "TSDF fusion against open3d on the same depth maps", issue="14",
                    about="The synthetic cube's exact depth maps fused over [-1, 1]^3 at "
                          f"{args.resolution}^3, truncation 4 voxels, by pointfield (PyTorch, sparse voxel "
                          "blocks, CPU; also with the nearest pixel's depth instead of the interpolated one) "
                          f"and open3d {o3d.__version__}'s VoxelBlockGrid (sparse) and "
                          "UniformTSDFVolume (dense), interleaved in one run; meshes from each one's "
                          "marching cubes, compared with the true cube surface.")
    contenders = {"pointfield": fuse_pointfield, "pointfield, nearest pixel": fuse_pointfield_nearest,
                  "open3d VoxelBlockGrid": fuse_open3d_blocks, "open3d UniformTSDFVolume": fuse_open3d}
    if before is not None:
        contenders[earlier] = lambda *arguments: fuse_pointfield(*arguments, tsdf=before)
    meshers = {
        earlier: lambda volume: mesh_from_volume(volume).points,
        "pointfield": lambda volume: mesh_from_volume(volume).points,
        "pointfield, nearest pixel": lambda volume: mesh_from_volume(volume).points,
        "open3d VoxelBlockGrid": lambda grid: grid.extract_triangle_mesh(weight_threshold=0.0).vertex.positions.numpy(),
        "open3d UniformTSDFVolume": lambda volume: np.asarray(volume.extract_triangle_mesh().vertices),
    }
    rows = []
    for views, size in ((24, 100), (8, 800)):
        cameras, depths, colours = cube_views(views, size)
        timings = interleaved({
            name: lambda f=fuse, c=cameras, d=depths, k=colours: f(c, d, k, args.resolution)
            for name, fuse in contenders.items()
        }, repeats=args.repeats)
        for name, fuse in contenders.items():
            vertices = meshers[name](fuse(cameras, depths, colours, args.resolution))
            median, p95 = cube_distance_in_voxels(vertices, args.resolution) if len(vertices) else (np.nan, np.nan)
            rows.append([f"{size}x{size}", views, name, f"{views / timings[name].median:.2f}",
                         f"{timings[name].median:.2f}", f"{timings[name].spread:.2f}", f"{median:.2f}", f"{p95:.2f}"])
        record.figures[f"{size}"] = {name: timings[name].as_dict() for name in timings}
        ours = timings["pointfield"].median
        record.note(f"{size}x{size}: pointfield fuses at "
                    + ", ".join(f"{timings[name].median / ours:.2f}x {name}'s speed" for name in contenders if name != "pointfield")
                    + f" ({ours:.2f} s for {views} maps).")
        if size == 100:
            legacy = legacy_scalable_vertices(cameras, depths, colours, args.resolution)
            record.figures["open3d_legacy_scalable_vertices"] = legacy
            record.note(f"open3d's legacy ScalableTSDFVolume makes a mesh of {legacy} vertices of the same 24 maps.")
    record.table(["depth maps", "views", "library", "maps per s", "median s", "spread",
                  "median distance (voxels)", "95th pct distance (voxels)"], rows,
                 title=f"Fusing the cube's exact depth at {args.resolution}^3 (2 cores)")
    if args.frames and ROOM.is_dir():
        room_table(record, args.frames, args.repeats, before, earlier)
    elif args.frames:
        record.note(f"The living-room frames are not here ({ROOM}); no second table.")
    return record.finish()


def room_table(record: Record, count: int, repeats: int, before, earlier: str) -> None:
    """The second table (module docstring): sensor frames fused as scene from-rgbd fuses them, and their meshes."""
    from scipy.spatial import cKDTree

    from pointfield.geometry.meshes import mesh_from_volume

    cameras, depths, colours, box = room_frames(ROOM, count)
    contenders = {"pointfield": fuse_room_pointfield, "open3d VoxelBlockGrid": fuse_room_open3d}
    if before is not None:
        contenders[earlier] = lambda *arguments: fuse_room_pointfield(*arguments, tsdf=before)
    timings = interleaved({name: lambda f=fuse: f(cameras, depths, colours, box) for name, fuse in contenders.items()},
                          repeats=repeats)
    meshes = {}
    for name, fuse in contenders.items():
        volume = fuse(cameras, depths, colours, box)
        started = time.perf_counter()
        if name.startswith("pointfield"):
            vertices = mesh_from_volume(volume).points
        else:
            vertices = volume.extract_triangle_mesh(weight_threshold=1.0).vertex.positions.numpy()
        meshes[name] = (vertices, time.perf_counter() - started)
    ours = meshes["pointfield"][0]
    rows = []
    for name in contenders:
        vertices, seconds = meshes[name]
        distance = cKDTree(vertices).query(ours)[0] / ROOM_VOXEL
        rows.append([name, f"{count / timings[name].median:.2f}", f"{timings[name].median:.2f}",
                     f"{timings[name].spread:.2f}", f"{seconds:.2f}", len(vertices),
                     f"{np.median(distance):.3f}", f"{np.percentile(distance, 95):.3f}"])
    record.figures["room"] = {name: timings[name].as_dict() for name in timings}
    record.table(["library", "frames per s", "median s", "spread", "mesh s", "vertices",
                  "pointfield's vertices to this mesh, median (voxels)", "95th pct (voxels)"], rows,
                 title=f"Fusing {count} living-room frames (640 x 480) as scene from-rgbd does, at open3d's poses, "
                       f"1 cm voxels (threads: OMP_NUM_THREADS or torch's)")
    ours = timings["pointfield"].median
    record.note(f"living room: pointfield fuses {count} frames in {ours:.2f} s, "
                + ", ".join(f"{timings[name].median / ours:.2f}x the speed of {name}" for name in contenders
                            if name != "pointfield") + ".")


if __name__ == "__main__":
    sys.exit(main())
