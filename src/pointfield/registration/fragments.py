"""Fragments and loop closures: bounding the drift of frame-to-frame odometry over a long RGB-D sequence.

open3d's reconstruction system (Choi, Zhou, Koltun, "Robust Reconstruction of Indoor Scenes",
CVPR 2015), on the odometry that :func:`~pointfield.registration.odometry.rgbd_odometry` found:

1. **Fragments.** The frames are cut into runs of ``fragment_size`` (a last run shorter than half
   of that joins the one before). A fragment's frame is that of its first camera; its cloud is
   its frames' thinned clouds put there by the odometry, thinned again to one point per
   ``voxel``. Within a fragment, first, a pose graph of its own (open3d's ``make_fragments.py``,
   :func:`fragment_pose_graph`): the odometry between consecutive frames, and every pair of
   keyframes (every 5th frame) registered onto each other, optimised with open3d's options for
   fragments (inlier distance ``1.4 voxel``, ``preference_loop_closure`` 0.1: a keyframe pair the
   optimised poses put more than about ``0.44 voxel`` apart, RMS, is pruned).
2. **Pairs.** Consecutive fragments ``k, k + 1`` are registered from the odometry's guess
   (generalized ICP, coarse to fine: :func:`~pointfield.registration.pairwise.register`) --
   odometry edges. With ``loop_closure``, every other pair whose boxes, placed by the odometry,
   meet is a loop-closure candidate: registered from the odometry's guess first, and where that
   finds too little overlap, from anywhere (FPFH + RANSAC, then the fine step), as open3d's
   ``register_fragments.py`` does for non-adjacent fragments. A candidate whose fitness reaches
   ``min_fitness`` becomes an *uncertain* edge.
3. **Pose graph.** :func:`~pointfield.registration.pose_graph.optimize_pose_graph` over the
   fragments (the first held), inlier distance ``voxel``, ``preference_loop_closure`` 5 (open3d's
   for fragments): a loop closure the other edges disagree with is pruned.
4. **Frames.** Each frame's pose is its fragment's optimised pose times the odometry within the
   fragment::

       pose_f = P_k  P0_k^-1  pose0_f          (k the fragment of frame f, P0_k its odometry pose)

Conventions: poses are camera-to-world ``(4, 4)``; an edge ``(i, j, T_ij)`` maps fragment i into
fragment j's frame, ``P_j T_ij = P_i`` (:mod:`pointfield.registration.pose_graph`).

What this does not do that open3d's does: a last refinement of the frames against the fused
model; and open3d checks keyframe pairs with ORB features (and registers them from those where
the odometry's guess is far off), where here they start from the odometry's guess alone.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from pointfield.errors import PointfieldError
from pointfield.registration.pose_graph import PoseGraph, PoseGraphEdge, optimize_pose_graph

DEFAULT_FRAGMENT_SIZE = 100
"""Frames per fragment (open3d's reconstruction system's ``n_frames_per_fragment``)."""
MIN_FITNESS = 0.3
"""A pair of fragments registered with less fitness than this is not an edge."""
PREFERENCE_LOOP_CLOSURE = 5.0
"""open3d's reconstruction system's ``preference_loop_closure`` for loop closures between fragments."""
KEYFRAME_INTERVAL = 5
"""Every so many frames of a fragment is a keyframe, registered against the others (open3d's
``n_keyframes_per_n_frame``)."""
FRAGMENT_PREFERENCE_LOOP_CLOSURE = 0.1
"""open3d's ``preference_loop_closure_odometry``: the pose graph within a fragment."""
MAX_LOOP_PARTNERS = 8
"""Loop-closure candidates registered per fragment, the nearest first (:func:`nearest_pairs`)."""
MAX_KEYFRAME_PARTNERS = 4
"""Keyframe pairs registered per keyframe within a fragment, the nearest first."""
FRAGMENT_CORRESPONDENCE = 1.4
"""The inlier distance of the pose graph within a fragment, in voxels (open3d's ``voxel_size * 1.4``)."""


