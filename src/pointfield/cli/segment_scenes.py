"""``pointfield segment`` on whole scans: ``train DATA...`` on scenes, ``make-scenes``, and ``eval`` /
``predict`` of scene runs.

``segment train`` trains on scenes (:func:`pointfield.clouds.scene_tasks.train_scenes`) when
DATA is a scene dataset in its own layout (S3DIS, ScanNet v2, SemanticKITTI), one or more
labelled files, or a folder with a ``classes.json`` class table (what ``make-scenes`` writes);
otherwise (a folder of object clouds, ShapeNetPart, no DATA) it trains on objects as before.
``make-scenes`` sits in this group, not in ``pointfield scene`` (posed images for radiance
fields), because what it makes is segmentation data: labelled clouds and their class table.
``eval`` and ``predict`` (``segment.run_predict``) open the run and do what its task does.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from pointfield.cli.classify import print_per_class
from pointfield.cli.classify import run_eval as run_object_eval
from pointfield.cli.classify import run_train as run_object_train
from pointfield.cli.training_options import max_time_left

DEFAULT_OBJECT_MODEL = "pointnet"
DEFAULT_OBJECT_POINTS = 1024
SCENE_LAYOUT_FILES = ("classes.json",)


def add_scene_arguments(parser: argparse.ArgumentParser) -> None:
    """The ``segment train`` options that only scenes take."""
    scenes = parser.add_argument_group("scenes (DATA a scene dataset or labelled files)")
    scenes.add_argument("--features", help="comma-separated inputs besides xyz: colour, intensity, normals, height "
                        "(default: colour and intensity where the data has them, and height)")
    scenes.add_argument("--grid", type=float, help="grid subsampling cell in metres (default 0.05; 0: none)")
    scenes.add_argument("--radius", type=float, help="crop radius in metres (default 2.0)")
    scenes.add_argument("--crop", dest="shape", choices=("sphere", "block"),
                        help="crop shape: a ball (default) or a vertical column of square section")
    scenes.add_argument("--crops", type=int, help="training crops per epoch (default 256)")
    scenes.add_argument("--max-time", type=float, metavar="S",
                        help="the whole command returns within S seconds of wall clock: reading the scans, training, "
                        "the evaluation after each epoch (left out when it would not fit) and the final scores")
    scenes.add_argument("--classes", help="class names of labelled files, comma-separated (code i is the i-th) "
                        "or a JSON file; default: a classes.json beside the files")
    scenes.add_argument("--test-area", type=int, help="S3DIS area held out for testing (default 5)")


def add_predict_scale_options(parser: argparse.ArgumentParser) -> None:
    """``segment predict``'s ``--memory``, ``--scratch`` and ``--no-progress`` (scene runs)."""
    scale = parser.add_argument_group("memory (scene runs)")
    scale.add_argument("--memory", metavar="SIZE",
                       help="resident memory the prediction may use, e.g. 2G or 512M (default: what is free); a scan "
                       "that does not fit read whole is predicted tile by tile, with the same labels (to float rounding)")
    scale.add_argument("--scratch", type=Path, metavar="DIR",
                       help="folder for the tiles' temporary spills (default: beside the output)")
    scale.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bars")


def predict_scale(args: argparse.Namespace) -> dict[str, Any]:
    """The options of :func:`add_predict_scale_options` as :meth:`SceneRun.predict` takes them."""
    if args.memory is not None:
        from pointfield.streaming.memory import parse_memory

        parse_memory(args.memory)  # a malformed size is refused before the run is opened
    return {"memory": args.memory, "scratch": args.scratch, "progress": args.progress}


def add_make_scenes_parser(verbs: argparse._SubParsersAction) -> None:
    make = verbs.add_parser(
        "make-scenes", help="write synthetic labelled scans of rooms or streets",
        description="Write COUNT synthetic scans (rooms: floor, wall, ceiling, table, chair, shelf, seen by a "
        "depth camera; streets: ground, building, tree, car, pole, seen by a spinning lidar) to OUT/train and "
        "OUT/test, with OUT/classes.json; train on them with 'pointfield segment train OUT'.",
    )
    make.add_argument("out", type=Path, metavar="OUT", help="folder to write")
    make.add_argument("--kind", choices=("room", "street"), default="room", help="room (default) or street")
    make.add_argument("--count", type=int, default=10, help="scans to write (default 10; a fifth go to test/)")
    make.add_argument("--seed", type=int, default=0, help="seed of the first scan (default 0)")
    make.add_argument("--density", type=float, default=1.0,
                      help="rays relative to the default sensor (default 1.0: about 150k per room)")
    make.add_argument("--format", default="ply", help="file format of the scans (default ply)")
    make.set_defaults(run=run_make_scenes)


