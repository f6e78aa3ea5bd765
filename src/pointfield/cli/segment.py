"""``pointfield segment train|eval|predict``: per-point labels with the PointNet family.

Each subcommand calls the function of the same name and arguments in
:mod:`pointfield.clouds.tasks` (train) and :mod:`pointfield.clouds.run` (eval, predict) with ``task="segment"`` (``eval`` calls ``evaluate``); the training
options are those of ``pointfield classify train`` plus ``--label-field``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from pointfield.cli import segment_scenes, segment_tiles
from pointfield.cli.classify import DEFAULT_RUN_COST, add_eval_parser, add_training_arguments


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Add ``segment`` and its subcommands to the ``pointfield`` parser."""
    group = subparsers.add_parser(
        "segment",
        help="train, evaluate and apply per-point segmenters (PointNet, PointNet++)",
        description="Label every point of a cloud (parts, or semantic classes). DATA is a "
        "folder of clouds whose per-point integer field (--label-field, default 'label') "
        "holds the labels, with optional train/ and test/ subfolders, or ShapeNetPart. Without DATA, the "
        "built-in synthetic shapes and their 17 parts. Whole scans train on crops: DATA an S3DIS, "
        "ScanNet v2 or SemanticKITTI folder, labelled files in any format, or a folder from make-scenes "
        "(see docs/scenes.md).",
    )
    verbs = group.add_subparsers(dest="verb", metavar="SUBCOMMAND", required=True)
    train = verbs.add_parser(
        "train", help="train a segmenter into a run folder",
        description="Train a per-point segmenter into a run folder. " + DEFAULT_RUN_COST["segment"],
    )
    add_training_arguments(train, "segment")
    segment_scenes.add_scene_arguments(train)
    train.set_defaults(run=segment_scenes.run_train)
    add_eval_parser(verbs, "segment")
    verbs.choices["eval"].set_defaults(run=segment_scenes.run_eval)
    predict = verbs.add_parser(
        "predict", help="label every point of files with a trained run",
        description="Write each FILE, labelled, to OUT/<name>.ply with an int32 'label' field "
        "(a mesh keeps its faces), and print how many points each part got. With a scene run, "
        "overlapping crops vote; OUT is a file (one FILE) or a folder of outputs named as their inputs, "
        "with the labels (LAS: classification) and a 'confidence' field, and a .classes.json beside each. "
        "A folder of tiles (or FILEs with --tiles) is predicted as one scan, each tile's crops seeing its "
        "neighbours' points, into OUT/<tile name>, on Dask with --workers or --scheduler.",
    )
    predict.add_argument("run_dir", type=Path, metavar="RUN", help="a run folder from segment train")
    predict.add_argument("files", type=Path, nargs="+", metavar="FILE", help="clouds or meshes, or folders of tiles")
    predict.add_argument("--out", type=Path, help="folder for the labelled clouds, or a file for one scan "
                         "(default: RUN/predictions)")
    predict.add_argument("--device", help="auto (default), cpu, cuda, cuda:N or mps")
    predict.add_argument("--json", action="store_true", help="print JSON")
    segment_scenes.add_predict_scale_options(predict)
    segment_tiles.add_tile_options(predict)
    predict.set_defaults(run=run_predict)
    segment_scenes.add_make_scenes_parser(verbs)


def run_predict(args: argparse.Namespace) -> int:
    """Label the files with an object run (answers count ``parts``) or a scene run (``classes``)."""
    if segment_scenes.scene_run_task(args.run_dir) and segment_tiles.wants_tiles(args):
        answers = segment_tiles.run_predict_tiles(args)
        counted = "classes"
    elif segment_scenes.scene_run_task(args.run_dir):
        from pointfield.clouds.scene_tasks import open_scene_run

        answers = open_scene_run(args.run_dir, args.device).predict(args.files, out=args.out,
                                                                    **segment_scenes.predict_scale(args))
        counted = "classes"
    else:
        from pointfield.clouds import run
        from pointfield.errors import PointfieldError

        if args.tiles or args.workers is not None or args.scheduler is not None:
            raise PointfieldError(f"{args.run_dir}: --tiles, --workers and --scheduler are for scene runs; "
                                  "this run labels objects")
        answers = run.predict("segment", args.run_dir, args.files, device=args.device, out=args.out)
        counted = "parts"
    if args.json:
        print(json.dumps(answers, indent=2))
        return 0
    for answer in answers:
        counts = ", ".join(f"{name} {count}" for name, count in answer[counted].items())
        print(f"{answer['file']} -> {answer['output']}: {answer['points']} points ({counts})")
    return 0
