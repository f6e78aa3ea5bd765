"""The options of ``nerf export`` and ``splat export`` that give geometry: one definition for both.

Both call :func:`pointfield.geometry.export_cloud` and :func:`~pointfield.geometry.export_mesh`
on the run; see them for what each option does.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path


def add_cloud_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--cloud", type=Path, metavar="OUT",
                        help="write a point cloud of rendered depth (any format pointfield writes: .ply, .pcd, .las, ...)")
    parser.add_argument("--mesh", type=Path, metavar="OUT",
                        help="write a mesh: rendered depth fused into a TSDF, marching cubes (.ply, .off, .obj, .glb)")
    parser.add_argument("--method", choices=("tsdf", "density", "sdf"), default=None,
                        help="mesh: tsdf (the default, except for sdf runs: fuse rendered depth; any run), density "
                        "(marching cubes on the field's density; field runs of a bounded scene, such as ngp on an "
                        "object) or sdf (the default for nerf train --model sdf runs: the zero level set, closed)")
    parser.add_argument("--threshold", type=float,
                        help="mesh, density: the density level of the surface (default: 2.5 / the field box's "
                        "longest side, instant-ngp's level)")
    parser.add_argument("--resolution", type=int, default=256,
                        help="mesh: voxels along the box's longest side (default 256)")
    parser.add_argument("--faces", type=int, help="mesh: decimate to at most this many triangles")
    parser.add_argument("--path", choices=("dataset", "orbit", "spiral"), default="dataset",
                        help="cameras to render from (default: the run's training views)")
    parser.add_argument("--frames", type=int, help="cameras of the path, evenly spaced (default: every training view; orbit 60); "
                        "mesh, density: the training views that judge what was seen (default all)")
    parser.add_argument("--points", type=int, help="thin the cloud to this many points (farthest point sampling)")
    parser.add_argument("--min-opacity", type=float, default=0.5,
                        help="pixels less opaque than this give no point (default 0.5)")
    parser.add_argument("--depth", choices=("expected", "median"), default="expected",
                        help="the rendered depth used: expected (default; the opacity-weighted mean) or median "
                        "(where the opacity passes 0.5: no blend of a surface with what lies behind it)")
    parser.add_argument("--crop", type=float, nargs=6, metavar=("X0", "Y0", "Z0", "X1", "Y1", "Z1"),
                        help="keep only points inside this box")
    parser.add_argument("--outlier-neighbours", type=int, default=16,
                        help="drop points far from their N nearest, statistically (default 16; 0 keeps all)")
    parser.add_argument("--device", help="auto (default), cpu, cuda, cuda:N or mps")
    parser.add_argument("--overwrite", action="store_true", help="replace output files that exist (default: refuse)")
    parser.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")


def refuse_existing(args: argparse.Namespace, *outputs: str) -> None:
    """Stop before any work when two of ``outputs`` (attributes of ``args``) name one file, or when one
    exists and ``--overwrite`` was not given, as ``scene from-images`` and the streaming verbs do: two exports naming one file (the splats
    and then a mesh as ``lego.ply``) must not leave the second where the first was expected."""
    from pointfield.errors import PointfieldError

    named = [Path(path) for path in (getattr(args, name, None) for name in outputs) if path is not None]
    if len({path.resolve() for path in named}) < len(named):
        raise PointfieldError(f"one file is named for two outputs ({', '.join(map(str, named))}); give each its own")
    if args.overwrite:
        return
    for path in named:
        if path.exists():
            raise PointfieldError(f"{path} already exists; choose another name or pass --overwrite to replace it")


def export_geometry_of(args: argparse.Namespace) -> None:
    """Run :func:`pointfield.geometry.export_cloud` / ``export_mesh`` as the options ask; print what was written."""
    from pointfield.geometry import export_cloud, export_mesh
    from pointfield.geometry.clouds import cameras_of, open_scene_run, render_views

    run, views = args.run_dir, None
    if args.mesh is not None and args.cloud is not None and args.method in (None, "tsdf"):
        # Both start from the same renders of the same cameras, most of an export's time: render once.
        run = open_scene_run(args.run_dir, args.device)
        views = render_views(run, cameras_of(run, args.path, args.frames), args.progress, depth=args.depth)
    if args.mesh is not None:
        result = export_mesh(
            run, args.mesh, resolution=args.resolution, method=args.method, threshold=args.threshold,
            path=args.path, frames=args.frames, min_opacity=args.min_opacity, depth=args.depth, crop=args.crop,
            faces=args.faces,
            device=args.device, progress=args.progress, views=views,
        )
        grid = "x".join(map(str, result["grid"]))
        if "watertight" in result:  # the zero level set of an sdf run
            from pointfield.volumes.voxels import openness_text

            how = (f"SDF zero level on {grid} nodes over the {result['box_source']}, largest of {result['pieces']} "
                   f"pieces, {openness_text(result['openness'])}")
        elif args.method == "density":
            how = f"density {grid} at {result['threshold']:.3g} over the {result['box_source']}"
        else:
            how = f"TSDF {grid} over the {result['box_source']}, {result['views']} views"
        print(f"wrote {result['faces']:,} faces, {result['vertices']:,} vertices ({how}) to {result['out']}")
    if args.cloud is None:
        return
    result = export_cloud(
        run, args.cloud, path=args.path, frames=args.frames, min_opacity=args.min_opacity, depth=args.depth,
        crop=args.crop, points=args.points, outlier_neighbours=args.outlier_neighbours, device=args.device,
        progress=args.progress, views=views,
    )
    print(f"wrote {result['points']:,} points (of {result['rendered_points']:,} rendered from "
          f"{result['views']} views) to {result['out']}")


def opacity_error_text(metrics: dict) -> str:
    """``"opacity error 0.0123, "`` for a run scored against alpha, else nothing."""
    error = metrics.get("opacity_error")
    return f"opacity error {error:.4f}, " if error is not None and not math.isnan(error) else ""
