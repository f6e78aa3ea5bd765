"""``pointfield view PATH [PATH ...]``: clouds, meshes, scenes, splats and runs in the browser.

A thin layer over :func:`pointfield.viewer.view`. viser and torch are imported only when the
command runs, so other commands start fast.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

DEFAULT_HOST = "127.0.0.1"  # pointfield.viewer.server.DEFAULT_HOST, without importing viser
DEFAULT_PORT = 8080
DEFAULT_MAX_POINTS = 2_000_000  # pointfield.viewer.clouds.DEFAULT_MAX_POINTS


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Add ``view`` to the ``pointfield`` parser."""
    parser = subparsers.add_parser(
        "view", help="show clouds, meshes, scenes, splats and runs in the browser",
        description="Serve a page that shows every PATH in 3D: a cloud or mesh file in any format "
        "pointfield reads (decimated past --max-points, coloured by any field), a scene folder "
        "(camera frustums with thumbnails, sparse points), a splat .ply or splat run (the "
        "Gaussians), a nerf run (rendered on the server from the browser's camera). Several "
        "PATHs share one page. Ctrl-C stops it.",
    )
    parser.add_argument("paths", nargs="+", type=Path, metavar="PATH", help="file or folder to show")
    parser.add_argument("--host", default=DEFAULT_HOST,
                        help=f"address to bind (default {DEFAULT_HOST}: this machine only)")
    parser.add_argument("--port", type=int, default=DEFAULT_PORT,
                        help=f"port (default {DEFAULT_PORT}; the next free one when it is taken)")
    parser.add_argument("--max-points", type=int, default=DEFAULT_MAX_POINTS,
                        help=f"show at most this many points of a cloud (default {DEFAULT_MAX_POINTS:,})")
    parser.add_argument("--device", help="device that renders runs: auto (default), cpu, cuda, cuda:N or mps")
    parser.set_defaults(run=run_view)


def address(viewer) -> str:
    """The page's URL, and the port used when the asked-for one was taken."""
    return f"{viewer.url} ({viewer.port_note})" if viewer.port_note else viewer.url


def announce(viewer) -> None:
    """Print where the page is, the moment the server listens (before large files are read)."""
    print(f"pointfield view: open {address(viewer)}; Ctrl-C to stop", flush=True)


def run_view(args: argparse.Namespace) -> int:
    from pointfield.viewer import view

    try:
        view(args.paths, host=args.host, port=args.port, max_points=args.max_points, device=args.device,
             on_started=announce)
    except KeyboardInterrupt:  # Ctrl-C while files were still being read: as clean a stop as later
        pass
    print("pointfield view: stopped", flush=True)
    return 0


def add_view_options(parser: argparse.ArgumentParser) -> None:
    """``--view``, ``--view-host`` and ``--view-port`` of ``nerf train`` and ``splat train``."""
    parser.add_argument("--view", action="store_true",
                        help="watch training in the browser: the model rendered from your camera, step, loss, "
                             "held-out PSNR; pause / resume from the page")
    parser.add_argument("--view-host", default=DEFAULT_HOST, help=f"with --view: address to bind (default {DEFAULT_HOST})")
    parser.add_argument("--view-port", type=int, default=DEFAULT_PORT,
                        help=f"with --view: port (default {DEFAULT_PORT}; the next free one when it is taken)")


@contextmanager
def training_view(args: argparse.Namespace) -> Iterator[None]:
    """With ``--view``: the block trains into ``args.out`` watched by a page; once it has, the
    page keeps the trained model up until Ctrl-C. If training fails, the page closes."""
    if not args.view:
        yield
        return
    from pointfield.viewer.training import watch_training

    view = watch_training(args.out, host=args.view_host, port=args.view_port)
    print(f"watch training at {address(view.viewer)}", flush=True)
    try:
        yield
    except BaseException:
        view.viewer.close()
        raise
    view.finish()
    print(f"the page stays up at {view.viewer.url} with the trained model; Ctrl-C to stop", flush=True)
    view.serve()
    print("pointfield view: stopped", flush=True)
