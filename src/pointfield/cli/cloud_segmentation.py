"""``pointfield cloud planes|clusters|ground``: classical segmentation, labels written back as a field.

Each is a thin layer over a function of :mod:`pointfield.segmentation`:

=============================  =====================================================  ==================
``pointfield cloud planes``    :func:`pointfield.segmentation.segment_planes`          field ``plane``
``pointfield cloud clusters``  :func:`pointfield.segmentation.dbscan`                  field ``cluster``
``pointfield cloud ground``    :func:`pointfield.segmentation.ground_mask` (CSF)       ``classification``
=============================  =====================================================  ==================

Labels are int32 with -1 for none (planes, clusters) and LAS classes for ground (2 ground, the
file's own class elsewhere), so every format that holds the field keeps them.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from pointfield.errors import PointfieldError


def add_commands(commands: argparse._SubParsersAction) -> None:
    """Add planes, clusters and ground to the ``cloud`` subcommands."""
    planes = commands.add_parser(
        "planes", help="RANSAC planes, largest first, with their equations (field 'plane')",
        description="Find up to --count planes one after another (RANSAC, refitted by least squares), largest "
        "first; print each as a x + b y + c z + d = 0 with its point count, and write IN to OUT with an int32 "
        "field 'plane' (the plane's index, -1 for none).")
    planes.add_argument("source", type=Path, metavar="IN")
    planes.add_argument("destination", type=Path, metavar="OUT")
    planes.add_argument("--count", type=int, default=1, metavar="N", help="planes to find (default 1)")
    planes.add_argument("--distance", type=float, metavar="D",
                        help="inlier distance (default: 1 %% of the bounding-box diagonal)")
    planes.add_argument("--iterations", type=int, default=1000, help="RANSAC samples per plane at most (default 1000)")
    planes.add_argument("--seed", type=int, default=0, help="RANSAC seed (default 0)")
    planes.add_argument("--json", action="store_true", help="print the planes as JSON")
    planes.set_defaults(run=run_planes)

    clusters = commands.add_parser(
        "clusters", help="DBSCAN / Euclidean clusters, largest first (field 'cluster')",
        description="Cluster IN by density (DBSCAN: points with --min-points within --eps are cores, cores "
        "within --eps join; --min-points 1 gives PCL's Euclidean clusters) and write it to OUT with an int32 "
        "field 'cluster' (0 the largest, -1 noise).")
    clusters.add_argument("source", type=Path, metavar="IN")
    clusters.add_argument("destination", type=Path, metavar="OUT")
    clusters.add_argument("--eps", type=float, metavar="E", help="neighbour distance (default: 3 x the median point spacing)")
    clusters.add_argument("--min-points", type=int, default=10, metavar="M", help="points within E of a core (default 10)")
    clusters.add_argument("--planes", action="store_true",
                          help="IN's field 'plane' (from `cloud planes`) first: each plane one cluster, DBSCAN on the "
                          "other points, so that objects standing on a table are not joined to it (PCL's table top)")
    clusters.add_argument("--json", action="store_true", help="print the cluster sizes as JSON")
    clusters.set_defaults(run=run_clusters)

    ground = commands.add_parser(
        "ground", help="ground / non-ground of lidar by the cloth simulation filter (LAS class 2)",
        description="Drop a simulated cloth on the upside-down cloud (CSF, Zhang et al. 2016) and write IN to OUT "
        "with a 'classification' field: 2 (ground) where the cloth rests, the file's own class elsewhere (1 where "
        "it said ground). Where IN has classes, the IoU of the two ground sets is printed.")
    ground.add_argument("source", type=Path, metavar="IN")
    ground.add_argument("destination", type=Path, metavar="OUT")
    ground.add_argument("--resolution", type=float, metavar="R",
                        help="cloth particle spacing (default: 2 x the points' mean x-y spacing)")
    ground.add_argument("--rigidness", type=int, choices=(1, 2, 3), default=2,
                        help="1 steep slopes, 2 relief, 3 flat land (default 2)")
    ground.add_argument("--threshold", type=float, metavar="T",
                        help="distance to the cloth that is still ground (default: the resolution / 2)")
    ground.add_argument("--no-slope-smooth", dest="slope_smooth", action="store_false",
                        help="skip CSF's post-processing of steep slopes")
    ground.add_argument("--json", action="store_true", help="print the summary as JSON")
    ground.set_defaults(run=run_ground)


def _read(path: Path):
    import pointfield

    cloud = pointfield.read(path)
    if len(cloud) - cloud.nan_count < 3:
        raise PointfieldError(f"{path}: {len(cloud) - cloud.nan_count} finite points; segmentation needs at least 3")
    return cloud


def _write(path: Path, cloud, name: str, labels: np.ndarray) -> None:
    import pointfield

    pointfield.write(path, pointfield.PointCloud(cloud.points, {**cloud.fields, name: labels}, cloud.shape,
                                                 dict(cloud.metadata)))


def run_planes(args: argparse.Namespace) -> int:
    from pointfield.segmentation import segment_planes

    if args.count < 1:
        raise PointfieldError(f"--count must be at least 1, got {args.count}")
    if args.distance is not None and not args.distance > 0:
        raise PointfieldError(f"--distance must be positive, got {args.distance}")
    cloud = _read(args.source)
    planes, labels = segment_planes(cloud.points, args.count, args.distance, iterations=args.iterations, seed=args.seed)
    _write(args.destination, cloud, "plane", labels)
    if args.json:
        print(json.dumps({"planes": [p.as_dict() for p in planes], "points": len(cloud)}, indent=2))
        return 0
    for index, plane in enumerate(planes):
        a, b, c, d = plane.equation
        print(f"plane {index}: {a:+.6f} x {b:+.6f} y {c:+.6f} z {d:+.6f} = 0  ({len(plane.inliers):,} points)")
    print(f"wrote {args.destination}: {len(cloud):,} points, {(labels >= 0).sum():,} in {len(planes)} plane(s) (field 'plane')")
    return 0


def run_clusters(args: argparse.Namespace) -> int:
    from scipy.spatial import cKDTree

    from pointfield.clouds.ops import finite_rows
    from pointfield.segmentation import clusters_beside_planes, dbscan

    cloud = _read(args.source)
    if args.planes and "plane" not in cloud.fields:
        raise PointfieldError(f"{args.source}: --planes needs the field 'plane' that `pointfield cloud planes` writes; "
                              f"the cloud has {', '.join(cloud.fields) or 'no fields'}")
    eps = args.eps
    if eps is None:
        finite = cloud.points[finite_rows(cloud.points)].astype(np.float64)
        sample = finite[np.random.default_rng(0).choice(len(finite), min(len(finite), 5000), replace=False)]
        eps = 3.0 * float(np.median(cKDTree(finite).query(sample, k=2)[0][:, 1]))
        print(f"eps {eps:.4g} = 3 x the median point spacing; set --eps to override")
    elif not eps > 0:
        raise PointfieldError(f"--eps must be positive, got {eps}")
    labels = (clusters_beside_planes(cloud.points, cloud.fields["plane"], eps, args.min_points) if args.planes
              else dbscan(cloud.points, eps, args.min_points))
    _write(args.destination, cloud, "cluster", labels)
    sizes = np.bincount(labels[labels >= 0]) if (labels >= 0).any() else np.zeros(0, np.int64)
    if args.json:
        print(json.dumps({"eps": eps, "clusters": sizes.tolist(), "noise": int((labels < 0).sum())}, indent=2))
        return 0
    shown = ", ".join(f"{s:,}" for s in sizes[:10]) + (", ..." if len(sizes) > 10 else "")
    print(f"wrote {args.destination}: {len(sizes)} clusters ({shown} points), {(labels < 0).sum():,} noise "
          "(field 'cluster')")
    return 0


def run_ground(args: argparse.Namespace) -> int:
    from pointfield.segmentation import default_cloth_resolution, ground_classification, ground_mask, iou

    cloud = _read(args.source)
    resolution = args.resolution
    if resolution is None:
        resolution = default_cloth_resolution(cloud.points)
        print(f"cloth resolution {resolution:.4g} = 2 x the mean x-y spacing; set --resolution to override")
    threshold = resolution / 2 if args.threshold is None else args.threshold
    mask = ground_mask(cloud.points, cloth_resolution=resolution, rigidness=args.rigidness, class_threshold=threshold,
                       slope_smooth=args.slope_smooth)
    own = cloud.fields.get("classification")
    summary = {"points": len(cloud), "ground": int(mask.sum()), "resolution": resolution, "rigidness": args.rigidness,
               "threshold": threshold, "slope_smooth": args.slope_smooth}
    if own is not None and (np.asarray(own) == 2).any():
        summary["iou_with_file_labels"] = iou(mask, np.asarray(own) == 2)
    _write(args.destination, cloud, "classification", ground_classification(mask, own))
    if args.json:
        print(json.dumps(summary, indent=2))
        return 0
    agreement = (f"; ground IoU with the file's own class 2: {summary['iou_with_file_labels']:.3f}"
                 if "iou_with_file_labels" in summary else "")
    print(f"wrote {args.destination}: {summary['ground']:,} of {len(cloud):,} points ground (class 2){agreement}")
    return 0
