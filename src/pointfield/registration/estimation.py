"""Transformation estimation: one small object per ICP variant, swappable as open3d's ``estimation_method``.

Each object prepares what it needs from the scans (normals, covariances, intensity gradients),
then, given correspondences and the rotation applied so far (generalized ICP turns the source's
covariances by it), returns the motion that reduces its error; :func:`~pointfield.
registration.icp.registration_icp` alternates that with finding correspondences. With
``p_i`` the moved source point, ``q_j`` its target, ``n_j`` the target normal and a twist
``xi = [omega, t]`` applied on the left (``p -> p + omega x p + t``):

==========================  =====================================================  ==========================
``PointToPoint``            ``sum w |R p + t - q|^2``, solved in closed form       Besl & McKay 1992; Umeyama
``PointToPlane``            ``sum w ((p - q) . n)^2``, one Gauss-Newton step       Chen & Medioni 1992
``GeneralizedICP``          ``sum d^T (C_q + R C_p R^T)^-1 d``, ``d = p - q``      Segal, Haehnel, Thrun 2009
``ColoredICP``              ``lambda r_G^2 + (1 - lambda) r_C^2``                  Park, Zhou, Koltun 2017
==========================  =====================================================  ==========================

Every one takes a robust ``kernel`` (:mod:`pointfield.registration.kernels`) that reweights the
correspondences each iteration.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pointfield.registration.kernels import HuberLoss, L2Loss, TukeyLoss
from pointfield.registration.result import se3_exp, skew
from pointfield.registration.scan import Scan

Kernel = L2Loss | HuberLoss | TukeyLoss


def _solve(jacobian: np.ndarray, residual: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """The Gauss-Newton motion ``exp(-(J^T W J)^-1 J^T W r)`` for ``(K, 6)`` J, ``(K,)`` r and w."""
    weighted = jacobian * weight[:, None]
    hessian = weighted.T @ jacobian + 1e-12 * np.eye(6)
    return se3_exp(-np.linalg.solve(hessian, weighted.T @ residual))


@dataclass(frozen=True)
class PointToPoint:
    """Point-to-point ICP: the weighted Kabsch / Umeyama solution, exact for given correspondences.

    With weights w, centroids ``p_bar``, ``q_bar`` and ``H = sum w (p - p_bar)(q - q_bar)^T = U S V^T``,
    ``R = V diag(1, 1, det(V U^T)) U^T`` and ``t = q_bar - R p_bar``.
    """

    kernel: Kernel = field(default_factory=L2Loss)
    name = "point-to-point ICP"

    def prepare(self, source: Scan, target: Scan) -> tuple[Scan, Scan]:
        return source, target

    def step(self, moved: np.ndarray, source: Scan, target: Scan, pairs: np.ndarray,
             rotation: np.ndarray) -> np.ndarray:
        p, q = moved[pairs[:, 0]], target.points[pairs[:, 1]]
        return kabsch(p, q, self.kernel.weight(np.linalg.norm(p - q, axis=1)))


@dataclass(frozen=True)
class PointToPlane:
    """Point-to-plane ICP: residual ``r = n^T (p - q)``, Jacobian ``[(p x n)^T, n^T]``; needs target normals."""

    kernel: Kernel = field(default_factory=L2Loss)
    name = "point-to-plane ICP"

    def prepare(self, source: Scan, target: Scan) -> tuple[Scan, Scan]:
        return source, target.with_normals()

    def step(self, moved: np.ndarray, source: Scan, target: Scan, pairs: np.ndarray,
             rotation: np.ndarray) -> np.ndarray:
        p, q, n = moved[pairs[:, 0]], target.points[pairs[:, 1]], target.normals[pairs[:, 1]]
        residual = ((p - q) * n).sum(axis=1)
        return _solve(np.hstack([np.cross(p, n), n]), residual, self.kernel.weight(residual))


@dataclass(frozen=True)
class GeneralizedICP:
    """Generalized ICP: plane-to-plane, each point a thin disc (:meth:`Scan.with_covariances`).

    With ``d = p - q`` and ``M = (C_q + R C_p R^T)^-1`` (fixed within a step),
    ``H = sum J^T M J``, ``b = sum J^T M d`` for ``J = [-[p]_x, I]``; the step is ``exp(-H^-1 b)``.
    """

    kernel: Kernel = field(default_factory=L2Loss)
    name = "generalized ICP"

    def prepare(self, source: Scan, target: Scan) -> tuple[Scan, Scan]:
        return source.with_covariances(), target.with_covariances()

    def step(self, moved: np.ndarray, source: Scan, target: Scan, pairs: np.ndarray,
             rotation: np.ndarray) -> np.ndarray:
        p, q = moved[pairs[:, 0]], target.points[pairs[:, 1]]
        combined = target.covariances[pairs[:, 1]] + rotation @ source.covariances[pairs[:, 0]] @ rotation.T
        information = np.linalg.inv(combined)
        d = p - q
        weight = self.kernel.weight(np.linalg.norm(d, axis=1))
        jacobian = np.zeros((len(p), 3, 6))
        jacobian[:, :, :3] = -skew(p)
        jacobian[:, :, 3:] = np.eye(3)
        weighted = information * weight[:, None, None]
        hessian = np.einsum("kia,kij,kjb->ab", jacobian, weighted, jacobian) + 1e-12 * np.eye(6)
        gradient = np.einsum("kia,kij,kj->a", jacobian, weighted, d)
        return se3_exp(-np.linalg.solve(hessian, gradient))


@dataclass(frozen=True)
class ColoredICP:
    """Coloured ICP (Park, Zhou, Koltun, ICCV 2017): geometry and intensity in one Gauss-Newton step.

    Geometric residual ``r_G = (p - q) . n`` as point-to-plane; photometric residual
    ``r_C = I(q) + d_q . (p' - q) - I_s(p)``, where ``p'`` is p projected on q's tangent plane and
    ``d_q`` the target's intensity gradient there (:meth:`Scan.with_gradients`), Jacobian
    ``[(p x d_q)^T, d_q^T]``. The two are weighted ``lambda_geometric`` (0.968, the paper's and
    open3d's) and ``1 - lambda_geometric``. Both scans need colours; the target needs normals.
    """

    kernel: Kernel = field(default_factory=L2Loss)
    lambda_geometric: float = 0.968
    name = "coloured ICP"

    def prepare(self, source: Scan, target: Scan) -> tuple[Scan, Scan]:
        if source.intensity is None or target.intensity is None:
            raise ValueError("coloured ICP needs colours in both clouds")
        return source, target.with_normals().with_gradients()

    def step(self, moved: np.ndarray, source: Scan, target: Scan, pairs: np.ndarray,
             rotation: np.ndarray) -> np.ndarray:
        p, j = moved[pairs[:, 0]], pairs[:, 1]
        q, n, d = target.points[j], target.normals[j], target.gradients[j]
        geometric = ((p - q) * n).sum(axis=1)
        projected = p - geometric[:, None] * n
        photometric = target.intensity[j] + ((projected - q) * d).sum(axis=1) - source.intensity[pairs[:, 0]]
        a, b = np.sqrt(self.lambda_geometric), np.sqrt(1.0 - self.lambda_geometric)
        jacobian = np.vstack([a * np.hstack([np.cross(p, n), n]), b * np.hstack([np.cross(p, d), d])])
        residual = np.concatenate([a * geometric, b * photometric])
        weight = np.concatenate([self.kernel.weight(geometric), self.kernel.weight(photometric)])
        return _solve(jacobian, residual, weight)


def kabsch(p: np.ndarray, q: np.ndarray, weight: np.ndarray | None = None) -> np.ndarray:
    """``(4, 4)`` rigid motion minimising ``sum w |R p + t - q|^2`` for ``(K, 3)`` p, q (Umeyama, no scale)."""
    weight = np.ones(len(p)) if weight is None else weight
    total = max(float(weight.sum()), 1e-300)
    p_bar = (weight[:, None] * p).sum(axis=0) / total
    q_bar = (weight[:, None] * q).sum(axis=0) / total
    h = ((p - p_bar) * weight[:, None]).T @ (q - q_bar)
    u, _, vt = np.linalg.svd(h)
    sign = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    rotation = vt.T @ np.diag([1.0, 1.0, sign]) @ u.T
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = rotation, q_bar - rotation @ p_bar
    return out
