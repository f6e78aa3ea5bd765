"""``pointfield demo``: the main job on built-in data (see :func:`pointfield.demo.run_demo`)."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Add ``demo`` to the ``pointfield`` parser."""
    demo = subparsers.add_parser(
        "demo",
        help="generate clouds, round-trip them through every format, render them; train a NeRF",
        description="Generate a few clouds and a mesh, write each in every format and encoding "
        "that can hold it, read them back and check that nothing was lost, print a summary "
        "table and write PNG renders. Then train TinyNeRF on the built-in synthetic cube "
        "(about two minutes on a 2-core CPU), print its held-out PSNR and write a turntable "
        "GIF. Exits non-zero if any round trip failed.",
    )
    demo.add_argument(
        "--out", type=Path, default=Path("demo-output"), help="output folder (default: demo-output)"
    )
    demo.add_argument(
        "--quick", action="store_true",
        help="small clouds, images and NeRF: seconds instead of ~2 minutes",
    )
    demo.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from pointfield.demo import run_demo

    report = run_demo(args.out, quick=args.quick)
    return 0 if report.all_ok else 1
