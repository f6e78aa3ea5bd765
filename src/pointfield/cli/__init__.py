"""The ``pointfield`` command: one verb group per module, each adding its subcommands here.

Every subcommand is a thin layer over a Python function of the same name and arguments, so
whatever the command line does can be done from Python.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from collections.abc import Sequence

import pointfield
from pointfield.cli import (
    classify,
    cloud,
    demo,
    nerf,
    route,
    scene,
    segment,
    splat,
    view,
)
from pointfield.errors import PointfieldError

# Each module exposes add_parser(subparsers); order is the order `pointfield --help` lists them.
VERB_GROUPS = (cloud, classify, segment, scene, nerf, splat, view, route, demo)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pointfield",
        description="3D vision toolkit: point clouds, radiance fields and Gaussian splats.",
    )
    parser.add_argument("--version", action="version", version=f"pointfield {pointfield.__version__}")
    subparsers = parser.add_subparsers(dest="group", metavar="COMMAND", required=True)
    for group in VERB_GROUPS:
        group.add_parser(subparsers)
    return parser


def print_warning(message: Warning | str, category: type[Warning], filename: str, lineno: int, file=None,
                  line: str | None = None) -> None:
    """The command's :func:`warnings.showwarning`: one ``pointfield: warning:`` line on stderr, as
    errors are one ``pointfield: error:`` line, with no source file or line of code a user cannot act on."""
    print(f"pointfield: warning: {message}", file=sys.stderr)


def main(argv: Sequence[str] | None = None) -> int:
    """Run a command; expected failures print one line to stderr and return non-zero, and each
    warning is printed, when it happens, as one line (:func:`print_warning`)."""
    started = time.perf_counter()  # what --max-time counts from
    args = build_parser().parse_args(argv)
    args.started = started
    with warnings.catch_warnings():
        warnings.showwarning = print_warning
        code = _run(args)
    if "WORLD_SIZE" in os.environ:  # launched by torchrun
        from pointfield.training.distributed import exit_joined

        return exit_joined(code)
    return code


def _run(args: argparse.Namespace) -> int:
    try:
        return int(args.run(args) or 0)
    except (PointfieldError, FileNotFoundError, IsADirectoryError, PermissionError) as error:
        # A PointfieldError may say its message in the command line's words (--resume, not resume=True).
        print(f"pointfield: error: {getattr(error, 'command_line', None) or error}", file=sys.stderr)
        return 1
    except BrokenPipeError:
        # `pointfield cloud info x | head` closed our stdout: not an error; silence the flush.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except KeyboardInterrupt:
        print("pointfield: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
