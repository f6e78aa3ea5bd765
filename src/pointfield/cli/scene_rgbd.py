"""``pointfield scene from-rgbd``: an RGB-D sequence posed, fused into a mesh, and written as a scene.

A thin layer over :func:`pointfield.scenes.rgbd.reconstruct_rgbd`, which is imported (and torch with
it) only when the command runs.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def add_commands(verbs: argparse._SubParsersAction) -> None:
    """Add ``from-rgbd`` to the ``scene`` subcommands."""
    parser = verbs.add_parser(
        "from-rgbd",
        help="pose an RGB-D sequence by odometry, fuse it into a mesh, write a scene",
        description="Read an RGB-D sequence (depth/ beside image/ or color/, as Redwood and open3d's "
        "reconstruction system lay it out, or TUM's rgb.txt and depth.txt), pose it frame to frame "
        "(generalized ICP on the depth), refine long sequences over fragments and a pose graph with loop "
        "closures, fuse it into a TSDF and write SCENE: mesh.ply, cloud.ply, "
        "trajectory.txt (TUM), trajectory.log (open3d), transforms.json with the posed colour images and "
        "their depth (what `nerf train` and `splat train` read), report.json.",
    )
    parser.add_argument("folder", type=Path, metavar="FOLDER", help="the sequence's folder")
    parser.add_argument("--intrinsics", type=Path, metavar="camera.json",
                        help="open3d's PinholeCameraIntrinsic JSON (default: the folder's one camera*.json)")
    parser.add_argument("--out", type=Path, required=True, metavar="SCENE", help="scene folder to write")
    parser.add_argument("--depth-scale", type=float, metavar="S",
                        help="stored depth units per metre (default 1000; 5000 for a TUM layout)")
    parser.add_argument("--depth-max", type=float, default=3.0, metavar="M",
                        help="drop depth farther than M metres (default 3)")
    parser.add_argument("--voxel", type=float, default=0.01, metavar="V", help="TSDF voxel, metres (default 0.01)")
    parser.add_argument("--odometry-voxel", type=float, default=0.02, metavar="V",
                        help="odometry clouds thinned to one point per V metres (default 0.02)")
    parser.add_argument("--frames", type=int, metavar="N", help="only the first N frames")
    parser.add_argument("--fragment-size", type=int, default=100, metavar="N",
                        help="a sequence of more than 2N frames is cut into fragments of N frames, registered "
                        "pairwise and put through a pose graph, as open3d's reconstruction system (default 100, "
                        "open3d's; 0: never)")
    parser.add_argument("--loop-closure", action=argparse.BooleanOptionalAction, default=True,
                        help="with fragments, register non-consecutive ones too (loop closures), so that a camera "
                        "that comes back lands where it started (default on)")
    parser.add_argument("--keyframe-every", type=int, default=5, metavar="N",
                        help="within each fragment every Nth frame is a keyframe, registered onto its nearest "
                        "keyframes for the fragment's own pose graph, as open3d's make_fragments (default 5, "
                        "open3d's; 0: none, the odometry kept within fragments)")
    parser.add_argument("--device", help="where to fuse: cpu, cuda, mps (default: the best available)")
    parser.add_argument("--fusion-threads", type=int, default=1, metavar="N",
                        help="torch threads while fusing on the CPU (default 1: each frame's work is too small to "
                        "share; 0 leaves torch's own setting)")
    parser.add_argument("--overwrite", action="store_true", help="replace SCENE if it exists")
    parser.add_argument("--json", action="store_true", help="print the report as JSON")
    parser.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bars")
    parser.set_defaults(run=run_from_rgbd)


def run_from_rgbd(args: argparse.Namespace) -> int:
    from pointfield.scenes.rgbd import reconstruct_rgbd

    result = reconstruct_rgbd(args.folder, args.out, intrinsics=args.intrinsics, depth_scale=args.depth_scale,
                              depth_max=args.depth_max, voxel=args.voxel, odometry_voxel=args.odometry_voxel,
                              frames=args.frames, fragment_size=args.fragment_size,
                              loop_closure=args.loop_closure, keyframe_every=args.keyframe_every,
                              overwrite=args.overwrite, device=args.device,
                              fusion_threads=None if args.fusion_threads == 0 else args.fusion_threads,
                              progress=args.progress)
    print(json.dumps(result.report, indent=2) if args.json else result.format())
    return 0
