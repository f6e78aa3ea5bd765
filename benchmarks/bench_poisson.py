"""Oriented points to a watertight mesh: pointfield's FFT Poisson against open3d's screened Poisson, same run.

The claim (issue 46): :func:`pointfield.volumes.poisson.poisson_surface` -- Poisson surface
reconstruction on a regular grid solved by the FFT, with no screening term and no octree -- gives a
closed mesh as close to the points as open3d's ``create_from_point_cloud_poisson`` (PoissonRecon's
screened Poisson on an octree) at the same depth, and says what it costs in time.

The cloud is shared/data's Armadillo (38,294 points with normals). Both run at ``--depth`` (default 8:
256 cells across the box grown by 1.1, the same finest cell), one run each (ours first, then
open3d's; the machine is shared, so times are noisy). Each mesh is scored against the input points
(:func:`pointfield.geometry.compare.surface_scores`, 200,000 samples of the mesh's surface):
Chamfer distance, accuracy and completeness as fractions of the points' bounding-box diagonal, and
F-score at half a percent of it; and whether every edge is shared by two faces (watertight).

Run: ``python benchmarks/bench_poisson.py`` (``make bench-poisson``); the record goes to
``benchmarks/records/poisson.json``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from harness import Record

ARMADILLO = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "ply" / "armadillo_points_normals_ascii.ply"


def main() -> int:
    import open3d as o3d
    import trimesh

    import pointfield
    from pointfield.clouds.mesh import Mesh
    from pointfield.geometry.compare import sample_mesh, surface_scores
    from pointfield.volumes.poisson import poisson_surface

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--depth", type=int, default=8, help="2^depth cells across the box (default 8)")
    args = parser.parse_args()
    if not ARMADILLO.is_file():
        raise SystemExit(f"no Armadillo at {ARMADILLO}")
    cloud = pointfield.read(ARMADILLO)
    low, high = cloud.bounds()
    diagonal = float(np.linalg.norm(np.asarray(high, np.float64) - low))
    record = Record(
        "poisson", "Oriented points to a watertight mesh: FFT Poisson against open3d's screened Poisson", issue="46",
        about="`volumes.poisson_surface` (Poisson's equation on a regular 2^depth grid over the box grown by 1.1, "
              "solved by the FFT; no screening, no octree) against open3d's create_from_point_cloud_poisson at the "
              f"same depth ({args.depth}), in the same run, on shared/data's Armadillo ({len(cloud):,} points with "
              "normals). Scores against the input points, 200,000 samples of each mesh; distances as fractions of "
              "the points' diagonal. The machine was shared with other jobs: one run each, times noisy.")

    def ours() -> Mesh:
        return poisson_surface(cloud, depth=args.depth)

    def theirs() -> Mesh:
        points = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud.points.astype(np.float64)))
        points.normals = o3d.utility.Vector3dVector(cloud.fields["normals"].astype(np.float64))
        mesh, _ = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(points, depth=args.depth)
        return Mesh(np.asarray(mesh.vertices), faces=np.asarray(mesh.triangles).astype(np.int32))

    rows, figures = [], {}
    for name, build in (("pointfield", ours), ("open3d", theirs)):
        start = time.perf_counter()
        mesh = build()
        seconds = time.perf_counter() - start
        scores = surface_scores(sample_mesh(mesh, 200_000), cloud.points, 0.005 * diagonal, unit=diagonal)
        watertight = bool(trimesh.Trimesh(mesh.points, mesh.faces, process=True).is_watertight)
        figures[name] = {"seconds": seconds, "faces": len(mesh.faces), "watertight": watertight,
                         **{k: v for k, v in scores.items() if isinstance(v, float)}}
        rows.append([name, f"{seconds:.1f}", f"{len(mesh.faces):,}", "yes" if watertight else "no",
                     f"{scores['chamfer_relative']:.3%}", f"{scores['accuracy_relative']:.3%}",
                     f"{scores['completeness_relative']:.3%}", f"{scores['fscore']:.3f}"])
        print(rows[-1], flush=True)
    record.figures.update({"depth": args.depth, "points": len(cloud), "diagonal": diagonal, **figures})
    record.table(["mesher", "seconds", "faces", "watertight", "Chamfer", "accuracy", "completeness", "F-score"], rows,
                 title=f"Armadillo, depth {args.depth}; distances as fractions of the diagonal {diagonal:.1f}, "
                       "F-score at 0.5 % of it")
    ours_f, theirs_f = figures["pointfield"], figures["open3d"]
    record.verdict("pointfield's mesh is watertight", ours_f["watertight"])
    record.verdict("its Chamfer to the points is at most open3d's", ours_f["chamfer_relative"] <= theirs_f["chamfer_relative"],
                   f"{ours_f['chamfer_relative']:.3%} against {theirs_f['chamfer_relative']:.3%}")
    record.note(f"time: pointfield {ours_f['seconds']:.1f} s, open3d {theirs_f['seconds']:.1f} s "
                f"({ours_f['seconds'] / theirs_f['seconds']:.1f}x)")
    return record.finish()


if __name__ == "__main__":
    sys.exit(main())
