"""``pointfield classify train|eval|predict``: shape classification with the PointNet family.

Each subcommand calls the function of the same name and arguments in
:mod:`pointfield.clouds.tasks` (train) and :mod:`pointfield.clouds.run` (eval, predict) with ``task="classify"`` (``eval`` calls ``evaluate``). torch is
imported only when a subcommand runs, so other commands start fast.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
from typing import Any

MODELS = ("pointnet", "pointnet2", "pointnet2-msg")
SCENE_MODELS = ("ptv3",)  # segment train on scenes only
DEFAULT_RUN_COST = {
    "classify": "A default run (PointNet, 10 epochs of the built-in shapes) takes about 15 minutes on a 2-core "
    "laptop CPU, 90 seconds an epoch (one epoch costs about 170 CPU-seconds; docs/runs.md).",
    "segment": "A default run (PointNet, 10 epochs of the built-in shapes' parts) takes about 25 minutes on a "
    "2-core laptop CPU, 2.5 minutes an epoch (one epoch costs about 240 CPU-seconds; docs/runs.md).",
}
"""What a default run costs, said in ``train --help`` (measured: docs/runs.md)."""


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Add ``classify`` and its subcommands to the ``pointfield`` parser."""
    group = subparsers.add_parser(
        "classify",
        help="train, evaluate and apply shape classifiers (PointNet, PointNet++)",
        description="Classify whole point clouds. DATA is a folder with one subfolder per class "
        "(files in any format pointfield reads; meshes are surface-sampled; optional train/ and "
        "test/ subfolders), or a ModelNet folder (raw OFF, modelnet40_normal_resampled, "
        "ply_hdf5_2048). Without DATA, the built-in synthetic shapes (10 classes).",
    )
    verbs = group.add_subparsers(dest="verb", metavar="SUBCOMMAND", required=True)
    train = verbs.add_parser(
        "train", help="train a classifier into a run folder",
        description="Train a shape classifier into a run folder. " + DEFAULT_RUN_COST["classify"],
    )
    add_training_arguments(train, "classify")
    train.set_defaults(run=lambda args: run_train(args, "classify"))
    add_eval_parser(verbs, "classify")
    predict = verbs.add_parser(
        "predict", help="classify files with a trained run",
        description="Print the class and its probability for each file; with --json, a list "
        "of objects with file, class, probability and probabilities (by class name). The "
        "answer does not depend on the order of the points in the file.",
    )
    predict.add_argument("run_dir", type=Path, metavar="RUN", help="a run folder from classify train")
    predict.add_argument("files", type=Path, nargs="+", metavar="FILE", help="clouds or meshes")
    predict.add_argument("--device", help="auto (default), cpu, cuda, cuda:N or mps")
    predict.add_argument("--json", action="store_true", help="print JSON")
    predict.set_defaults(run=run_predict)


def add_training_arguments(parser: argparse.ArgumentParser, task: str) -> None:
    """The ``train`` arguments shared by ``classify`` and ``segment``."""
    scenes = task == "segment"
    parser.add_argument(
        "data", nargs="*" if scenes else "?", type=Path, metavar="DATA",
        help="training data: a folder, or for segment also a scene dataset or labelled files "
        "(default: the built-in synthetic shapes)",
    )
    parser.add_argument("--model", choices=MODELS + (SCENE_MODELS if scenes else ()),
                        default=None if scenes else "pointnet",
                        help="pointnet (default; scenes: pointnet2), pointnet2 (PointNet++ SSG) or pointnet2-msg"
                        + ("; for scenes also ptv3 (Point Transformer V3)" if scenes else ""))
    parser.add_argument("--epochs", type=int, help="epochs (default: pointnet 10, pointnet2 5)")
    parser.add_argument("--batch-size", type=int,
                        help="clouds per batch, per process (default: pointnet 32, pointnet2 16)")
    parser.add_argument("--points", type=int, default=None if scenes else 1024,
                        help="points per cloud (default 1024; scene crops: 4096)")
    parser.add_argument("--out", type=Path, default=Path(f"runs/{task}"),
                        help=f"run folder to write (default runs/{task})")
    parser.add_argument("--device", help="auto (default), cpu, cuda, cuda:N or mps")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--resume", action="store_true",
                        help="continue the run in --out from its last checkpoint")
    parser.add_argument("--normals", action="store_true",
                        help="feed per-point normals to the model as well as xyz")
    parser.add_argument("--no-input-transform", dest="input_transform", action="store_false",
                        help="PointNet without its input (3x3) T-Net")
    parser.add_argument("--no-feature-transform", dest="feature_transform",
                        action="store_false", help="PointNet without its feature (64x64) T-Net")
    parser.add_argument("--lr", dest="learning_rate", type=float, default=1e-3,
                        help="Adam learning rate (default 0.001, cosine-decayed)")
    parser.add_argument("--workers", type=int, default=0,
                        help="DataLoader worker processes (default 0: load in the main process)")
    parser.add_argument("--on-error", choices=("skip", "fail"), default="skip",
                        help="a DATA file that cannot be read: skip it with a warning (default) "
                        "or stop")
    parser.add_argument("--shapes-per-class", type=int,
                        help="synthetic training shapes per class (default 100; test: 30 %%)")
    parser.add_argument("--no-progress", dest="progress", action="store_false",
                        help="no progress bar")
    if task == "segment":
        parser.add_argument("--label-field",
                            help="per-point integer field holding the labels (default: label; labelled "
                            "scans: classification or label)")


