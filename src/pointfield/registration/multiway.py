"""``pointfield.align(clouds)``: many scans into one frame, as open3d's multiway registration.

1. **Pairs.** Every pair ``i < j`` is registered with :func:`~pointfield.registration.register`
   (scan i onto scan j, one voxel for all pairs so that every fitness is measured at the same
   inlier distance; with a fine method, which starts from identity, a pair whose bounding boxes
   are farther apart than its coarsest inlier distance, ``4 voxel``, cannot link and is not
   tried). A pair is *linked* when its fitness reaches ``min_fitness`` (default
   :data:`~pointfield.registration.result.LOW_FITNESS`, the fitness below which ``register``
   warns); others are taken as not overlapping.
2. **Which scans.** The linked pairs split the scans into connected groups; the largest is
   aligned (ties: the one with the earliest scan) and its first scan is the *reference*, whose
   frame every pose maps into. A scan outside it overlaps none of the aligned scans: it is left
   out -- a warning names it and its best fitness -- rather than kept at identity, where it
   would sit at a place nothing measured.
3. **Odometry and loop closures.** A spanning tree grown from the reference (consecutive pairs
   first, then by fitness, so that when scans are given in acquisition order the tree is
   open3d's odometry chain ``0 - 1 - 2 ...``) gives the starting poses; its edges are odometry,
   every other linked pair a loop closure, flagged uncertain. A wrong odometry edge (two scans
   that look alike, registered wrongly with a fair fitness) would make the true loop closures
   look wrong, so a second tree is tried, grown by fitness alone, and the one whose optimised
   poses more pairs agree with (the sum of the fitness of the edges kept) is taken.
4. **Optimisation.** :func:`~pointfield.registration.pose_graph.optimize_pose_graph` with the
   inlier distance ``d`` and ``preference_loop_closure`` 5 (open3d's reconstruction system's for
   loop closures between fragments): a loop closure whose correspondences the poses put more
   than ``sqrt(5) d`` apart (RMS) once the poses are optimised is pruned, and named in the notes.
   The line process runs from two starts, its weights measured on the chain and graduated from
   full weight, and the lower cost wins, so a true loop closure is closed however far the chain
   drifted from it, and a false one (from scans that only look alike) is pruned.

Coordinates are shifted by the reference scan's centroid (rounded) while registering, so that
survey-sized coordinates (UTM) neither lose float precision nor make the information matrices,
which weigh rotations by the distance from the origin, ill-conditioned; the poses returned are in
the scans' own coordinates.
"""

from __future__ import annotations

import heapq
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.errors import PointfieldError
from pointfield.registration.pairwise import check_cloud, default_voxel, register
from pointfield.registration.pose_graph import PoseGraph, PoseGraphEdge, edge_residuals, optimize_pose_graph
from pointfield.registration.result import LOW_FITNESS, skew

FINE_METHODS = ("icp", "plane", "gicp", "colored")
"""The methods that start every pair from identity (the others run global registration first)."""
PREFERENCE_LOOP_CLOSURE = 5.0
"""open3d's reconstruction system's ``preference_loop_closure`` for loop closures between fragments."""


@dataclass(eq=False)
class AlignedPair:
    """Scan ``source`` registered onto scan ``target``: the motion (source into target's frame), its
    ``fitness``, ``rmse`` and ``information`` (over a left twist in the scans' own coordinates); ``linked`` when the fitness reaches the threshold;
    ``kind`` ``"odometry"``, ``"loop closure"`` or ``""`` (unlinked, or outside the aligned group);
    ``weight``, the line-process weight the optimisation gave it (0: pruned); ``error`` the
    reason a pair could not be registered at all (too few points at the voxel)."""

    source: int
    target: int
    transformation: np.ndarray
    fitness: float
    rmse: float
    information: np.ndarray
    linked: bool
    kind: str = ""
    weight: float = 0.0
    error: str = ""

    def as_dict(self) -> dict:
        return {"source": self.source, "target": self.target, "fitness": float(self.fitness),
                "rmse": float(self.rmse), "linked": self.linked, "kind": self.kind,
                "weight": float(self.weight), "transformation": self.transformation.tolist(),
                **({"error": self.error} if self.error else {})}


