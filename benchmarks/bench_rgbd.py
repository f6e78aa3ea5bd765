"""RGB-D sequence to mesh: `scene from-rgbd` against open3d's odometry and TSDF on the same 60 frames.

The frames are open3d's own living-room test sequence (ICL-NUIM, 640 x 480, ../shared/data/rgbd/
livingroom1_micro); open3d's reconstruction system posed all 211 frames of it (fragments, pose
graphs, refinement) into ``open3d_trajectory.log``, the reference the trajectories are scored
against: absolute trajectory error (camera centres, RMSE after the best rigid alignment).

The peer runs the same steps as ``scene from-rgbd``, end to end, in open3d: read the frames,
``pipelines.odometry.compute_rgbd_odometry`` frame to frame (the hybrid photometric + geometric
term, open3d's default pyramid, ``depth_max`` 3 m, ``depth_diff_max`` 0.07 m as its
reconstruction system sets them), each pair from identity as ``make_fragments.py`` does for
neighbours, then TSDF fusion of every frame at its pose in a ``t.geometry.VoxelBlockGrid`` at the
same voxel and truncation (open3d's legacy ScalableTSDFVolume makes no mesh in the 0.20 CPU wheel
installed here: bench_tsdf) and its marching cubes, the mesh written as PLY. pointfield runs
``reconstruct_rgbd`` with its defaults (odometry: generalized ICP on depth clouds thinned to
2 cm; fusion: voxel 1 cm, truncation 4 voxels, depth beyond 3 m dropped), which also writes the
scene folder. Each is run ``--repeats`` times, interleaved.

Fragments and loop closures (``--fragment-size``, ``--loop-closure``) are measured on poses alone
(no fusion), on three sequences: the 60 frames as they are; the 60 frames played forward then
backward (``0 .. 59, 58 .. 0``, 119 frames), a camera that returns exactly to its first view, so
that the end-to-start distance of a trajectory is its drift; and that sequence's odometry bent by
a steady drift (each step turned 0.05 degree and slid 0.5 mm more: a biased sensor, the same
clouds). Each is posed by odometry alone, by fragments of 20 frames that keep the odometry within
them (as before fragments had pose graphs of their own) with loop closures, and by fragments with
their own pose graphs without and with loop closures; the peers on the same frames are open3d's
frame-to-frame hybrid odometry, and open3d's own pose-graph optimisation
(``global_optimization``, Levenberg-Marquardt, the same options) over pointfield's fragment
edges. Last, the fragment stage's cost on 1,000 frames (the 60 frames' odometry played forward
and back, every fragment's box meeting every other's): loop candidates are capped at each
fragment's 8 nearest, and the cost of registering all of them is estimated from the measured
cost of one.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from pointfield.registration.odometry import absolute_trajectory_error
from pointfield.scenes.rgbd import read_log_trajectory, read_rgbd_folder, reconstruct_rgbd

from harness import Record, interleaved

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
ROOM = DATA / "rgbd" / "livingroom1_micro"
VOXEL = 0.01
TRUNCATION_VOXELS = 4.0
DEPTH_MAX = 3.0


def run_pointfield(out: Path) -> np.ndarray:
    result = reconstruct_rgbd(ROOM, out, intrinsics=ROOM / "camera_primesense.json", voxel=VOXEL,
                              depth_max=DEPTH_MAX, overwrite=True, device="cpu")
    return result.poses


def run_open3d(out: Path) -> np.ndarray:
    """open3d's frame-to-frame RGB-D odometry, VoxelBlockGrid fusion and marching cubes, the mesh written."""
    import open3d as o3d
    import open3d.core as o3c

    frames = read_rgbd_folder(ROOM)
    intrinsic = o3d.io.read_pinhole_camera_intrinsic(str(ROOM / "camera_primesense.json"))
    images = [(o3d.io.read_image(str(c)), o3d.io.read_image(str(d))) for c, d in zip(frames.colour, frames.depth)]
    rgbd = [o3d.geometry.RGBDImage.create_from_color_and_depth(c, d, depth_trunc=DEPTH_MAX,
                                                                convert_rgb_to_intensity=True) for c, d in images]
    option = o3d.pipelines.odometry.OdometryOption(depth_diff_max=0.07, depth_max=DEPTH_MAX)
    poses = [np.eye(4)]
    for i in range(1, len(rgbd)):
        _, motion, _ = o3d.pipelines.odometry.compute_rgbd_odometry(
            rgbd[i], rgbd[i - 1], intrinsic, np.eye(4), o3d.pipelines.odometry.RGBDOdometryJacobianFromHybridTerm(),
            option)
        poses.append(poses[-1] @ motion)
    grid = o3d.t.geometry.VoxelBlockGrid(
        attr_names=("tsdf", "weight", "color"), attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
        attr_channels=((1), (1), (3)), voxel_size=VOXEL, block_resolution=8, block_count=50_000,
        device=o3c.Device("CPU:0"))
    k = o3c.Tensor(intrinsic.intrinsic_matrix)
    for (colour, depth), pose in zip(images, poses):
        extrinsic = o3c.Tensor(np.linalg.inv(pose))
        depth_image = o3d.t.geometry.Image.from_legacy(depth)
        colour_image = o3d.t.geometry.Image.from_legacy(colour)  # uint16 depth with uint8 colour, as the kernel takes
        blocks = grid.compute_unique_block_coordinates(depth_image, k, extrinsic, 1000.0, DEPTH_MAX,
                                                       trunc_voxel_multiplier=TRUNCATION_VOXELS)
        grid.integrate(blocks, depth_image, colour_image, k, k, extrinsic, 1000.0, DEPTH_MAX,
                       trunc_voxel_multiplier=TRUNCATION_VOXELS)
    mesh = grid.extract_triangle_mesh(weight_threshold=1.0)
    mesh.vertex.colors = mesh.vertex.colors / 255.0  # fused from uint8 colour: 0..255
    o3d.t.io.write_triangle_mesh(str(out / "open3d_mesh.ply"), mesh)
    return np.stack(poses)