def add_eval_parser(verbs: argparse._SubParsersAction, task: str) -> None:
    evaluate = verbs.add_parser(
        "eval", help="score a trained run on test data",
        description="Score a trained run on the test split of DATA (default: the data it was "
        "trained on): accuracy, mean class accuracy" + (", mIoU" if task == "segment" else "")
        + " and the score of each class.",
    )
    evaluate.add_argument("run_dir", type=Path, metavar="RUN", help=f"a run folder from {task} train")
    evaluate.add_argument("data", type=Path, nargs="?", metavar="DATA",
                          help="test data (default: the run's own)")
    evaluate.add_argument("--device", help="auto (default), cpu, cuda, cuda:N or mps")
    evaluate.add_argument("--on-error", choices=("skip", "fail"), default="skip",
                          help="unreadable DATA files: skip with a warning (default) or stop")
    evaluate.add_argument("--json", action="store_true", help="print JSON")
    evaluate.set_defaults(run=lambda args: run_eval(args, task))


def run_train(args: argparse.Namespace, task: str) -> int:
    from pointfield.clouds import tasks

    options: dict[str, Any] = dict(
        model=args.model, epochs=args.epochs, batch_size=args.batch_size, points=args.points,
        out=args.out, device=args.device, seed=args.seed, resume=args.resume,
        normals=args.normals, input_transform=args.input_transform,
        feature_transform=args.feature_transform, learning_rate=args.learning_rate,
        workers=args.workers, on_error=args.on_error, shapes_per_class=args.shapes_per_class,
        progress=args.progress,
    )
    if task == "segment":
        options["label_field"] = args.label_field
    metrics = tasks.train(task, args.data, **options)
    if os.environ.get("RANK", "0") == "0":
        epochs = metrics["epochs"]
        print(f"{task} run {args.out}: {_scores_line(metrics)} ({epochs} epoch{'' if epochs == 1 else 's'}, "
              f"{metrics['seconds']:.0f} s); see {args.out / 'metrics.json'}")
    return 0


def run_eval(args: argparse.Namespace, task: str) -> int:
    from pointfield.clouds import run
    from pointfield.training.run import to_json

    metrics = run.evaluate(task, args.run_dir, args.data, device=args.device, on_error=args.on_error)
    if args.json:
        print(to_json(metrics, indent=2))
        return 0
    print(f"{metrics['samples']} test clouds: {_scores_line(metrics)}")
    print_per_class(metrics["per_class"], "IoU" if task == "segment" else "accuracy")
    if "per_category" in metrics:
        print_per_class(metrics["per_category"], "mIoU")
    return 0


def print_per_class(per_class: dict[str, float | None], label: str) -> None:
    """One line per class: its ``label`` score, or "absent" where the test data holds none of it."""
    width = max(len(name) for name in per_class)
    for name, value in per_class.items():
        print(f"  {name:<{width}}  {label} {'absent' if value is None else f'{value:.4f}'}")


def run_predict(args: argparse.Namespace) -> int:
    from pointfield.clouds import run

    answers = run.predict("classify", args.run_dir, args.files, device=args.device)
    if args.json:
        print(json.dumps(answers, indent=2))
    else:
        for answer in answers:
            print(f"{answer['file']}: {answer['class']} ({answer['probability']:.3f})")
    return 0


def _scores_line(metrics: dict[str, Any]) -> str:
    parts = [f"accuracy {metrics['accuracy']:.4f}",
             f"mean class accuracy {metrics['mean_class_accuracy']:.4f}"]
    if "miou" in metrics:
        parts.append(f"mIoU {metrics['miou']:.4f}")
    if "instance_miou" in metrics:  # ShapeNetPart's per-shape scores
        parts.append(f"instance mIoU {metrics['instance_miou']:.4f}, class mIoU {metrics['class_miou']:.4f}")
    return ", ".join(parts)
