"""A pose graph of scans, optimised for global consistency, as open3d's ``PoseGraph`` and
``global_optimization`` (Choi, Zhou, Koltun, "Robust Reconstruction of Indoor Scenes", CVPR 2015).

Conventions (those of :mod:`pointfield.registration.result`, points as column vectors):

- A node is a scan; its pose ``P_i`` is a ``(4, 4)`` rigid motion that maps scan i into the frame
  of the reference scan (``P_ref = I``, held fixed).
- An edge ``(i, j, T_ij, Lambda_ij)`` is a pairwise registration of scan i (source) onto scan j
  (target): ``T_ij`` maps scan i into scan j's frame, so that consistent poses satisfy
  ``P_j T_ij = P_i``. ``Lambda_ij`` is its ``(6, 6)`` information matrix over a twist
  ``[omega, t]`` applied on the left, in scan j's frame
  (:func:`~pointfield.registration.result.information_matrix`).
- An edge is *uncertain* (a loop closure) or not (odometry: the chain that places every scan).

The residual of an edge is the motion left over in scan j's frame, written in so(3) x R^3::

    E_ij = P_j^-1 P_i T_ij^-1 = [[R_E, t_E], [0, 1]]        r_ij = [log(R_E)^vee, t_E]    (6,)

and the cost, with the line process of Choi et al. on the uncertain edges,

    F(P, l) = sum_odometry r^T Lambda r + sum_loops ( l r^T Lambda r + mu (sqrt(l) - 1)^2 ).

For fixed poses the best ``l`` of a loop edge is ``l = (mu / (mu + r^T Lambda r))^2`` (0 where that
falls below ``edge_prune_threshold``); for fixed ``l`` the poses are a weighted nonlinear least
squares problem. :func:`optimize_pose_graph` alternates the two (iteratively reweighted least
squares, each solve Levenberg-Marquardt on the sparse normal equations over left perturbations ``P_i <-
exp(xi_i) P_i``, with the sparse first-order Jacobian of :func:`adjoint_of_inverse`), then prunes the loop
closures whose ``l`` ended below the threshold and solves once more without them -- open3d's
scheme, with its weight ``mu = preference_loop_closure * d^2 * mean(Lambda[5, 5])``: ``d`` the
inlier distance of the registrations (open3d's ``max_correspondence_distance``) and
``Lambda[5, 5]`` an edge's number of correspondences. ``l`` falls to the prune threshold 0.25
where ``r^T Lambda r = mu``: where the poses put an edge's correspondences about
``sqrt(preference_loop_closure) * d`` apart (RMS) -- the loop closure's tolerance, in inlier
distances, measured *after* the optimisation.

How the alternation starts decides which loops survive: the cost is not convex in ``P``, and
each start ends in a local minimum. So the alternation runs from two starts and keeps the one of
lower ``F`` (the second only where the first pruned a loop, which it might close instead). One
is open3d's scheme as the weights first measured on the odometry chain have it:
a false loop closure is weighed down before it can pull the chain -- but so is a true loop whose
drift exceeds the tolerance on the chain, exactly the loops worth closing. The other is graduated
(graduated non-convexity, Yang, Antonante, Tzoumas, Carlone, RA-L 2020; ``l`` is Black and
Rangarajan's line process of the Geman-McClure kernel, whose scale is ``mu``): the first weights
are computed with ``mu`` scaled up to ``2 max r^T Lambda r / mu`` times itself, so that every loop
starts at ``l`` near 1 (open3d's start), and the scale shrinks by 1.4 a round down to ``mu``. A
true loop that drifted is followed while the scale is large, the chain shares its drift out, and
its residual falls: closing it costs less than pruning it (``mu``), and that start wins. A false
loop the chain can bend to within the tolerance may be followed there too, but the bent chain then
costs more than the pruned loop, and the first start wins.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import csr_matrix, diags
from scipy.spatial.transform import Rotation

from pointfield.errors import PointfieldError
from pointfield.registration.result import skew

GRADUATION = 1.4
"""The factor the line process's scale shrinks by each round (Yang et al.'s for Geman-McClure)."""


@dataclass(eq=False)
class PoseGraphEdge:
    """Scan ``source`` registered onto scan ``target``: ``transformation`` ``(4, 4)`` maps source into
    target's frame; ``information`` ``(6, 6)``; ``uncertain`` for a loop closure (open3d's name)."""

    source: int
    target: int
    transformation: np.ndarray
    information: np.ndarray
    uncertain: bool = False


@dataclass(eq=False)
class PoseGraph:
    """``poses`` ``(N, 4, 4)``, scan i into the reference frame; ``edges`` between them."""

    poses: np.ndarray
    edges: list[PoseGraphEdge] = field(default_factory=list)


@dataclass(eq=False)
class PoseGraphOptimization:
    """What :func:`optimize_pose_graph` found: ``poses`` ``(N, 4, 4)``; ``weights`` ``(E,)``, each edge's
    final line-process value (1 for odometry; 0 for a pruned loop closure); ``pruned``, the indices
    of the loop closures left out; ``cost`` the final ``F``; ``rounds`` of reweighting."""

    poses: np.ndarray
    weights: np.ndarray
    pruned: list[int]
    cost: float
    rounds: int


def edge_residuals(poses: np.ndarray, graph_edges: list[PoseGraphEdge]) -> np.ndarray:
    """``(E, 6)`` residuals ``r_ij = [log(R_E), t_E]`` of ``E_ij = P_j^-1 P_i T_ij^-1`` (module docstring)."""
    if not graph_edges:
        return np.zeros((0, 6))
    source = np.array([e.source for e in graph_edges])
    target = np.array([e.target for e in graph_edges])
    inverse_edges = np.linalg.inv(np.stack([e.transformation for e in graph_edges]))
    leftover = np.linalg.inv(poses[target]) @ poses[source] @ inverse_edges
    return np.hstack([Rotation.from_matrix(leftover[:, :3, :3]).as_rotvec(), leftover[:, :3, 3]])


def whitening(information: np.ndarray) -> np.ndarray:
    """``(6, 6)`` W with ``W^T W = Lambda``: ``|W r|^2 = r^T Lambda r`` (negative eigenvalues of a
    numerically indefinite matrix are taken as 0)."""
    values, vectors = np.linalg.eigh(0.5 * (information + information.T))
    return np.sqrt(np.clip(values, 0.0, None))[:, None] * vectors.T


def _perturbed(base: np.ndarray, free: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``base`` poses with ``exp(xi_i) P_i`` for the ``free`` nodes, ``xi`` the rows of ``x`` reshaped (F, 6)."""
    poses = base.copy()
    xi = x.reshape(-1, 6)
    moves = np.repeat(np.eye(4)[None], len(free), axis=0)
    moves[:, :3, :3] = Rotation.from_rotvec(xi[:, :3]).as_matrix()
    moves[:, :3, 3] = xi[:, 3:]
    poses[free] = moves @ base[free]
    return poses