def is_scene_data(paths: list[Path]) -> bool:
    """Whether DATA is for scene training (see the module doc)."""
    from pointfield.clouds.datasets import scene_layout

    if not paths:
        return False
    if any(p.is_file() for p in paths) or len(paths) > 1:
        return True
    return scene_layout(paths) != "labelled" or any((paths[0] / name).is_file() for name in SCENE_LAYOUT_FILES)


def run_train(args: argparse.Namespace) -> int:
    from pointfield.errors import PointfieldError

    if not is_scene_data(args.data):
        if len(args.data) > 1:
            raise PointfieldError("objects train on one DATA folder; several DATA are for scenes")
        if args.max_time is not None:
            raise PointfieldError("--max-time is for scene training; objects train for --epochs")
        args.data = args.data[0] if args.data else None
        args.model = args.model or DEFAULT_OBJECT_MODEL
        args.points = args.points or DEFAULT_OBJECT_POINTS
        args.label_field = args.label_field or "label"
        return run_object_train(args, "segment")
    from pointfield.clouds.scene_tasks import train_scenes

    features = [f.strip() for f in args.features.split(",") if f.strip()] if args.features else None
    if args.normals:
        features = [*(features or []), "normals"]
    metrics = train_scenes(
        args.data, out=args.out, model=args.model, features=features, grid=args.grid, radius=args.radius,
        shape=args.shape, points=args.points, crops=args.crops, epochs=args.epochs, batch_size=args.batch_size,
        learning_rate=args.learning_rate, label_field=args.label_field, class_names=_class_names(args.classes),
        test_area=args.test_area, seed=args.seed, device=args.device, resume=args.resume,
        max_time=max_time_left(args),
        workers=args.workers, progress=args.progress,
    )
    print(f"segment run {args.out}: {_scores(metrics)} ({metrics['epochs']} epochs, {metrics['seconds']:.0f} s); "
          f"see {args.out / 'metrics.json'}")
    print_per_class(metrics["per_class"], "IoU")
    return 0


def _class_names(option: str | None) -> list[str] | None:
    if option is None:
        return None
    path = Path(option)
    if path.suffix == ".json" and path.is_file():
        from pointfield.clouds.datasets.labelled import read_class_table

        return list(read_class_table(path).values())
    return [name.strip() for name in option.split(",")]


def _scores(metrics: dict[str, Any]) -> str:
    return f"overall accuracy {metrics['accuracy']:.4f}, mIoU {metrics['miou']:.4f}"


def scene_run_task(run_dir: Path) -> bool:
    """Whether the run folder holds a scene run (its config's task)."""
    config = Path(run_dir) / "config.json"
    try:
        return json.loads(config.read_text()).get("task") == "segment-scenes"
    except (OSError, ValueError):
        return False  # the object path reports what is wrong with the folder


def run_eval(args: argparse.Namespace) -> int:
    if not scene_run_task(args.run_dir):
        return run_object_eval(args, "segment")
    from pointfield.clouds.scene_tasks import open_scene_run
    from pointfield.training.run import to_json

    metrics = open_scene_run(args.run_dir, args.device).evaluate([args.data] if args.data else None)
    if args.json:
        print(to_json(metrics, indent=2))
        return 0
    print(f"{metrics['scans']} test scans, {metrics['points']:,} points: {_scores(metrics)}")
    print_per_class(metrics["per_class"], "IoU")
    return 0


def run_make_scenes(args: argparse.Namespace) -> int:
    from pointfield.clouds.synthetic_scenes import make_scenes

    written = make_scenes(args.out, args.kind, args.count, seed=args.seed, density=args.density,
                          suffix="." + args.format.lstrip("."))
    print(f"{len(written)} {args.kind} scans in {args.out} (train/, test/, classes.json)")
    return 0
