"""``pointfield route INPUT [INPUT ...] [--task WORDS] [--json]``: which 3D representation fits, and the commands.

A thin layer over :func:`pointfield.route.route` (imported when the command runs, so that other
commands start fast).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Add ``route`` to the ``pointfield`` parser."""
    parser = subparsers.add_parser(
        "route",
        help="what you have and what you want -> the representation to use and the commands to run",
        description="Look at what you have -- a point-cloud or mesh file, Gaussian splats, photos or a folder of "
        "them, a video, a posed dataset (Blender, nerfstudio / instant-ngp, LLFF, COLMAP), a run folder -- "
        "reading headers only, and say which representation fits the task (point cloud, mesh, voxels, "
        "radiance field, Gaussian splats), why, and the pointfield commands to run next, in order.",
    )
    parser.add_argument("inputs", nargs="+", type=Path, metavar="INPUT",
                        help="a file or folder; several files when they are photos, or clouds and meshes")
    parser.add_argument("--task", metavar="WORDS",
                        help="what you want, in a few words (quote them): classify, segment, reconstruct, novel "
                        "views, mesh for a game engine, measure, real-time viewing, a robot's collision map "
                        "(default: what the input is best at)")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object: schema, inputs, input_kind, details, task, task_words, "
                        "representation, reason, commands, python, notes")
    parser.set_defaults(run=run_route)


def run_route(args: argparse.Namespace) -> int:
    from pointfield.route import format_route, route

    answer = route(args.inputs, task=args.task)
    print(json.dumps(answer.to_dict(), indent=2) if args.json else format_route(answer))
    return 0