@dataclass(eq=False)
class FragmentPair:
    """Fragment ``source`` registered onto fragment ``target`` (``transformation`` maps source into
    target's frame). ``kind``: ``"odometry"`` (consecutive) or ``"loop closure"``; ``how``: ``"fine"``
    (from the odometry's guess) or ``"global"`` (FPFH + RANSAC, then fine); ``kept``: an edge of the
    graph and not pruned by the optimisation."""

    source: int
    target: int
    transformation: np.ndarray
    fitness: float
    information: np.ndarray
    kind: str
    how: str
    kept: bool = False


@dataclass(eq=False)
class FragmentPoses:
    """What :func:`fragment_poses` found: ``poses`` ``(N, 4, 4)`` refined camera-to-world; ``fragments``
    the ``(first, stop)`` frame range of each; ``fragment_poses`` ``(K, 4, 4)`` before and after the
    pose graph; ``pairs`` every registration tried that linked; ``notes`` one sentence per choice."""

    poses: np.ndarray
    fragments: list[tuple[int, int]]
    initial_fragment_poses: np.ndarray
    fragment_poses: np.ndarray
    pairs: list[FragmentPair] = field(default_factory=list)
    loop_candidates: int = 0
    notes: list[str] = field(default_factory=list)
    keyframe_pairs: tuple[int, int, int] = (0, 0, 0)
    """Over every fragment's own pose graph: keyframe pairs linked, kept, pruned."""

    @property
    def loops_kept(self) -> int:
        return sum(p.kind == "loop closure" and p.kept for p in self.pairs)

    @property
    def loops_pruned(self) -> int:
        return sum(p.kind == "loop closure" and not p.kept for p in self.pairs)


def split_fragments(count: int, size: int) -> list[tuple[int, int]]:
    """``(first, stop)`` frame ranges of ``size`` frames; a last run under ``size / 2`` joins the one before."""
    if size < 1:
        raise PointfieldError(f"a fragment needs at least one frame, got fragment size {size}")
    ranges = [(start, min(start + size, count)) for start in range(0, count, size)]
    if len(ranges) > 1 and ranges[-1][1] - ranges[-1][0] < size / 2:
        ranges[-2:] = [(ranges[-2][0], count)]
    return ranges


def fragment_cloud(points: list[np.ndarray], poses: np.ndarray, first: int, stop: int, voxel: float) -> np.ndarray:
    """``(M, 3)``: the camera-frame clouds of frames ``first`` to ``stop - 1`` in camera ``first``'s frame, one point per voxel."""
    from pointfield.registration.scan import Scan

    base = np.linalg.inv(poses[first])
    moved = [points[f] @ m[:3, :3].T + m[:3, 3] for f in range(first, stop) if len(points[f])
             for m in (base @ poses[f],)]
    if not moved:
        return np.zeros((0, 3))
    return Scan(np.concatenate(moved)).downsample(voxel).points


