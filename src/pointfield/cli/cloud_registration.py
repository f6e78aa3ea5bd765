"""``pointfield cloud register``: the rigid motion that maps one scan onto another.

A thin layer over :func:`pointfield.registration.pairwise.register`; ``--out`` writes the source moved
by it through :func:`pointfield.write`, every field kept and normals rotated
(:func:`pointfield.registration.aligned`).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from pointfield.errors import PointfieldError
from pointfield.streaming.memory import DEFAULT_MEMORY

METHOD_HELP = ("auto (default: global when no --init, then coloured, point-to-plane or generalized ICP by what the "
               "clouds carry), icp (point-to-point), plane (point-to-plane), gicp (generalized), colored (Park et al.; "
               "both clouds need colours), global (FPFH + RANSAC from any pose, then the fine step)")


def add_commands(commands: argparse._SubParsersAction) -> None:
    """Add ``register`` to the ``cloud`` subcommands."""
    register = commands.add_parser(
        "register",
        help="align SOURCE onto TARGET: the 4x4 motion, fitness and RMSE",
        description="Find the rigid motion that maps SOURCE onto TARGET (ICP variants from a pose, or global "
        "FPFH + RANSAC from any pose), print it with its fitness (share of SOURCE within the inlier distance of "
        "TARGET) and inlier RMSE, and with --out write SOURCE moved by it. Every choice made for you (voxel, "
        "method) is printed.",
    )
    register.add_argument("source", type=Path, metavar="SOURCE", help="the cloud to move")
    register.add_argument("target", type=Path, metavar="TARGET", help="the cloud to move it onto")
    register.add_argument("--method", default="auto",
                          choices=("auto", "icp", "plane", "gicp", "colored", "global"), help=METHOD_HELP)
    register.add_argument("--init", type=Path, metavar="T.json",
                          help="starting motion: a JSON 4x4 matrix, or an object with a 'transformation' (as --json prints)")
    register.add_argument("--voxel", type=float, metavar="S",
                          help="scale of the problem in the clouds' units (default: the median point spacing)")
    register.add_argument("--max-distance", type=float, metavar="D",
                          help="inlier distance of the fine step, fitness and RMSE (default: the voxel)")
    register.add_argument("--kernel", choices=("huber", "tukey"), help="robust kernel against outliers (default none)")
    register.add_argument("--seed", type=int, default=0, help="seed of RANSAC (default 0)")
    register.add_argument("--memory", metavar="SIZE", default=DEFAULT_MEMORY,
                          help=f"memory registration may take, e.g. 2G (default {DEFAULT_MEMORY}); a pair that does not "
                          "fit is thinned to the voxel while reading, and refused naming the voxel that fits if still "
                          "too big")
    register.add_argument("--out", type=Path, metavar="ALIGNED",
                          help="write SOURCE moved onto TARGET, in the format its suffix names, every field kept")
    register.add_argument("--json", action="store_true",
                          help='print {"transformation", "fitness", "rmse", "method", ...} as JSON on stdout')
    register.set_defaults(run=run_register)


def read_init(path: Path) -> object:
    """The matrix in a --init file: a 4x4 list, or an object whose 'transformation' is one."""
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as error:
        raise PointfieldError(f"{path}: not JSON ({error.msg} at line {error.lineno})") from None
    except UnicodeDecodeError:
        raise PointfieldError(f"{path}: not a JSON text file") from None
    if isinstance(data, dict):
        if "transformation" not in data:
            raise PointfieldError(f"{path}: expected a 4x4 matrix or an object with 'transformation'")
        data = data["transformation"]
    return data


def run_register(args: argparse.Namespace) -> int:
    import pointfield
    from pointfield.registration import aligned, check_cloud, check_transformation, register
    from pointfield.registration.streamed import read_scans, write_moved

    (source, target), thinned = read_scans([args.source, args.target], args.voxel, args.memory,
                                            scratch=None if args.out is None else args.out.resolve().parent)
    check_cloud(source, str(args.source))
    check_cloud(target, str(args.target))
    init = None if args.init is None else check_transformation(read_init(args.init), str(args.init))
    result = register(source, target, method=args.method, init=init, voxel=args.voxel,
                      max_distance=args.max_distance, kernel=args.kernel, seed=args.seed)
    result.notes[:0] = thinned
    if args.out is not None and thinned:  # SOURCE did not fit whole: moved a chunk at a time from its file
        write_moved([args.source], [result.transformation], args.out, memory=args.memory)
    elif args.out is not None:
        pointfield.write(args.out, aligned(source, result.transformation))
    if args.json:
        print(json.dumps(result.as_dict(), indent=2))
    else:
        rows = "\n".join("  " + " ".join(f"{v: .6f}" for v in row) for row in result.transformation)
        print(f"{result.method}: fitness {result.fitness:.4f}, inlier RMSE {result.inlier_rmse:.4g} "
              f"({len(result.correspondence_set):,} correspondences within {result.max_distance:.4g})\n{rows}")
        for note in result.notes:
            print(f"  {note}", file=sys.stderr)
        if args.out is not None:
            print(f"wrote {args.out}: {f'every point of {args.source}' if thinned else f'{len(source):,} points'} moved onto {args.target}")
    return 0
