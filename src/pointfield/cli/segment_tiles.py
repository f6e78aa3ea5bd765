"""``pointfield segment predict RUN TILES/ --out OUT/ [--workers N | --scheduler ADDRESS]``: the tiles of one
scan predicted as one, a task per tile on Dask (:meth:`pointfield.clouds.scene_tasks.SceneRun.predict_tiles`).

A folder among the inputs, or ``--tiles``, makes the inputs tiles of one scan: each tile's crops
see its neighbours' points, so the labels show no seam at the tiles' borders. ``--workers`` and
``--scheduler`` are the streaming verbs' (:mod:`~pointfield.cli.cloud_streaming`).
"""

from __future__ import annotations

import argparse

from pointfield.errors import PointfieldError


def add_tile_options(parser: argparse.ArgumentParser) -> None:
    """``--tiles``, ``--workers``, ``--scheduler`` of ``segment predict``."""
    tiles = parser.add_argument_group("tiles of one scan (scene runs)")
    tiles.add_argument("--tiles", action="store_true",
                       help="the FILEs are tiles of one scan: each tile's crops see its neighbours' points, so no "
                       "seam shows at the borders (implied when a FILE is a folder); OUT is a folder")
    where = tiles.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, metavar="N", help="predict the tiles on a local Dask cluster of N "
                       "worker processes")
    where.add_argument("--scheduler", metavar="ADDRESS", help="predict the tiles on an existing Dask cluster, "
                       "e.g. tcp://host:8786")


def wants_tiles(args: argparse.Namespace) -> bool:
    """Whether the inputs are tiles of one scan (see the module doc); Dask options without them are refused."""
    tiles = args.tiles or any(path.is_dir() for path in args.files)
    if not tiles and (args.workers is not None or args.scheduler is not None):
        raise PointfieldError("--workers and --scheduler predict the tiles of one scan: give a folder of tiles, "
                              "or --tiles with the files")
    if tiles and args.memory is not None:
        raise PointfieldError("--memory applies to scans predicted one by one; a tile is read whole with its halo")
    return tiles


def run_predict_tiles(args: argparse.Namespace) -> list[dict]:
    """The tiles predicted by a scene run; the answers as :meth:`SceneRun.predict_tiles` gives them."""
    from pointfield.clouds.scene_tasks import open_scene_run

    if args.workers is not None and args.workers < 1:
        raise PointfieldError(f"--workers must be at least 1, got {args.workers}")
    run = open_scene_run(args.run_dir, args.device)
    return run.predict_tiles(args.files, out=args.out, workers=args.workers, scheduler=args.scheduler,
                             progress=args.progress)