@dataclass(eq=False)
class AlignResult:
    """``poses`` one per scan: ``(4, 4)`` mapping scan i into the reference scan's frame, or None for a
    scan left out; ``initial_poses`` the same from the odometry chain alone (before optimisation);
    ``reference`` the scan whose frame that is; ``pairs`` every pair tried; ``voxel``; ``notes``
    every choice and finding, one sentence each."""

    poses: list[np.ndarray | None]
    initial_poses: list[np.ndarray | None]
    reference: int
    pairs: list[AlignedPair]
    voxel: float
    notes: list[str] = field(default_factory=list)

    @property
    def left_out(self) -> list[int]:
        return [i for i, pose in enumerate(self.poses) if pose is None]

    def as_dict(self, names: Sequence[str] | None = None) -> dict:
        """The JSON form of ``poses.json``: per scan its name and 4 x 4 pose (null when left out), per pair
        its fitness, RMSE, kind and weight."""
        names = list(names) if names is not None else [f"scan {i}" for i in range(len(self.poses))]
        return {"reference": self.reference, "voxel": float(self.voxel),
                "convention": "pose maps the scan's points into the reference scan's frame: q = R p + t",
                "scans": [{"scan": names[i], "pose": None if pose is None else pose.tolist(),
                           "left_out": pose is None} for i, pose in enumerate(self.poses)],
                "pairs": [p.as_dict() for p in self.pairs], "notes": list(self.notes)}


def _shift(offset: np.ndarray, sign: float) -> np.ndarray:
    out = np.eye(4)
    out[:3, 3] = sign * offset
    return out


def _groups(count: int, linked: list[AlignedPair]) -> list[list[int]]:
    """The connected groups of ``count`` scans under the ``linked`` pairs, each sorted."""
    parent = list(range(count))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for pair in linked:
        parent[root(pair.source)] = root(pair.target)
    groups: dict[int, list[int]] = {}
    for i in range(count):
        groups.setdefault(root(i), []).append(i)
    return sorted(groups.values(), key=lambda g: (-len(g), g[0]))


def _spanning_tree(reference: int, group: list[int], linked: list[AlignedPair], consecutive_first: bool = True
                   ) -> tuple[list[AlignedPair], dict]:
    """``(tree pairs, poses)``: Prim's tree from ``reference`` over ``group`` (consecutive scans first
    when ``consecutive_first``, then the highest fitness), and each scan's pose chained along it."""
    poses = {reference: np.eye(4)}
    tree = []
    frontier: list = []

    def push(node: int) -> None:
        for k, pair in enumerate(linked):
            if node in (pair.source, pair.target):
                heapq.heappush(frontier, (consecutive_first and abs(pair.source - pair.target) != 1, -pair.fitness, k))

    push(reference)
    while frontier and len(poses) < len(group):
        _, _, k = heapq.heappop(frontier)
        pair = linked[k]
        if (pair.source in poses) == (pair.target in poses):
            continue
        if pair.target in poses:  # P_i = P_j T_ij
            poses[pair.source] = poses[pair.target] @ pair.transformation
            new = pair.source
        else:  # P_j = P_i T_ij^-1
            poses[pair.target] = poses[pair.source] @ np.linalg.inv(pair.transformation)
            new = pair.target
        tree.append(pair)
        push(new)
    return tree, poses