def fragment_pose_graph(poses: np.ndarray, points: list[np.ndarray], first: int, stop: int, voxel: float,
                        keyframe_interval: int = KEYFRAME_INTERVAL, min_fitness: float = MIN_FITNESS,
                        max_partners: int | None = MAX_KEYFRAME_PARTNERS,
                        information: list[np.ndarray | None] | None = None) -> tuple[np.ndarray, int, int, int]:
    """``(poses, registered, kept, pruned)``: frames ``first`` to ``stop - 1`` put through their own pose graph,
    as open3d's ``make_fragments.py``; ``poses`` ``(stop - first, 4, 4)`` camera-to-world, frame ``first`` where
    it was; ``registered`` the keyframe pairs that linked (fitness >= ``min_fitness``), ``kept`` and ``pruned``
    of them by the optimisation.

    Nodes are the frames; edges: the odometry between consecutive frames (certain), and every pair of
    keyframes (every ``keyframe_interval``-th frame) not consecutive whose clouds, placed by the odometry,
    meet (each keyframe's ``max_partners`` nearest: :func:`nearest_pairs`), registered by generalized ICP (small_gicp) from the odometry's guess, partners first within
    ``4 voxel`` then within ``voxel`` -- uncertain. Each edge's
    information counts its correspondences within ``voxel``. The graph is optimised with open3d's options
    for fragments: inlier distance ``1.4 voxel``, ``preference_loop_closure`` 0.1.

    ``information``: the odometry's own measure of each step's information (``Odometry.information``,
    over the whole sequence, entry ``i`` for frame ``i + 1`` onto frame ``i``, at the same ``voxel``):
    used for the consecutive edges where given (not None) instead of measuring it again -- a k-d tree
    per pair, about half the cost of a fragment's graph. The poses must then be the odometry's.
    """
    import small_gicp

    from pointfield.registration.icp import solver_threads

    start = np.linalg.inv(poses[first]) @ poses[first:stop]
    clouds = points[first:stop]
    edges = []
    for k in range(len(clouds) - 1):
        motion = np.linalg.inv(start[k]) @ start[k + 1]  # frame k + 1 into frame k, as the odometry has it
        given = None if information is None else information[first + k]
        edges.append(PoseGraphEdge(k + 1, k, motion,
                                   given if given is not None else _information_at(clouds[k + 1], clouds[k], motion, voxel)))
    keyframes = [k for k in range(0, len(clouds), keyframe_interval) if len(clouds[k]) >= 3]
    world = {k: clouds[k] @ start[k][:3, :3].T + start[k][:3, 3] for k in keyframes}
    meeting = [(a, b) for a in keyframes for b in keyframes if b > a + 1 and _boxes_meet(world[a], world[b], voxel)]
    centres = {k: world[k].mean(axis=0) for k in keyframes}
    prepared = {}
    for a, b in nearest_pairs(centres, meeting, max_partners):
        for k in (a, b):
            if k not in prepared:
                prepared[k] = small_gicp.preprocess_points(clouds[k], downsampling_resolution=voxel,
                                                           num_neighbors=20, num_threads=solver_threads(len(clouds[k])))
        guess = np.linalg.inv(start[b]) @ start[a]  # keyframe a into keyframe b's frame
        (source, _), (target, tree) = prepared[a], prepared[b]
        for reach in (4 * voxel, voxel):  # coarse (room for the odometry's drift), then within the inlier distance
            found = small_gicp.align(target, source, tree, init_T_target_source=guess, registration_type="GICP",
                                     max_correspondence_distance=reach, num_threads=solver_threads(source.size()))
            guess = np.asarray(found.T_target_source, np.float64)
        if source.size() and found.num_inliers / source.size() >= min_fitness:
            edges.append(PoseGraphEdge(a, b, guess, _information_at(clouds[a], clouds[b], guess, voxel),
                                       uncertain=True))
    loops = sum(e.uncertain for e in edges)
    if not loops:
        return poses[first:stop].copy(), 0, 0, 0
    optimised = optimize_pose_graph(PoseGraph(start, edges), FRAGMENT_CORRESPONDENCE * voxel, reference=0,
                                    preference_loop_closure=FRAGMENT_PREFERENCE_LOOP_CLOSURE)
    return poses[first] @ optimised.poses, loops, loops - len(optimised.pruned), len(optimised.pruned)


def _register(source: np.ndarray, target: np.ndarray, guess: np.ndarray, voxel: float, allow_global: bool,
              min_fitness: float):
    """``(result, how)``: fine from ``guess``; where that links too little and ``allow_global``, FPFH +
    RANSAC, then fine.

    The fine step is generalized ICP at two levels, the clouds thinned to ``2 voxel`` with partners
    within ``4 voxel`` (room for the odometry's drift), then as they are within ``voxel``: the
    fragments are thinned to ``voxel`` already, and the guess is close.
    """
    from pointfield.registration.estimation import GeneralizedICP
    from pointfield.registration.icp import multiscale_icp
    from pointfield.registration.pairwise import register
    from pointfield.registration.scan import Scan

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a low fitness is decided on below
        result = multiscale_icp(Scan(source), Scan(target), [2 * voxel, 0.0], [4 * voxel, voxel], guess,
                                GeneralizedICP())
        if (result is None or result.fitness < min_fitness) and allow_global:
            try:
                found = register(source, target, method="global", voxel=voxel)
            except PointfieldError:
                found = None
            if found is not None and (result is None or found.fitness > result.fitness):
                return found, "global"
    return result, "fine"


