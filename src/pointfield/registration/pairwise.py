"""``pointfield.register(source, target)``: pairwise registration that chooses what the clouds allow and says so.

What it decides, when not told (each choice is one sentence of ``result.notes``):

- **voxel** -- from the data, as KISS-ICP derives its parameters: the median distance from a
  point to its nearest neighbour (the scan's own sampling), and never under 1/200 of the
  source's bounding-box diagonal (so that a dense scan is not matched at its noise level).
  Global registration matches features on clouds thinned to ``1.5 voxel`` (normals from
  ``k = 20`` neighbours, FPFH over 5 and RANSAC inliers within 1.5 times that: open3d's
  tutorial values); fine registration ends on the full clouds with an inlier distance of
  ``max_distance`` (default: the voxel; aligned scans sampled at that spacing then find a
  partner for every overlapping point, so fitness reads as the overlap).
- **method** -- ``auto`` runs global registration when no ``init`` is given (nothing says the
  scans start close), then the fine step: coloured ICP where both clouds carry colours and
  the geometry alone leaves a direction free (a wall, a floor, a corridor), else generalized
  ICP, which measured the most accurate of the four on real scans and needs no normals.
- **coarse to fine** -- from a given pose the fine step runs at 4, 2 and 1 voxel then on the full
  clouds; after global registration, at 1 voxel then on the full clouds.

A result whose fitness is below :data:`~pointfield.registration.result.LOW_FITNESS` comes with
a warning, never silently.
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.errors import PointfieldError
from pointfield.registration.estimation import ColoredICP, GeneralizedICP, PointToPlane, PointToPoint
from pointfield.registration.fpfh import compute_fpfh
from pointfield.registration.global_registration import RANSACCriteria, match_features, ransac_on_matches
from pointfield.registration.icp import Estimation, multiscale_icp
from pointfield.registration.kernels import kernel_named
from pointfield.registration.result import RegistrationResult
from pointfield.registration.scan import Scan

METHODS = ("auto", "icp", "plane", "gicp", "colored", "global")
"""``--method`` values: ``auto``, the four fine estimations, and ``global`` (FPFH + RANSAC, then fine)."""

GLOBAL_SCALE = 1.5
"""Global registration thins the scans to this many voxels: features need the shape, not every point
(open3d's tutorial thins its fragments, spaced 0.03, to 0.05)."""
FEATURE_RADIUS = 5.0
"""FPFH radius in voxels (open3d's tutorial)."""
RANSAC_DISTANCE = 1.5
"""RANSAC inlier distance in voxels (open3d's tutorial)."""
FLAT = 0.02
"""Normal spread (:func:`unconstrained_spread`) below which geometry leaves a direction free: normals
within about 8 degrees of one plane's normal, or of one plane (a corridor)."""


def check_cloud(cloud: PointCloud | np.ndarray, name: str = "source") -> Scan:
    """The :class:`Scan` of ``cloud``, or a :class:`PointfieldError` naming ``name`` when it cannot be registered.

    Refused: no points, fewer than 3 finite points. Points with NaN or inf coordinates (the
    invalid returns an organised sensor keeps) are left out of the registration; the aligned
    cloud keeps them where they were.
    """
    if not isinstance(cloud, PointCloud):
        cloud = PointCloud(np.asarray(cloud, np.float64).reshape(-1, 3))
    if len(cloud) == 0:
        raise PointfieldError(f"{name}: the cloud has no points; registration needs at least 3")
    scan = Scan.from_cloud(cloud)
    if len(scan) < 3:
        invalid = len(cloud) - len(scan)
        raise PointfieldError(f"{name}: {len(scan)} finite point{'s' * (len(scan) != 1)} of {len(cloud)} "
                              f"({invalid} with NaN or inf coordinates); registration needs at least 3")
    extent = np.ptp(scan.points, axis=0)
    if not np.any(extent > 0):
        raise PointfieldError(f"{name}: all {len(scan)} points coincide; registration needs a cloud with extent")
    return scan


def check_transformation(matrix: object, name: str = "init") -> np.ndarray:
    """``(4, 4)`` float64 rigid motion, or a :class:`PointfieldError` naming ``name`` and what is wrong.

    Rigid: finite, last row ``0 0 0 1``, ``R^T R = I`` and ``det R = +1`` to 1e-4 (a scale, a shear or a
    mirror is refused: registration estimates motions, and a mirrored cloud cannot be aligned by one).
    """
    try:
        t = np.asarray(matrix, np.float64)
    except (TypeError, ValueError) as error:
        raise PointfieldError(f"{name}: not a 4 x 4 matrix of numbers ({error})") from None
    if t.shape != (4, 4):
        raise PointfieldError(f"{name}: expected a 4 x 4 matrix, got shape {t.shape}")
    if not np.all(np.isfinite(t)):
        raise PointfieldError(f"{name}: the matrix has NaN or infinite entries")
    if not np.allclose(t[3], [0, 0, 0, 1], atol=1e-6):
        raise PointfieldError(f"{name}: last row is {t[3].tolist()}, expected [0, 0, 0, 1]")
    rotation = t[:3, :3]
    error = float(np.abs(rotation.T @ rotation - np.eye(3)).max())
    if error > 1e-4 or np.linalg.det(rotation) < 0:
        what = "a mirror (det < 0)" if np.linalg.det(rotation) < 0 else f"R^T R differs from I by {error:.2g}"
        raise PointfieldError(f"{name}: not a rigid transformation: {what}; expected a rotation and a translation")
    return t


def default_voxel(scan: Scan, sample: int = 5000) -> tuple[float, str]:
    """``(voxel, why)``: the median nearest-neighbour spacing, at least 1/200 of the bounding-box diagonal."""
    rng = np.random.default_rng(0)
    picked = scan.points if len(scan) <= sample else scan.points[rng.choice(len(scan), sample, replace=False)]
    distances, _ = scan.tree.query(picked, k=2, workers=-1)
    spacing = float(np.median(distances[:, 1]))
    diagonal = float(np.linalg.norm(np.ptp(scan.points, axis=0)))
    voxel = max(spacing, diagonal / 200.0)
    rule = "the median point spacing" if spacing >= diagonal / 200.0 else "1/200 of the source's diagonal"
    return voxel, (f"voxel {voxel:.4g} = {rule} (spacing {spacing:.4g}, diagonal {diagonal:.4g}); "
                   "set --voxel to override")


def unconstrained_spread(scan: Scan, sample: int = 20_000) -> float:
    """Smallest eigenvalue of ``mean(n n^T)`` over the scan's normals (a sample of them): near 0 when
    some direction is along every surface -- a plane, a corridor -- so geometry cannot fix a
    translation along it; up to 1/3 for surfaces that face every way."""
    if len(scan) > sample:
        keep = np.random.default_rng(0).choice(len(scan), sample, replace=False)
        scan = Scan(scan.points[keep], None if scan.normals is None else scan.normals[keep])
    normals = scan.with_normals().normals
    return float(np.linalg.eigvalsh(normals.T @ normals / len(normals))[0])


def choose_estimation(method: str, source: Scan, target: Scan, kernel: str | None, scale: float
                      ) -> tuple[Estimation, str]:
    """``(estimation, why)`` for a fine ``method`` (``icp``, ``plane``, ``gicp``, ``colored``) or ``auto``/``global``.

    ``auto``: coloured ICP where both clouds carry colours and the target's geometry leaves a
    direction free (:func:`unconstrained_spread` below :data:`FLAT`); else generalized ICP, the
    most accurate of the four on the fragments and the bunny (docs/registration.md), which
    needs neither normals nor colours.
    """
    robust = kernel_named(kernel, scale)
    fixed = {"icp": PointToPoint, "plane": PointToPlane, "gicp": GeneralizedICP, "colored": ColoredICP}
    if method in fixed:
        if method == "colored" and (source.intensity is None or target.intensity is None):
            missing = " and ".join(n for n, s in (("source", source), ("target", target)) if s.intensity is None)
            raise PointfieldError(f"--method colored needs colours in both clouds; {missing} has none")
        return fixed[method](robust), f"fine step: {fixed[method].name}, as asked"
    if source.intensity is None or target.intensity is None:
        return GeneralizedICP(robust), "fine step: generalized ICP (no colours in both clouds)"
    spread = unconstrained_spread(target)
    if spread < FLAT:
        return ColoredICP(robust), (f"fine step: coloured ICP, as both clouds carry colours and the target's "
                                    f"geometry leaves a direction free (normal spread {spread:.3f} < {FLAT})")
    return GeneralizedICP(robust), (f"fine step: generalized ICP; colours left aside, as the geometry fixes "
                                    f"every direction (normal spread {spread:.3f} >= {FLAT})")


def feature_alignment(source: Scan, target: Scan, voxel: float, seed: int = 0,
                      criteria: RANSACCriteria | None = None) -> tuple[np.ndarray, int]:
    """``(transformation, inlier matches)`` from FPFH features and RANSAC on scans thinned to ``voxel``."""
    # Normals estimated afresh in both, with one orientation rule: a carried normal may follow
    # another convention than the other scan's, and FPFH changes with the normals' signs.
    small = [replace(scan.downsample(voxel), normals=None).with_normals(20) for scan in (source, target)]
    if min(len(s) for s in small) < 3:
        raise PointfieldError(f"fewer than 3 points remain at voxel {voxel:.4g}; give a smaller --voxel")
    features = [compute_fpfh(s.points, s.normals, FEATURE_RADIUS * voxel) for s in small]
    matches = match_features(*features)
    motion, inliers = ransac_on_matches(small[0].points, small[1].points, matches, RANSAC_DISTANCE * voxel,
                                        criteria=criteria or RANSACCriteria(), seed=seed)
    return motion, len(inliers)


def register(source: PointCloud | np.ndarray, target: PointCloud | np.ndarray, method: str = "auto",
             init: np.ndarray | None = None, voxel: float | None = None, max_distance: float | None = None,
             kernel: str | None = None, backend: str = "auto", seed: int = 0) -> RegistrationResult:
    """The rigid motion that maps ``source`` onto ``target``, with the evidence for it.

    ``source``, ``target``: clouds (normals and colours used where present) or ``(N, 3)`` arrays.
    ``method``: one of :data:`METHODS`. ``init``: a ``(4, 4)`` starting motion (fine methods
    start from identity without one). ``voxel``, ``max_distance``: see the module docstring.
    ``kernel``: ``"huber"`` or ``"tukey"`` (scale ``k = max_distance``) against outliers.
    ``backend``: ``"auto"`` (small_gicp for plain point-to-point, point-to-plane and
    generalized ICP), ``"numpy"`` or ``"small_gicp"``. ``seed``: RANSAC's.

    Example::

        result = pointfield.register(pointfield.read("bun0.pcd"), pointfield.read("bun4.pcd"), method="global")
        result.transformation, result.fitness, result.inlier_rmse, result.notes
    """
    if method not in METHODS:
        raise PointfieldError(f"unknown method {method!r}: expected one of {', '.join(METHODS)}")
    src, tgt = check_cloud(source, "source"), check_cloud(target, "target")
    init = None if init is None else check_transformation(init)
    notes = []
    if voxel is None:
        voxel, why = default_voxel(src)
        notes.append(why)
    elif not (np.isfinite(voxel) and voxel > 0):
        raise PointfieldError(f"--voxel must be a positive number, got {voxel}")
    distance = voxel if max_distance is None else float(max_distance)
    estimation, why = choose_estimation(method, src, tgt, kernel, distance)
    notes.append(why)
    run_global = method == "global" or (method == "auto" and init is None)
    if run_global:
        if init is not None:
            notes.append("global registration ignores the given init")
        init, inliers = feature_alignment(src, tgt, GLOBAL_SCALE * voxel, seed)
        coarse = GLOBAL_SCALE * voxel
        notes.append(f"global: FPFH (radius {FEATURE_RADIUS * coarse:.4g}) on the scans thinned to {coarse:.4g}, "
                     f"RANSAC ({inliers} inlier matches within {RANSAC_DISTANCE * coarse:.4g})"
                     + (", as no init was given" if method == "auto" else ""))
        levels, distances = [voxel, 0.0], [RANSAC_DISTANCE * coarse, distance]
    else:
        levels, distances = [4 * voxel, 2 * voxel, voxel, 0.0], [4 * voxel, 2 * voxel, 1.5 * voxel, distance]
    result = multiscale_icp(src, tgt, levels, distances, init, estimation, backend)
    result.method = ("global (FPFH + RANSAC) + " if run_global else "") + result.method
    result.voxel, result.notes = voxel, notes
    if result.warning:
        warnings.warn(result.warning, stacklevel=2)
    return result


def aligned(cloud: PointCloud, transformation: np.ndarray) -> PointCloud:
    """``cloud`` moved by ``transformation``: points (in their own dtype), normals rotated, every other field kept."""
    t = check_transformation(transformation)
    points = (np.asarray(cloud.points, np.float64) @ t[:3, :3].T + t[:3, 3]).astype(cloud.points.dtype)
    fields = dict(cloud.fields)
    if "normals" in fields and np.asarray(fields["normals"]).shape[1:] == (3,):
        normals = np.asarray(fields["normals"])
        fields["normals"] = (normals.astype(np.float64) @ t[:3, :3].T).astype(normals.dtype)
    return PointCloud(points, fields, cloud.shape, dict(cloud.metadata))


__all__ = ["METHODS", "aligned", "check_cloud", "check_transformation", "choose_estimation", "default_voxel",
           "feature_alignment", "register"]