def align(clouds: Sequence[PointCloud | np.ndarray], method: str = "auto", voxel: float | None = None,
          max_distance: float | None = None, min_fitness: float = LOW_FITNESS, kernel: str | None = None,
          names: Sequence[str] | None = None, seed: int = 0,
          preference_loop_closure: float = PREFERENCE_LOOP_CLOSURE) -> AlignResult:
    """Poses that put ``clouds`` into one frame, consistent over every overlapping pair (module docstring).

    ``clouds``: two or more clouds or ``(N, 3)`` arrays. ``method``, ``voxel``, ``max_distance``,
    ``kernel``, ``seed``: as :func:`~pointfield.registration.register`, for every pair (``voxel``
    defaults to the first scan's). ``min_fitness``: the fitness at which a pair counts as
    overlapping. ``names``: what errors and warnings call the scans (file names).
    ``preference_loop_closure``: the pose graph's (module docstring).

    A scan that overlaps none of the aligned ones is left out with a warning.

    Example::

        result = pointfield.align([pointfield.read(p) for p in ("a.pcd", "b.pcd", "c.pcd")])
        result.poses[1]      # (4, 4): scan b into scan a's frame
    """
    names = list(names) if names is not None else [f"scan {i}" for i in range(len(clouds))]
    if len(clouds) < 2:
        raise PointfieldError(f"align needs at least two scans, got {len(clouds)}")
    if len(names) != len(clouds):
        raise PointfieldError(f"align: {len(names)} names for {len(clouds)} scans")
    if not 0.0 <= min_fitness <= 1.0:
        raise PointfieldError(f"min_fitness must be between 0 and 1, got {min_fitness}")
    if not preference_loop_closure > 0:
        raise PointfieldError(f"preference_loop_closure must be positive, got {preference_loop_closure}")
    clouds = [c if isinstance(c, PointCloud) else PointCloud(np.asarray(c, np.float64).reshape(-1, 3)) for c in clouds]
    scans = [check_cloud(c, n) for c, n in zip(clouds, names)]
    notes = []
    if voxel is None:
        voxel, why = default_voxel(scans[0])
        notes.append(why.replace("the source's", f"{names[0]}'s") + ", for every pair")
    elif not (np.isfinite(voxel) and voxel > 0):
        raise PointfieldError(f"--voxel must be a positive number, got {voxel}")
    offset = np.round(scans[0].points.mean(axis=0), 0)
    shifted = [PointCloud(s.points - offset, {k: v for k, v in (("normals", s.normals),) if v is not None}
                          | ({"colors": _grey(s.intensity)} if s.intensity is not None else {})) for s in scans]

    # The fine methods start every pair from identity, and find no partner farther than their coarsest
    # inlier distance: pairs whose boxes are farther apart than that cannot link, and are not tried.
    reach = max(4 * voxel, voxel if max_distance is None else max_distance) if method in FINE_METHODS else np.inf
    boxes = [(s.points.min(axis=0), s.points.max(axis=0)) for s in scans]
    pairs = []
    for i in range(len(scans)):
        for j in range(i + 1, len(scans)):
            gap = float(np.max(np.maximum(boxes[i][0] - boxes[j][1], boxes[j][0] - boxes[i][1])))
            if gap > reach:
                pairs.append(AlignedPair(i, j, np.eye(4), 0.0, 0.0, np.zeros((6, 6)), False,
                                         error=f"not tried: the scans' boxes are {gap:.3g} apart, farther than "
                                               f"{method} from identity reaches ({reach:.3g})"))
                continue
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # a low fitness is reported below, pair by pair
                try:
                    result = register(shifted[i], shifted[j], method=method, voxel=voxel, max_distance=max_distance,
                                      kernel=kernel, seed=seed)
                except PointfieldError as error:
                    pairs.append(AlignedPair(i, j, np.eye(4), 0.0, 0.0, np.zeros((6, 6)), False, error=str(error)))
                    continue
            pairs.append(AlignedPair(i, j, result.transformation, result.fitness, result.inlier_rmse,
                                     result.information, result.fitness >= min_fitness))
    linked = [p for p in pairs if p.linked]
    notes.append(f"{len(linked)} of {len(pairs)} pairs overlap (fitness >= {min_fitness:g}): "
                 + (", ".join(f"{names[p.source]}-{names[p.target]} {p.fitness:.2f}" for p in linked) or "none"))

    group = _groups(len(scans), linked)[0]
    reference = group[0]
    if len(group) < 2:
        raise PointfieldError(f"no two scans overlap (best fitness {max(p.fitness for p in pairs):.2f}, below "
                              f"{min_fitness:g}): these scans do not seem to overlap; try a larger --voxel or "
                              "--method global")
    for i in range(len(scans)):
        if i not in group:
            best = max((p for p in pairs if i in (p.source, p.target) and (p.source in group or p.target in group)),
                       key=lambda p: p.fitness, default=None)
            against = "" if best is None else (f" (best fitness {best.fitness:.2f}, with "
                                               f"{names[best.target if best.source == i else best.source]})")
            warnings.warn(f"{names[i]}: overlaps none of the aligned scans{against}; left out of the alignment "
                          "and the merge. Try a larger --voxel or --method global", stacklevel=2)
    group_pairs = [p for p in linked if p.source in group and p.target in group]
    index = {scan: k for k, scan in enumerate(group)}
    distance = voxel if max_distance is None else max_distance
    trials = []
    for rule in ("consecutive", "fitness"):
        tree, chained = _spanning_tree(reference, group, group_pairs, consecutive_first=rule == "consecutive")
        if trials and {id(p) for p in tree} == {id(p) for p in trials[0][1]}:
            continue
        start = np.stack([chained[scan] for scan in group])
        edges = [PoseGraphEdge(index[p.source], index[p.target], p.transformation, p.information,
                               uncertain=p not in tree) for p in group_pairs]
        optimised = optimize_pose_graph(PoseGraph(start, edges), distance, reference=0,
                                        preference_loop_closure=preference_loop_closure)
        support = sum(p.fitness for p, w in zip(group_pairs, optimised.weights) if w > 0)
        trials.append((support, tree, start, edges, optimised, rule))
    support, tree, start, edges, optimised, rule = max(trials, key=lambda t: t[0])  # the first on a tie
    if rule == "fitness":
        notes.append("odometry from the pairs of highest fitness: more pairs agree with it than with the chain of "
                     f"consecutive scans (supporting fitness {support:.2f} against {trials[0][0]:.2f})")
    for pair, weight in zip(group_pairs, optimised.weights):
        pair.kind = "odometry" if pair in tree else "loop closure"
        pair.weight = float(weight)
    loops = [p for p in group_pairs if p.kind == "loop closure"]
    notes.append(f"pose graph: {len(tree)} odometry edges, {len(loops)} loop closures"
                 + (", pruned as inconsistent: " + ", ".join(f"{names[p.source]}-{names[p.target]}" for p in loops
                                                            if p.weight == 0.0) if optimised.pruned else ""))
    if loops:
        kept = [e for e, w in zip(edges, optimised.weights) if w > 0]
        before, after = _disagreement(start, kept), _disagreement(optimised.poses, kept)
        notes.append(f"largest disagreement between a pair and the poses: {before[0]:.3g} deg, {before[1]:.3g} "
                     f"before the optimisation; {after[0]:.3g} deg, {after[1]:.3g} after")

    def unshift(pose: np.ndarray) -> np.ndarray:  # poses found on shifted coordinates, back to the scans' own
        return _shift(offset, 1.0) @ pose @ _shift(offset, -1.0)

    poses: list[np.ndarray | None] = [None] * len(scans)
    initial: list[np.ndarray | None] = [None] * len(scans)
    for scan, k in index.items():
        poses[scan], initial[scan] = unshift(optimised.poses[k]), unshift(start[k])
    # A left twist [omega, t] on shifted coordinates is [omega, t + c x omega] on the scans' own:
    # S exp(xi) S^-1 p = p + omega x p + t - omega x c. The information follows: A^-T Lambda A^-1.
    twist = np.eye(6)
    twist[3:, :3] = -skew(offset)
    for pair in pairs:
        pair.transformation = unshift(pair.transformation)
        pair.information = twist.T @ pair.information @ twist
    return AlignResult(poses, initial, reference, pairs, float(voxel), notes)


def _grey(intensity: np.ndarray) -> np.ndarray:
    """``(N, 3)`` uint8 grey colours of a [0, 1] intensity: what :class:`Scan` read from the colours, given back."""
    return np.repeat(np.clip(np.round(intensity * 255), 0, 255).astype(np.uint8)[:, None], 3, axis=1)


def _disagreement(poses: np.ndarray, edges: list[PoseGraphEdge]) -> tuple[float, float]:
    """``(degrees, distance)``: the largest rotation and translation of ``E_ij`` over the edges kept."""
    r = edge_residuals(poses, edges)
    return float(np.degrees(np.linalg.norm(r[:, :3], axis=1).max())), float(np.linalg.norm(r[:, 3:], axis=1).max())


__all__ = ["AlignResult", "AlignedPair", "align"]