def adjoint_of_inverse(pose: np.ndarray) -> np.ndarray:
    """``(6, 6)`` ``Ad(P^-1)`` for twists ``[omega, t]``: ``P^-1 exp(xi) P = exp(Ad(P^-1) xi)``.

    With ``P^-1 = (R', t')``, ``R' = R^T``, ``t' = -R^T t``: ``Ad = [[R', 0], [[t']_x R', R']]``.
    """
    rotation = pose[:3, :3].T
    out = np.zeros((6, 6))
    out[:3, :3] = out[3:, 3:] = rotation
    out[3:, :3] = skew(-rotation @ pose[:3, 3]) @ rotation
    return out


def _adjoints_of_inverse(poses: np.ndarray) -> np.ndarray:
    """``(N, 6, 6)`` :func:`adjoint_of_inverse` of each of ``poses`` ``(N, 4, 4)``."""
    rotation = np.swapaxes(poses[:, :3, :3], 1, 2)
    out = np.zeros((len(poses), 6, 6))
    out[:, :3, :3] = out[:, 3:, 3:] = rotation
    out[:, 3:, :3] = skew(-np.einsum("nab,nb->na", rotation, poses[:, :3, 3])) @ rotation
    return out


def _solve(poses: np.ndarray, graph_edges: list[PoseGraphEdge], weights: np.ndarray, reference: int,
           tolerance: float, max_iterations: int = 100) -> np.ndarray:
    """Poses minimising ``sum w_e |W_e r_e|^2`` with node ``reference`` fixed (Levenberg-Marquardt).

    The Jacobian is the first-order one: moving ``P_i`` by a left twist ``xi`` changes ``E_ij`` by
    ``exp(Ad(P_j^-1) xi)`` on the left, and moving ``P_j`` by ``exp(-Ad(P_j^-1) xi)``, so
    ``dr / dxi_i = Ad(P_j^-1) = -dr / dxi_j`` (exact where the residual is 0, close near it; the
    residual itself is exact, so the solve converges to the true optimum). Each step solves the
    sparse damped normal equations ``(J^T J + lambda diag(J^T J)) dx = -J^T r`` (SuperLU), is
    kept where it lowers the cost (then ``lambda / 3``, else ``lambda x 5`` and again), and the
    poses are relinearised where it lands; the solve stops when a kept step lowers the cost by
    less than ``tolerance`` of it.
    """
    from scipy.sparse.linalg import spsolve

    free = np.array([i for i in range(len(poses)) if i != reference], np.int64)
    active = [e for e, w in zip(graph_edges, weights) if w > 0]
    if not len(free) or not active:
        return poses
    scale = np.sqrt(np.array([w for w in weights if w > 0]))
    whiten = np.stack([whitening(e.information) for e in active]) * scale[:, None, None]
    column = np.full(len(poses), -1)
    column[free] = np.arange(len(free))
    source = np.array([e.source for e in active])
    target = np.array([e.target for e in active])
    # The Jacobian's 6 x 6 blocks: each edge's source block (+) and target block (-), where the node is free.
    block_row = np.concatenate([np.arange(len(active))] * 2)
    block_node = np.concatenate([source, target])
    block_sign = np.concatenate([np.ones(len(active)), -np.ones(len(active))])
    keep = column[block_node] >= 0
    block_row, block_node, block_sign = block_row[keep], block_node[keep], block_sign[keep]
    rows = (6 * block_row[:, None, None] + np.arange(6)[None, :, None] + np.zeros((1, 1, 6), np.int64)).ravel()
    columns = (6 * column[block_node][:, None, None] + np.zeros((1, 6, 1), np.int64) + np.arange(6)[None, None, :]).ravel()
    shape = (6 * len(active), 6 * len(free))

    def residuals(current: np.ndarray) -> np.ndarray:
        return np.einsum("eab,eb->ea", whiten, edge_residuals(current, active)).ravel()

    r = residuals(poses)
    cost, damping = float(r @ r), 1e-4
    for _ in range(max_iterations):
        adjoints = _adjoints_of_inverse(poses[target])
        values = block_sign[:, None, None] * np.einsum("eab,ebc->eac", whiten[block_row], adjoints[block_row])
        jacobian = csr_matrix((values.ravel(), (rows, columns)), shape=shape)
        normal = (jacobian.T @ jacobian).tocsc()
        gradient = jacobian.T @ r
        diagonal = normal.diagonal() + 1e-12
        while damping < 1e12:
            step = -spsolve(normal + diags(damping * diagonal, format="csc"), gradient)
            moved = _perturbed(poses, free, step)
            moved_r = residuals(moved)
            moved_cost = float(moved_r @ moved_r)
            if moved_cost < cost:
                damping = max(damping / 3.0, 1e-12)
                break
            damping *= 5.0
        else:
            return poses
        poses, r, improvement, cost = moved, moved_r, cost - moved_cost, moved_cost
        if improvement <= tolerance * (cost + improvement) or np.max(np.abs(step)) < tolerance:
            break
    return poses


