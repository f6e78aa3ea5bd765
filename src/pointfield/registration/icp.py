"""Fine registration from a starting pose: the ICP loop, its small_gicp fast path, and coarse to fine.

:func:`registration_icp` is open3d's ``registration_icp`` in numpy and scipy: find each moved
source point's nearest target point within ``max_distance`` (a k-d tree), let the estimation
object (:mod:`pointfield.registration.estimation`) compute a motion from those pairs, apply it on
the left, and stop when fitness and inlier RMSE change by less than the criteria's relative
tolerances or after ``max_iteration`` rounds. It is the reference every variant runs through,
coloured ICP and the robust kernels included.

:func:`registration_small_gicp` runs point-to-point, point-to-plane and generalized ICP in
small_gicp's compiled, multi-threaded solver, then measures fitness and RMSE exactly as the
reference does. docs/registration.md gives the measurement behind using it by default for those
three (``make bench-registration``).

:func:`multiscale_icp` runs either over a pyramid of voxel sizes, coarse to fine, each level
starting from the last one's answer: a wide basin first, the precision of the full clouds last.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from pointfield.registration.estimation import ColoredICP, GeneralizedICP, PointToPlane, PointToPoint
from pointfield.registration.result import (
    RegistrationResult,
    correspondences,
    evaluate,
    information_matrix,
    transform_points,
)
from pointfield.registration.scan import Scan, spatial_order

Estimation = PointToPoint | PointToPlane | GeneralizedICP | ColoredICP

SMALL_GICP_TYPES = {PointToPoint: "ICP", PointToPlane: "PLANE_ICP", GeneralizedICP: "GICP"}
"""The estimations small_gicp solves, by its name for them."""


@dataclass(frozen=True)
class ICPConvergenceCriteria:
    """Stop when fitness and inlier RMSE both change by less than these fractions, or after ``max_iteration``."""

    relative_fitness: float = 1e-6
    relative_rmse: float = 1e-6
    max_iteration: int = 30


def registration_icp(source: Scan, target: Scan, max_distance: float, init: np.ndarray | None = None,
                     estimation: Estimation | None = None,
                     criteria: ICPConvergenceCriteria = ICPConvergenceCriteria()) -> RegistrationResult:
    """Refine ``init`` (default identity) so that ``source`` lies on ``target``; pairs farther than ``max_distance`` are ignored.

    Returns a :class:`~pointfield.registration.result.RegistrationResult` measured at ``max_distance``.
    """
    estimation = estimation or PointToPoint()
    source, target = estimation.prepare(source, target)
    transformation = np.eye(4) if init is None else np.asarray(init, np.float64).copy()
    fitness, rmse, pairs = evaluate(source.points, target.tree, transformation, max_distance)
    iterations = 0
    while iterations < criteria.max_iteration and len(pairs) >= 3:
        iterations += 1
        moved = transform_points(source.points, transformation)
        step = estimation.step(moved, source, target, pairs, transformation[:3, :3])
        transformation = step @ transformation
        previous = fitness, rmse
        fitness, rmse, pairs = evaluate(source.points, target.tree, transformation, max_distance)
        if (abs(fitness - previous[0]) <= criteria.relative_fitness * max(fitness, 1e-12)
                and abs(rmse - previous[1]) <= criteria.relative_rmse * max(rmse, 1e-12)):
            break
    return RegistrationResult(transformation, fitness, rmse, pairs, information_matrix(target.points, pairs),
                              estimation.name, max_distance=max_distance, iterations=iterations)


def registration_small_gicp(source: Scan, target: Scan, max_distance: float, init: np.ndarray | None = None,
                            estimation: Estimation | None = None,
                            criteria: ICPConvergenceCriteria = ICPConvergenceCriteria(),
                            threads: int | None = None) -> RegistrationResult:
    """The same as :func:`registration_icp` for point-to-point, point-to-plane and generalized ICP, in small_gicp.

    small_gicp estimates its own normals (point-to-plane) or covariances (generalized ICP) from 20
    neighbours on ``threads`` threads (default :func:`solver_threads`) and stops when a step
    turns less than 0.01 degree and moves less than 1e-4 of ``max_distance``. Fitness, RMSE and
    the correspondences are then measured as :func:`~pointfield.registration.result.evaluate`
    does, by the same nearest-neighbour rule, so both paths report the same quantities.

    Both clouds go to small_gicp in :func:`~pointfield.registration.scan.spatial_order`, so that
    consecutive queries walk nearby branches of the k-d tree (a scan sampled or stored in random
    order otherwise spends most of each iteration on cache misses), and the target's k-d tree is
    built once, for the normals, the solver and the final measurement.
    """
    import small_gicp

    estimation = estimation or PointToPoint()
    kind = SMALL_GICP_TYPES.get(type(estimation))
    if kind is None:
        raise ValueError(f"small_gicp has no {estimation.name}; use registration_icp")
    threads = threads or solver_threads(len(source) + len(target))
    source_order, target_order = spatial_order(source.points), spatial_order(target.points)
    source_points = source.points[source_order]
    target_cloud, source_cloud = small_gicp.PointCloud(target.points[target_order]), small_gicp.PointCloud(source_points)
    target_tree = small_gicp.KdTree(target_cloud, num_threads=threads)
    if kind == "PLANE_ICP":
        small_gicp.estimate_normals(target_cloud, target_tree, num_neighbors=20, num_threads=threads)
    elif kind == "GICP":
        small_gicp.estimate_covariances(target_cloud, target_tree, num_neighbors=20, num_threads=threads)
        small_gicp.estimate_covariances(source_cloud, small_gicp.KdTree(source_cloud, num_threads=threads),
                                        num_neighbors=20, num_threads=threads)
    init = np.eye(4) if init is None else np.asarray(init, np.float64)
    solved = small_gicp.align(target_cloud, source_cloud, target_tree, init_T_target_source=init,
                              registration_type=kind, max_correspondence_distance=max_distance,
                              num_threads=threads, max_iterations=criteria.max_iteration,
                              rotation_epsilon=np.radians(0.01), translation_epsilon=1e-4 * max_distance)
    transformation = np.asarray(solved.T_target_source, np.float64)
    # evaluate()'s measurement through the tree already built: each moved source point's nearest
    # target within max_distance, the pairs in the caller's indices, by source index.
    nearest, squared = target_tree.batch_nearest_neighbor_search(transform_points(source_points, transformation),
                                                                 num_threads=threads)
    nearest, squared = np.asarray(nearest, np.int64), np.asarray(squared, np.float64)
    found = (nearest >= 0) & (squared <= max_distance**2)
    pairs = np.stack([source_order[found], target_order[nearest[found]]], axis=1)
    by_source = np.argsort(pairs[:, 0], kind="stable")
    pairs, squared = pairs[by_source], squared[found][by_source]
    fitness = len(pairs) / len(source) if len(source) else 0.0
    rmse = float(np.sqrt(squared.mean())) if len(pairs) else 0.0
    return RegistrationResult(transformation, fitness, rmse, pairs, information_matrix(target.points, pairs),
                              f"{estimation.name} (small_gicp)", max_distance=max_distance,
                              iterations=int(solved.iterations))


def solver_threads(points: int) -> int:
    """Threads for small_gicp: ``OMP_NUM_THREADS`` when set, else one below 50,000 points, else every core.

    Below that the work per iteration is too small to share: the fragments of open3d's tutorial
    (7,400 points) took 0.09 s on one thread and 0.55 s on two of a busy 2-core machine.
    """
    if os.environ.get("OMP_NUM_THREADS", "").isdigit():
        return max(1, int(os.environ["OMP_NUM_THREADS"]))
    if points < 50_000:
        return 1
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def fine_registration(source: Scan, target: Scan, max_distance: float, init: np.ndarray | None,
                      estimation: Estimation, backend: str = "auto",
                      criteria: ICPConvergenceCriteria = ICPConvergenceCriteria()) -> RegistrationResult:
    """One ICP at one scale: small_gicp where it solves this estimation with plain least squares
    (``backend="auto"``), else the numpy reference; ``backend="numpy"`` or ``"small_gicp"`` forces one."""
    plain = type(estimation.kernel).__name__ == "L2Loss"
    if backend == "small_gicp" or (backend == "auto" and plain and type(estimation) in SMALL_GICP_TYPES):
        return registration_small_gicp(source, target, max_distance, init, estimation, criteria)
    if backend not in ("auto", "numpy"):
        raise ValueError(f"unknown backend {backend!r}: expected auto, numpy or small_gicp")
    return registration_icp(source, target, max_distance, init, estimation, criteria)


def multiscale_icp(source: Scan, target: Scan, voxels: Sequence[float], max_distances: Sequence[float],
                   init: np.ndarray | None, estimation: Estimation, backend: str = "auto",
                   criteria: ICPConvergenceCriteria = ICPConvergenceCriteria()) -> RegistrationResult:
    """ICP at each voxel size in turn (0 = the scans as they are), each level from the last one's motion.

    ``voxels`` and ``max_distances`` pair up, coarse first, e.g. ``[4v, 2v, 0]`` with ``[4v, 2v, v]``
    (open3d's ``multi_scale_icp``). A robust kernel's scale ``k`` holds at the last level and grows
    with the distance at coarser ones (residuals there are larger, and a Tukey kernel would
    otherwise drop them all). The result is the last level's, with ``iterations`` summed.
    """
    transformation = np.eye(4) if init is None else np.asarray(init, np.float64)
    result, total = None, 0
    for voxel, distance in zip(voxels, max_distances):
        level_source = source.downsample(voxel) if voxel > 0 else source
        level_target = target.downsample(voxel) if voxel > 0 else target
        if len(level_source) < 3 or len(level_target) < 3:
            continue
        level = estimation
        if hasattr(estimation.kernel, "k"):
            level = replace(estimation, kernel=replace(estimation.kernel, k=estimation.kernel.k * distance / max_distances[-1]))
        result = fine_registration(level_source, level_target, distance, transformation, level, backend, criteria)
        transformation, total = result.transformation, total + result.iterations
    if result is None:
        raise ValueError("no level of the pyramid has 3 points in both scans")
    result.iterations = total
    return result


__all__ = ["ICPConvergenceCriteria", "correspondences", "fine_registration", "multiscale_icp",
           "registration_icp", "registration_small_gicp", "solver_threads"]
