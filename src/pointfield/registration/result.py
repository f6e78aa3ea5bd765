"""What a registration returns, and how far to trust it: fitness, inlier RMSE, information matrix.

Conventions (shared by the whole package, as open3d's ``pipelines.registration``):

- A transformation ``T`` is a ``(4, 4)`` float64 rigid motion that maps SOURCE onto TARGET:
  ``q = R p + t`` with ``T = [[R, t], [0, 0, 0, 1]]``, points as column vectors.
- A correspondence is a pair ``(i, j)``: source point i, moved by ``T``, lies within the inlier
  distance of target point j (its nearest).
- ``fitness = |correspondences| / |source|``: the share of the source that found the target;
  ``inlier_rmse = sqrt(mean |T p_i - q_j|^2)`` over the correspondences only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from pointfield.registration.scan import query_workers

LOW_FITNESS = 0.2
"""Below this fitness a result is flagged: two scans of the same place rarely share less than a fifth."""


@dataclass(eq=False)
class RegistrationResult:
    """The motion found, and the evidence for it.

    ``transformation`` ``(4, 4)`` float64 maps source onto target; ``fitness`` and ``inlier_rmse``
    as in the module docstring, measured at ``max_distance``; ``correspondence_set`` ``(K, 2)``
    int64 source and target indices; ``information`` ``(6, 6)``, see :func:`information_matrix`;
    ``method`` the estimation that ran (``"global (FPFH + RANSAC) + point-to-plane ICP"``);
    ``notes`` every choice made for the caller, one sentence each (the voxel and why, the method
    and why), so that nothing is chosen silently.

    Example::

        >>> result = RegistrationResult(np.eye(4), 0.5, 0.01, np.zeros((0, 2), np.int64), np.eye(6), "icp")
        >>> result
        RegistrationResult(method='icp', fitness=0.5000, inlier_rmse=0.01000, correspondences=0)
    """

    transformation: np.ndarray
    fitness: float
    inlier_rmse: float
    correspondence_set: np.ndarray
    information: np.ndarray
    method: str
    max_distance: float = 0.0
    voxel: float = 0.0
    iterations: int = 0
    notes: list[str] = field(default_factory=list)

    @property
    def warning(self) -> str | None:
        """A sentence for a result not to trust (fitness below :data:`LOW_FITNESS`), else None."""
        if self.fitness >= LOW_FITNESS:
            return None
        return (f"fitness {self.fitness:.2f}: these scans do not seem to overlap; "
                "try --method global or a larger --voxel")

    def as_dict(self) -> dict:
        """The JSON form the CLI prints: transformation (4 rows), fitness, rmse, method, and the rest."""
        return {"transformation": self.transformation.tolist(), "fitness": float(self.fitness),
                "rmse": float(self.inlier_rmse), "method": self.method,
                "correspondences": len(self.correspondence_set), "max_distance": float(self.max_distance),
                "voxel": float(self.voxel), "iterations": int(self.iterations), "notes": list(self.notes)}

    def __repr__(self) -> str:
        return (f"RegistrationResult(method={self.method!r}, fitness={self.fitness:.4f}, "
                f"inlier_rmse={self.inlier_rmse:.4g}, correspondences={len(self.correspondence_set)})")


def transform_points(points: np.ndarray, transformation: np.ndarray) -> np.ndarray:
    """``(N, 3)`` float64 ``R p + t`` for each row p of ``points``."""
    return np.asarray(points, np.float64) @ transformation[:3, :3].T + transformation[:3, 3]


def correspondences(moved: np.ndarray, tree: cKDTree, max_distance: float) -> tuple[np.ndarray, np.ndarray]:
    """``(pairs (K, 2) int64, distances (K,))``: each moved source point's nearest target within ``max_distance``."""
    distances, index = tree.query(moved, distance_upper_bound=max_distance, workers=query_workers(len(moved)))
    found = np.isfinite(distances)
    pairs = np.stack([np.flatnonzero(found), index[found]], axis=1).astype(np.int64)
    return pairs, distances[found]


def evaluate(source: np.ndarray, target_tree: cKDTree, transformation: np.ndarray,
             max_distance: float) -> tuple[float, float, np.ndarray]:
    """``(fitness, inlier_rmse, correspondence_set)`` of ``transformation`` (open3d's ``evaluate_registration``)."""
    pairs, distances = correspondences(transform_points(source, transformation), target_tree, max_distance)
    if len(source) == 0 or len(pairs) == 0:
        return 0.0, 0.0, pairs
    return len(pairs) / len(source), float(np.sqrt(np.mean(distances**2))), pairs


def information_matrix(target: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """``(6, 6)`` information of the motion ``[omega, t]`` given the correspondences' target points.

    As open3d's ``get_information_matrix_from_point_clouds``: each target point q contributes
    ``G^T G`` with ``G = [-[q]_x | I]`` (3 x 6), the Jacobian of a point-to-point residual. Its
    inverse approximates the motion's covariance up to the noise variance; pose graphs weight
    edges by it.
    """
    q = np.asarray(target, np.float64)[pairs[:, 1]] if len(pairs) else np.zeros((0, 3))
    # The sum in closed form from the moments of q: [q]_x^T [q]_x = |q|^2 I - q q^T, and the
    # off-diagonal blocks are [sum q]_x and its transpose (no (K, 3, 6) Jacobians in memory).
    moment, total = q.T @ q, q.sum(axis=0)
    information = np.zeros((6, 6))
    information[:3, :3] = np.trace(moment) * np.eye(3) - moment
    information[:3, 3:] = skew(total)
    information[3:, :3] = skew(total).T
    information[3:, 3:] = len(q) * np.eye(3)
    return information


def skew(v: np.ndarray) -> np.ndarray:
    """``(..., 3, 3)`` cross-product matrices ``[v]_x`` with ``[v]_x w = v x w``."""
    v = np.asarray(v, np.float64)
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def se3_exp(xi: np.ndarray) -> np.ndarray:
    """``(4, 4)`` motion of the twist ``xi = [omega, t]`` (6,): rotation by Rodrigues' formula, then t.

    ``R = I + sin(a) K + (1 - cos(a)) K^2`` with ``a = |omega|``, ``K = [omega / a]_x``. Used as a
    left update ``T <- exp(xi) T``, the linearisation ``R p + t ~ p + omega x p + t`` that the
    Gauss-Newton steps assume.
    """
    omega, t = xi[:3], xi[3:]
    angle = float(np.linalg.norm(omega))
    rotation = np.eye(3)
    if angle > 1e-12:
        k = skew(omega / angle)
        rotation = np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = rotation, t
    return out