def _squared_residuals(poses: np.ndarray, graph_edges: list[PoseGraphEdge]) -> np.ndarray:
    """``(E,)`` ``r^T Lambda r`` of every edge."""
    r = edge_residuals(poses, graph_edges)
    return np.einsum("ea,eab,eb->e", r, np.stack([e.information for e in graph_edges]), r)


def line_process(poses: np.ndarray, graph_edges: list[PoseGraphEdge], mu: float, prune: float) -> np.ndarray:
    """``(E,)`` edge weights: 1 for odometry; ``(mu / (mu + r^T Lambda r))^2`` for a loop closure,
    0 where that is below ``prune``."""
    weights = (mu / (mu + _squared_residuals(poses, graph_edges))) ** 2
    weights[weights < prune] = 0.0
    uncertain = np.array([e.uncertain for e in graph_edges])
    return np.where(uncertain, weights, 1.0)


def graph_cost(poses: np.ndarray, graph_edges: list[PoseGraphEdge], weights: np.ndarray, mu: float) -> float:
    """``F(P, l)`` of the module docstring."""
    r = edge_residuals(poses, graph_edges)
    squared = np.einsum("ea,eab,eb->e", r, np.stack([e.information for e in graph_edges]), r)
    uncertain = np.array([e.uncertain for e in graph_edges])
    return float(np.sum(weights * squared) + np.sum(np.where(uncertain, mu * (np.sqrt(weights) - 1) ** 2, 0.0)))