def odometry_alternatives(frames, camera) -> dict[str, tuple[np.ndarray, float]]:
    """Frame-to-frame odometry by other estimations of pointfield's registration (each from the last
    motion, clouds thinned to 2 cm, two levels: 4 cm then 2 cm): ``name -> (poses, seconds)``."""
    from pointfield.registration import ColoredICP, PointToPlane, Scan, multiscale_icp
    from pointfield.registration.odometry import backproject
    from pointfield.scenes.rgbd import read_colour, read_depth

    scans = []
    for depth_path, colour_path in zip(frames.depth, frames.colour):
        depth = read_depth(depth_path, camera, 1000.0, DEPTH_MAX)[::2, ::2]
        colour = read_colour(colour_path, camera)[::2, ::2]
        points = backproject(depth, camera.scaled(2))
        scans.append(Scan(points, intensity=colour[depth > 0].mean(axis=1).astype(np.float64)).downsample(0.02))
    out = {}
    for name, estimation in (("pointfield coloured ICP (numpy)", ColoredICP()),
                             ("pointfield point-to-plane ICP (small_gicp)", PointToPlane())):
        started = time.perf_counter()
        poses, motion = [np.eye(4)], np.eye(4)
        for i in range(1, len(scans)):
            motion = multiscale_icp(scans[i], scans[i - 1], [0.04, 0.0], [0.08, 0.03], motion, estimation).transformation
            poses.append(poses[-1] @ motion)
        out[name] = (np.stack(poses), time.perf_counter() - started)
    return out


def end_to_start(poses: np.ndarray) -> tuple[float, float]:
    """``(metres, degrees)`` of the motion from the first camera to the last."""
    from scipy.spatial.transform import Rotation

    motion = np.linalg.inv(poses[0]) @ poses[-1]
    return float(np.linalg.norm(motion[:3, 3])), float(np.degrees(Rotation.from_matrix(motion[:3, :3]).magnitude()))