def nearest_pairs(centres: list[np.ndarray] | dict[int, np.ndarray], pairs: list[tuple[int, int]], limit: int | None) -> list[tuple[int, int]]:
    """The ``pairs`` ``(i, j)`` among the ``limit`` nearest of ``i``'s or of ``j``'s, by the distance between their
    ``centres`` (each ``(3,)``; what two clouds see is nearer where they share more): at most ``limit`` per node,
    so the pairs registered grow as ``n limit``, not ``n^2``. ``limit`` None: every pair."""
    if limit is None:
        return list(pairs)
    ranked: dict[int, list] = {}
    for pair in pairs:
        distance = float(np.linalg.norm(centres[pair[0]] - centres[pair[1]]))
        for node in pair:
            ranked.setdefault(node, []).append((distance, pair))
    kept = {pair for near in ranked.values() for _, pair in sorted(near)[:limit]}
    return [pair for pair in pairs if pair in kept]


def _boxes_meet(a: np.ndarray, b: np.ndarray, margin: float) -> bool:
    if not len(a) or not len(b):
        return False
    gap = np.maximum(a.min(axis=0) - b.max(axis=0), b.min(axis=0) - a.max(axis=0))
    return bool(np.max(gap) <= margin)


def fragment_poses(poses: np.ndarray, points: list[np.ndarray], fragment_size: int = DEFAULT_FRAGMENT_SIZE, *,
                   voxel: float = 0.02, loop_closure: bool = True, global_registration: bool = True,
                   min_fitness: float = MIN_FITNESS,
                   preference_loop_closure: float = PREFERENCE_LOOP_CLOSURE,
                   keyframe_interval: int | None = KEYFRAME_INTERVAL,
                   max_loop_partners: int | None = MAX_LOOP_PARTNERS,
                   information: list[np.ndarray | None] | None = None) -> FragmentPoses:
    """Odometry ``poses`` ``(N, 4, 4)`` refined over fragments and a pose graph (module docstring).

    ``points``: each frame's thinned camera-frame cloud ``(M_f, 3)`` (``Odometry.points``);
    ``voxel``: the fragments' thinning and the registrations' inlier distance (metres);
    ``loop_closure``: register non-consecutive fragments too; ``global_registration``: let a loop
    closure start from anywhere where the odometry's guess links too little; ``keyframe_interval``:
    every so many frames a keyframe, for the pose graph within each fragment
    (:func:`fragment_pose_graph`; None: keep the odometry within fragments); ``max_loop_partners``:
    of the pairs whose boxes meet, each fragment's so many nearest are registered (:func:`nearest_pairs`;
    None: all of them); ``information``: the odometry's information of each step, for the fragments'
    own pose graphs (:func:`fragment_pose_graph`; None: measured there).
    """
    poses = np.asarray(poses, np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or len(points) != len(poses):
        raise PointfieldError(f"fragments need (N, 4, 4) poses and N clouds, got {poses.shape} and {len(points)}")
    if not (np.isfinite(voxel) and voxel > 0):
        raise PointfieldError(f"the fragment voxel must be a positive number of metres, got {voxel}")
    ranges = split_fragments(len(poses), fragment_size)
    if keyframe_interval is not None and keyframe_interval < 1:
        raise PointfieldError(f"the keyframe interval must be a positive number of frames, got {keyframe_interval}")
    within = [0, 0, 0]  # keyframe pairs registered, kept, pruned over every fragment's own pose graph
    if keyframe_interval is not None and len(ranges) > 1:
        poses = poses.copy()
        for first, stop in ranges:
            poses[first:stop], *counts = fragment_pose_graph(poses, points, first, stop, voxel, keyframe_interval,
                                                             min_fitness, information=information)
            within = [a + b for a, b in zip(within, counts)]
    start = np.stack([poses[first] for first, _ in ranges])
    clouds = [fragment_cloud(points, poses, first, stop, voxel) for first, stop in ranges]
    last = ranges[-1][1] - ranges[-1][0]
    notes = [f"{len(ranges)} fragments of {fragment_size} frames" + (f" (the last {last})" if last != fragment_size else "")]
    if keyframe_interval is not None and len(ranges) > 1:
        notes.append(f"within fragments: keyframes every {keyframe_interval} frames, {within[0]} pairs linked, "
                     f"{within[1]} kept, {within[2]} pruned by each fragment's pose graph")
    if len(ranges) < 2:
        return FragmentPoses(poses.copy(), ranges, start, start.copy(), [], 0, notes, tuple(within))
    world = [c @ p[:3, :3].T + p[:3, 3] for c, p in zip(clouds, start)]
    pairs: list[FragmentPair] = []
    meeting = [(i, j) for i in range(len(ranges)) for j in range(i + 2, len(ranges))
               if loop_closure and _boxes_meet(world[i], world[j], 4 * voxel)]
    tried = nearest_pairs([w.mean(axis=0) if len(w) else np.zeros(3) for w in world], meeting, max_loop_partners)
    candidates = len(tried)
    for i, j in sorted([(i, i + 1) for i in range(len(ranges) - 1)] + tried):
        consecutive = j == i + 1
        guess = np.linalg.inv(start[j]) @ start[i]  # maps fragment i into j's frame, as the odometry has it
        result, how = (None, "fine") if min(len(clouds[i]), len(clouds[j])) < 3 else _register(
            clouds[i], clouds[j], guess, voxel, global_registration and not consecutive, min_fitness)
        if result is None or result.fitness < min_fitness:
            if consecutive:  # the odometry links them: its guess is the edge, weighed by what it matches
                information = _information_at(clouds[i], clouds[j], guess, voxel)
                pairs.append(FragmentPair(i, j, guess, 0.0 if result is None else result.fitness, information,
                                          "odometry", "odometry"))
                notes.append(f"fragments {i}-{j}: registration linked too little "
                             f"(fitness {0.0 if result is None else result.fitness:.2f}); the odometry kept")
            continue
        pairs.append(FragmentPair(i, j, result.transformation, result.fitness, result.information,
                                  "odometry" if consecutive else "loop closure", how))
    edges = [PoseGraphEdge(p.source, p.target, p.transformation, p.information, uncertain=p.kind == "loop closure")
             for p in pairs]
    optimised = optimize_pose_graph(PoseGraph(start, edges), voxel, reference=0,
                                    preference_loop_closure=preference_loop_closure)
    for pair, weight in zip(pairs, optimised.weights):
        pair.kept = bool(weight > 0)
    refined = np.empty_like(poses)
    for k, (first, stop) in enumerate(ranges):
        refined[first:stop] = optimised.poses[k] @ np.linalg.inv(start[k]) @ poses[first:stop]
    loops = [p for p in pairs if p.kind == "loop closure"]
    if loop_closure:
        notes.append(f"loop closures: {len(meeting)} pairs whose boxes meet, {candidates} tried (at most "
                     f"{max_loop_partners} nearest a fragment), {len(loops)} registered "
                     f"(fitness >= {min_fitness:g}), {sum(p.kept for p in loops)} kept, "
                     f"{sum(not p.kept for p in loops)} pruned by the pose graph"
                     + ("".join(f"; {p.source}-{p.target} {p.how} {p.fitness:.2f}"
                                + ("" if p.kept else " pruned") for p in loops)))
    return FragmentPoses(refined, ranges, start, optimised.poses, pairs, candidates, notes, tuple(within))


def _information_at(source: np.ndarray, target: np.ndarray, transformation: np.ndarray, voxel: float) -> np.ndarray:
    """``(6, 6)`` the information of ``transformation`` from the correspondences within ``voxel`` it makes."""
    from scipy.spatial import cKDTree

    from pointfield.registration.result import evaluate, information_matrix

    if not len(source) or not len(target):
        return np.eye(6) * 1e-6
    _, _, pairs = evaluate(source, cKDTree(target), transformation, voxel)
    return information_matrix(target, pairs) + np.eye(6) * 1e-6


__all__ = ["DEFAULT_FRAGMENT_SIZE", "FragmentPair", "FragmentPoses", "KEYFRAME_INTERVAL", "MAX_KEYFRAME_PARTNERS",
           "MAX_LOOP_PARTNERS", "fragment_cloud", "fragment_pose_graph", "fragment_poses", "nearest_pairs",
           "split_fragments"]