def optimize_pose_graph(graph: PoseGraph, max_correspondence_distance: float = 1.0, reference: int = 0,
                        preference_loop_closure: float = 1.0, edge_prune_threshold: float = 0.25,
                        max_rounds: int = 100, tolerance: float = 1e-10) -> PoseGraphOptimization:
    """Globally consistent poses for ``graph`` (module docstring), node ``reference`` held where it is.

    ``graph.poses`` is the starting point (the odometry chain); it is not changed. The options are
    open3d's ``GlobalOptimizationOption``'s, with its defaults but for ``max_correspondence_distance``,
    the edges' inlier distance ``d``, which the caller knows. Reweighting stops once the kernel's scale
    has shrunk to ``mu`` and no weight moves by more than 1e-4, or after ``max_rounds``.

    Example: three scans whose odometry drifts, and a loop closure that says where scan 2 is::

        >>> def shift(x):
        ...     out = np.eye(4); out[0, 3] = x; return out
        >>> info = 100 * np.eye(6)
        >>> edges = [PoseGraphEdge(1, 0, shift(1.0), info), PoseGraphEdge(2, 1, shift(1.0), info),
        ...          PoseGraphEdge(2, 0, shift(1.9), info, uncertain=True)]
        >>> found = optimize_pose_graph(PoseGraph(np.stack([shift(0), shift(1), shift(2)]), edges))
        >>> round(float(found.poses[2][0, 3]), 3)  # the 0.1 disagreement shared by the three edges
        1.933
    """
    poses = np.asarray(graph.poses, np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        raise PointfieldError(f"pose graph: expected (N, 4, 4) poses, got shape {poses.shape}")
    if not 0 <= reference < len(poses):
        raise PointfieldError(f"pose graph: reference node {reference} is not one of the {len(poses)} nodes")
    for edge in graph.edges:
        if not (0 <= edge.source < len(poses) and 0 <= edge.target < len(poses)) or edge.source == edge.target:
            raise PointfieldError(f"pose graph: edge {edge.source} -> {edge.target} does not join two of the "
                                  f"{len(poses)} nodes")
    edges = list(graph.edges)
    if not edges:
        return PoseGraphOptimization(poses.copy(), np.zeros(0), [], 0.0, 0)
    if not (np.isfinite(max_correspondence_distance) and max_correspondence_distance > 0):
        raise PointfieldError(f"max_correspondence_distance must be positive, got {max_correspondence_distance}")
    mu = preference_loop_closure * max_correspondence_distance**2 * float(np.mean([e.information[5, 5] for e in edges]))
    uncertain = np.array([e.uncertain for e in edges])
    # Two starts, one objective (module docstring): the weights measured on the chain, and graduated from 1.
    # The graduated start can only differ where the first pruned a loop (one it might close instead).
    squared = _squared_residuals(poses, edges)
    found = [_alternate(poses, edges, mu, 1.0, reference, edge_prune_threshold, max_rounds, tolerance)]
    graduated = max(1.0, 2.0 * float(np.max(squared[uncertain], initial=0.0)) / mu)
    if graduated > 1.0 and np.any(found[0][1][uncertain] == 0.0):
        found.append(_alternate(poses, edges, mu, graduated, reference, edge_prune_threshold, max_rounds, tolerance))
    poses, weights, rounds = min(found, key=lambda f: graph_cost(f[0], edges, f[1], mu))  # the chain's on a tie
    pruned = [k for k, e in enumerate(edges) if e.uncertain and weights[k] == 0.0]
    return PoseGraphOptimization(poses, weights, pruned, graph_cost(poses, edges, weights, mu), rounds)


def _alternate(poses: np.ndarray, edges: list[PoseGraphEdge], mu: float, scale: float, reference: int, prune: float,
               max_rounds: int, tolerance: float) -> tuple[np.ndarray, np.ndarray, int]:
    """``(poses, weights, rounds)``: poses and line process alternated from ``poses``, the kernel's scale
    ``mu x scale`` shrinking by :data:`GRADUATION` a round to ``mu``; then the pruned loops left out and solved
    once more (open3d's second pass)."""
    weights = line_process(poses, edges, mu * scale, prune)
    rounds, settled = 0, False
    while rounds < max_rounds and not settled:
        rounds += 1
        # While the scale is graduated the weights move on anyway: each solve need not be tight.
        poses = _solve(poses, edges, weights, reference, tolerance if scale == 1.0 else max(tolerance, 1e-6))
        scale = max(1.0, scale / GRADUATION)
        updated = line_process(poses, edges, mu * scale, prune)
        settled = scale == 1.0 and bool(np.max(np.abs(updated - weights)) < 1e-4)
        weights = updated
    if np.any(weights == 0.0):
        poses = _solve(poses, edges, weights, reference, tolerance)
    return poses, weights, rounds

__all__ = ["GRADUATION", "PoseGraph", "PoseGraphEdge", "PoseGraphOptimization", "edge_residuals", "optimize_pose_graph"]