def open3d_odometry(frames, order: list[int]) -> np.ndarray:
    """open3d's frame-to-frame hybrid RGB-D odometry over the frames in ``order`` (as ``run_open3d``)."""
    import open3d as o3d

    intrinsic = o3d.io.read_pinhole_camera_intrinsic(str(ROOM / "camera_primesense.json"))
    rgbd = [o3d.geometry.RGBDImage.create_from_color_and_depth(o3d.io.read_image(str(c)), o3d.io.read_image(str(d)),
                                                                depth_trunc=DEPTH_MAX, convert_rgb_to_intensity=True)
            for c, d in zip(frames.colour, frames.depth)]
    option = o3d.pipelines.odometry.OdometryOption(depth_diff_max=0.07, depth_max=DEPTH_MAX)
    poses = [np.eye(4)]
    for previous, current in zip(order, order[1:]):
        _, motion, _ = o3d.pipelines.odometry.compute_rgbd_odometry(
            rgbd[current], rgbd[previous], intrinsic, np.eye(4),
            o3d.pipelines.odometry.RGBDOdometryJacobianFromHybridTerm(), option)
        poses.append(poses[-1] @ motion)
    return np.stack(poses)


def open3d_pose_graph(fragments, voxel: float) -> np.ndarray:
    """Frame poses from open3d's ``global_optimization`` over the same fragment graph pointfield optimised (each
    frame kept where pointfield's own graph of its fragment put it)."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    graph = reg.PoseGraph()
    for pose in fragments.initial_fragment_poses:
        graph.nodes.append(reg.PoseGraphNode(pose))
    for pair in fragments.pairs:  # the same convention: P_target T = P_source
        graph.edges.append(reg.PoseGraphEdge(pair.source, pair.target, pair.transformation, pair.information,
                                             uncertain=pair.kind == "loop closure"))
    option = reg.GlobalOptimizationOption(max_correspondence_distance=voxel, edge_prune_threshold=0.25,
                                          preference_loop_closure=5.0, reference_node=0)
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        reg.global_optimization(graph, reg.GlobalOptimizationLevenbergMarquardt(),
                                reg.GlobalOptimizationConvergenceCriteria(), option)
    refined = np.empty_like(fragments.poses)
    for k, (first, stop) in enumerate(fragments.fragments):
        # pointfield's frames are P_k P0_k^-1 within_f: the same within-fragment poses, under open3d's P_k
        refined[first:stop] = np.asarray(graph.nodes[k].pose) @ np.linalg.inv(fragments.fragment_poses[k]) \
            @ fragments.poses[first:stop]
    return refined


def drifted(poses: np.ndarray, degrees: float) -> np.ndarray:
    """``poses`` with every step turned ``degrees`` more about the camera's y axis and slid ``degrees`` cm along x and z:
    an odometry that drifts steadily (a biased sensor), on the same frames."""
    from scipy.spatial.transform import Rotation

    bias = np.eye(4)
    bias[:3, :3], bias[:3, 3] = Rotation.from_euler("y", degrees, degrees=True).as_matrix(), [degrees / 100, 0, degrees / 100]
    out = [np.eye(4)]
    for before, after in zip(poses[:-1], poses[1:]):
        out.append(out[-1] @ np.linalg.inv(before) @ after @ bias)
    return np.stack(out)


DRIFT_DEGREES = 0.05
"""The drift injected into the forward-and-backward odometry, per frame (119 frames: 6 degrees, 7.8 cm at the end)."""


def fragment_modes(reference: np.ndarray, fragment_size: int = 20, voxel: float = 0.02) -> tuple[list, dict, object]:
    """Rows (and figures) of odometry alone, fragments (odometry or their own pose graph within), with loop closures,
    and the open3d peers, on the 60 frames, on them played forward then backward, and on that with a drift
    injected into the odometry; and the 60 frames' odometry, for :func:`long_sequence`."""
    from pointfield.registration.fragments import fragment_poses
    from pointfield.registration.odometry import rgbd_odometry
    from pointfield.scenes.rgbd import read_depth, read_intrinsics

    frames = read_rgbd_folder(ROOM)
    camera = read_intrinsics(ROOM / "camera_primesense.json")
    depths = [read_depth(p, camera, 1000.0, DEPTH_MAX) for p in frames.depth]
    rows, figures, first = [], {}, None
    count = len(depths)
    back = list(range(count)) + list(range(count - 2, -1, -1))
    injected = f"forward + backward, {DRIFT_DEGREES} deg a frame injected"
    for sequence, order in (("60 frames", list(range(count))), ("forward + backward", back), (injected, back)):
        truth = reference[order]
        if sequence != injected:
            started = time.perf_counter()
            odometry = rgbd_odometry([depths[i] for i in order], camera, voxel=voxel)
            seconds = time.perf_counter() - started
            first = first or odometry
            poses = odometry.poses
        else:  # the same clouds, the odometry bent
            poses, seconds = drifted(odometry.poses, DRIFT_DEGREES), 0.0
        results = [("pointfield odometry alone" + (" (drift injected)" if sequence == injected else ""), poses,
                    seconds, "-", "-")]
        for within, loops in ((None, True), (5, False), (5, True)):
            started = time.perf_counter()
            found = fragment_poses(poses, odometry.points, fragment_size, voxel=voxel, loop_closure=loops,
                                   keyframe_interval=within)
            seconds = time.perf_counter() - started
            edges = f"{found.loops_kept} / {found.loops_pruned}" if loops else "not tried"
            name = ("pointfield fragments, odometry within" if within is None else "pointfield fragments, own graphs") \
                + (" + loop closures" if loops else "")
            results.append((name, found.poses, seconds, len(found.fragments), edges))
        started = time.perf_counter()
        peer_graph = open3d_pose_graph(found, voxel)
        results.append(("open3d global_optimization, same edges", peer_graph, time.perf_counter() - started,
                        len(found.fragments), "(pointfield's)"))
        if sequence != injected:
            started = time.perf_counter()
            peer = open3d_odometry(frames, order)
            results.append(("open3d hybrid odometry alone", peer, time.perf_counter() - started, "-", "-"))
        for name, poses_found, seconds, fragments, edges in results:
            ate = absolute_trajectory_error(poses_found, truth)
            distance, angle = end_to_start(poses_found)
            drift = f"{100 * distance:.3f} cm, {angle:.3f} deg" if sequence != "60 frames" else "-"
            rows.append([sequence, name, fragments, edges, f"{seconds:.1f}", f"{100 * ate:.3f}", drift])
            figures[f"{sequence}: {name}"] = {"ate_m": ate, "end_to_start_m": distance, "end_to_start_deg": angle,
                                              "seconds": seconds}
    return rows, figures, first


LONG_FRAMES = 1000


def long_sequence(odometry, voxel: float = 0.02) -> tuple[list, dict]:
    """The fragment stage's cost on a 1,000-frame sequence: the 60 frames' odometry played forward, backward,
    forward ... (poses and thinned clouds reused, no new odometry), so that every fragment's box meets every
    other's -- a long sequence in one room, where loop candidates grow as n^2. Fragments of 100 frames
    (the default) and of 20; with 20, loop closures off and on, so that their difference over the pairs
    tried is the seconds a loop candidate costs, and the pairs whose boxes meet, at that price, what
    registering all of them (no cap) would cost."""
    from pointfield.registration.fragments import fragment_poses

    period = list(range(len(odometry.poses))) + list(range(len(odometry.poses) - 2, 0, -1))
    order = (period * (LONG_FRAMES // len(period) + 1))[:LONG_FRAMES]
    poses, points = odometry.poses[order], [odometry.points[i] for i in order]
    rows, figures = [], {}
    for size, loops in ((100, True), (20, False), (20, True)):
        started = time.perf_counter()
        found = fragment_poses(poses, points, size, voxel=voxel, loop_closure=loops)
        seconds = time.perf_counter() - started
        meeting = int(next((n.split(" pairs whose")[0].split(": ")[-1] for n in found.notes if "pairs whose" in n), 0))
        key = f"fragments of {size}" + (" + loop closures" if loops else "")
        figures[key] = {"seconds": seconds, "fragments": len(found.fragments), "pairs_meeting": meeting,
                        "pairs_tried": found.loop_candidates, "loops_kept": found.loops_kept,
                        "loops_pruned": found.loops_pruned, "keyframe_pairs": list(found.keyframe_pairs)}
        rows.append([LONG_FRAMES, size, len(found.fragments), f"{found.keyframe_pairs[0]}",
                     f"{meeting} / {found.loop_candidates}" if loops else "not tried",
                     f"{found.loops_kept} / {found.loops_pruned}" if loops else "-", f"{seconds:.1f}"])
    on, off = figures["fragments of 20 + loop closures"], figures["fragments of 20"]
    per_pair = (on["seconds"] - off["seconds"]) / max(on["pairs_tried"], 1)
    figures["seconds_per_loop_candidate"] = per_pair
    figures["uncapped_estimate_seconds"] = off["seconds"] + per_pair * on["pairs_meeting"]
    return rows, figures


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=1, help="timed runs per contender (default 1)")
    args = parser.parse_args()
    if not ROOM.is_dir():
        print(f"the living-room frames are not here: {ROOM} does not exist", file=sys.stderr)
        return 1
    import open3d as o3d

    record = Record("rgbd", "RGB-D frames to a posed, fused mesh against open3d", issue="44",
                    about=__doc__.split("\n\n", 1)[1].replace("\n", " ")
                    + f" open3d {o3d.__version__}; the machine's 2 cores are shared with other jobs.")
    reference = read_log_trajectory(ROOM / "open3d_trajectory.log")
    frames = len(read_rgbd_folder(ROOM))
    reference = reference[:frames]
    with tempfile.TemporaryDirectory() as scratch:
        scratch = Path(scratch)
        poses: dict[str, np.ndarray] = {}

        def timed(name, run):
            def call():
                poses[name] = run(scratch / name.split()[0])
            return call

        (scratch / "open3d").mkdir()
        contenders = {"pointfield scene from-rgbd": timed("pointfield scene from-rgbd", run_pointfield),
                      "open3d odometry + VoxelBlockGrid": timed("open3d odometry + VoxelBlockGrid", run_open3d)}
        started = time.perf_counter()
        timings = interleaved(contenders, repeats=args.repeats, warmup=0)
        wall = time.perf_counter() - started
        report = __import__("json").loads((scratch / "pointfield" / "report.json").read_text())
    errors = {name: absolute_trajectory_error(p, reference) for name, p in poses.items()}
    rows = [[name, frames, f"{timings[name].median:.1f}", f"{timings[name].spread:.2f}", f"{100 * errors[name]:.2f}"]
            for name in contenders]
    record.table(["pipeline", "frames", "median s", "spread", "ATE vs open3d's reconstruction (cm)"], rows,
                 title="60 frames of open3d's living room, posed and fused end to end (2 shared cores)")
    record.figures = {"timings": {name: t.as_dict() for name, t in timings.items()},
                      "ate_m": errors, "frames": frames, "wall_seconds": wall,
                      "pointfield_stages_seconds": report["seconds"], "pointfield_mesh_faces": report["faces"],
                      "pointfield_fitness_min": report["fitness_min"]}
    ours, peer = timings["pointfield scene from-rgbd"].median, timings["open3d odometry + VoxelBlockGrid"].median
    record.note(f"pointfield's stages (last run): odometry {report['seconds']['odometry']:.1f} s, fusion and "
                f"meshing {report['seconds']['fusion']:.1f} s, total with writing the scene "
                f"{report['seconds']['total']:.1f} s.")
    from pointfield.scenes.rgbd import read_intrinsics

    alternatives = odometry_alternatives(read_rgbd_folder(ROOM), read_intrinsics(ROOM / "camera_primesense.json"))
    odometry_rows = [["pointfield generalized ICP (small_gicp; the default)",
                      f"{report['seconds']['odometry']:.1f}", f"{100 * errors['pointfield scene from-rgbd']:.2f}"],
                     ["open3d hybrid RGB-D odometry", "-", f"{100 * errors['open3d odometry + VoxelBlockGrid']:.2f}"]]
    odometry_rows += [[name, f"{seconds:.1f}", f"{100 * absolute_trajectory_error(p, reference):.2f}"]
                      for name, (p, seconds) in alternatives.items()]
    record.figures["odometry_alternatives"] = {name: {"seconds": seconds, "ate_m": absolute_trajectory_error(p, reference)}
                                               for name, (p, seconds) in alternatives.items()}
    record.table(["frame-to-frame odometry", "seconds (reading included for pointfield's default)",
                  "ATE vs open3d's reconstruction (cm)"], odometry_rows,
                 title="Which odometry: the same 60 frames, each pair from the last motion")
    fragment_rows, record.figures["fragments"], odometry60 = fragment_modes(reference)
    record.table(["sequence", "poses by", "fragments", "loop closures kept / pruned",
                  "seconds (odometry or the fragment stage)", "ATE vs open3d's reconstruction (cm)",
                  "end to start (the drift)"],
                 fragment_rows, title="Fragments of 20 frames, their own pose graphs and loop closures (poses only, "
                 "voxel 2 cm; the second and third sequences return to their first view)")
    long_rows, record.figures["long_sequence"] = long_sequence(odometry60)
    record.table(["frames", "fragment size", "fragments", "keyframe pairs linked", "loop pairs meeting / tried",
                  "loop closures kept / pruned", "seconds (fragment stage)"], long_rows,
                 title=f"The fragment stage on {LONG_FRAMES} frames (the 60 played forward and back; every box meets "
                 "every other)")
    cost = record.figures["long_sequence"]
    record.note(f"{LONG_FRAMES} frames in fragments of 20: a loop candidate costs "
                f"{cost['seconds_per_loop_candidate']:.2f} s; registering every pair whose boxes meet "
                f"({cost['fragments of 20 + loop closures']['pairs_meeting']}) would take about "
                f"{cost['uncapped_estimate_seconds']:.0f} s against "
                f"{cost['fragments of 20 + loop closures']['seconds']:.0f} s with each fragment's 8 nearest "
                "(an estimate: the uncapped run is not made).")
    loop = record.figures["fragments"]
    ours60 = loop["60 frames: pointfield fragments, own graphs + loop closures"]["ate_m"]
    odometry_only = loop["60 frames: pointfield odometry alone"]["ate_m"]
    record.verdict("fragments keep the 60 frames within 0.1 cm ATE of the odometry alone", ours60 <= odometry_only + 0.001,
                   f"{100 * ours60:.3f} cm against {100 * odometry_only:.3f} cm")
    closed = loop["forward + backward: pointfield fragments, own graphs + loop closures"]["end_to_start_m"]
    drifted_odometry = loop["forward + backward: pointfield odometry alone"]["end_to_start_m"]
    record.verdict("loop closures bring the camera that returns nearer its start than the odometry alone",
                   closed < drifted_odometry, f"{100 * closed:.3f} cm against {100 * drifted_odometry:.3f} cm")
    injected = f"forward + backward, {DRIFT_DEGREES} deg a frame injected"
    within = loop[f"{injected}: pointfield fragments, own graphs + loop closures"]["end_to_start_m"]
    without = loop[f"{injected}: pointfield fragments, odometry within + loop closures"]["end_to_start_m"]
    record.verdict("with a drift injected, fragments' own pose graphs bring the camera nearer its start than "
                   "fragments that keep the odometry within", within < without,
                   f"{100 * within:.3f} cm against {100 * without:.3f} cm")
    record.verdict("the trajectory is within 2 cm ATE of open3d's reconstruction",
                   errors["pointfield scene from-rgbd"] < 0.02, f"{100 * errors['pointfield scene from-rgbd']:.2f} cm")
    record.verdict("pointfield takes less time than open3d's odometry and fusion of the same frames", ours < peer,
                   f"{ours:.1f} s against {peer:.1f} s ({peer / ours:.2f}x)")
    return record.finish()


if __name__ == "__main__":
    sys.exit(main())
