"""PointNet and PointNet++ on the CPU: speed against the lesson's PointNet, and accuracy.

Claims checked (issue 3):

1. Speed: pointfield's PointNet trains and infers at least 1.3x the samples per second of the
   same network written the way the lesson writes it (Conv1d layers on ``(B, C, N)``, same
   layer sizes, same batch), with the same accuracy (both trained with the same recipe).
2. Accuracy on the synthetic shapes (10 classes, 1,024 points): PointNet >= 95 %, PointNet++
   >= 97 % test accuracy with the default recipe of ``pointfield classify train``; the time
   each took on this machine.

Also printed: parameter counts, and samples per second of PointNet with T-Nets and of
PointNet++ SSG / MSG.

Usage::

    python benchmarks/bench_pointnet.py              # parameters, speed, same-recipe accuracy
                                                     # (about 8 min on 2 cores)
    python benchmarks/bench_pointnet.py --full       # and the synthetic-shape accuracy claims
                                                     # (about 30 min more on 2 cores)
    python benchmarks/bench_pointnet.py --quick      # a smoke run of every part (~3 min)
    python benchmarks/bench_pointnet.py --only speed # just the speed table

Results are printed and recorded in ``benchmarks/records/pointnet.json`` (harness.py).
"""

from __future__ import annotations

import argparse
import shutil
import sys
import time
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from pointfield.clouds.datasets import CloudCollate
from pointfield.clouds.models import (
    PointNet2Classifier,
    PointNet2Segmenter,
    PointNetClassifier,
    PointNetSegmenter,
    count_parameters,
)
from pointfield.clouds.shapes import SyntheticShapes
from pointfield.clouds.tasks import confusion_on, evaluation_transform, training_transform
from pointfield.metrics import accuracy
from pointfield.training import fit

from harness import Record, interleaved

CLASSES = 10
POINTS = 1024


class LessonPointNet(nn.Module):
    """The reference: PointNet's classifier as the lesson writes it, Conv1d layers, no T-Nets.

    Conv1d(3, 64) -> Conv1d(64, 128) -> Conv1d(128, 1024), each with BatchNorm and ReLU, max
    over points, then Linear 512 -> 256 (dropout 0.3) -> classes: 0.81M parameters for 40
    classes (the lesson says 1.6M).
    """

    def __init__(self, num_classes: int):
        super().__init__()
        self.conv1, self.bn1 = nn.Conv1d(3, 64, 1), nn.BatchNorm1d(64)
        self.conv2, self.bn2 = nn.Conv1d(64, 128, 1), nn.BatchNorm1d(128)
        self.conv3, self.bn3 = nn.Conv1d(128, 1024, 1), nn.BatchNorm1d(1024)
        self.fc1, self.bn4 = nn.Linear(1024, 512), nn.BatchNorm1d(512)
        self.fc2, self.bn5 = nn.Linear(512, 256), nn.BatchNorm1d(256)
        self.dropout = nn.Dropout(0.3)
        self.fc3 = nn.Linear(256, num_classes)

    def forward(self, points, features=None, mask=None, with_regulariser=False):
        x = points.transpose(1, 2)  # (B, 3, N)
        x = F.relu(self.bn1(self.conv1(x)))
        x = F.relu(self.bn2(self.conv2(x)))
        x = F.relu(self.bn3(self.conv3(x)))
        x = torch.max(x, 2)[0]
        x = F.relu(self.bn4(self.fc1(x)))
        x = F.relu(self.bn5(self.dropout(self.fc2(x))))
        logits = self.fc3(x)
        return (logits, logits.new_zeros(())) if with_regulariser else logits


def lesson_sized_pointnet(num_classes: int) -> PointNetClassifier:
    """pointfield's PointNet with the lesson's layer sizes and no T-Nets."""
    return PointNetClassifier(
        num_classes, input_transform=False, feature_transform=False,
        local_widths=(64,), global_widths=(128, 1024), head_widths=(512, 256), dropout=0.3,
    )


# ---------------------------------------------------------------------------------------------


def parameter_counts() -> dict[str, int]:
    models = {
        "lesson PointNet classifier (Conv1d, no T-Nets), 40 classes": LessonPointNet(40),
        "pointfield PointNet, lesson sizes, no T-Nets, 40 classes": lesson_sized_pointnet(40),
        "PointNet (paper layers), no T-Nets, 40 classes": PointNetClassifier(
            40, input_transform=False, feature_transform=False),
        "PointNet, input T-Net only, 40 classes": PointNetClassifier(40, feature_transform=False),
        "PointNet, both T-Nets, 40 classes": PointNetClassifier(40),
        "PointNet segmenter, both T-Nets, 50 parts": PointNetSegmenter(50),
        "PointNet++ SSG classifier, 40 classes": PointNet2Classifier(40),
        "PointNet++ MSG classifier, 40 classes": PointNet2Classifier(40, multi_scale=True),
        "PointNet++ SSG segmenter, 50 parts": PointNet2Segmenter(50),
        "PointNet++ MSG segmenter, 50 parts": PointNet2Segmenter(50, multi_scale=True),
    }
    return {name: count_parameters(model) for name, model in models.items()}


def speed(models: dict[str, nn.Module], batch: int, rounds: int, steps: int,
          device: str | torch.device = "cpu") -> dict[str, dict]:
    """Median samples/s of training steps (Adam) and of inference, models interleaved, on ``device``.

    Interleaving rounds (harness.interleaved) spreads any slowdown of a shared machine over all
    models alike; the median of the rounds discards the worst of it. The models are moved to
    ``device``; on a GPU each timed run ends by waiting for its kernels.
    """
    device = torch.device(device)
    torch.manual_seed(0)
    points = torch.randn(batch, POINTS, 3)
    points /= points.norm(dim=-1, keepdim=True).amax(dim=1, keepdim=True)
    points = points.to(device)
    labels = torch.randint(0, CLASSES, (batch,)).to(device)
    models = {name: model.to(device) for name, model in models.items()}
    optimizers = {name: torch.optim.Adam(m.parameters(), lr=1e-3) for name, m in models.items()}

    def synchronise():
        if device.type == "cuda":
            torch.cuda.synchronize(device)

    def train_steps(name: str) -> None:
        model, optimizer = models[name], optimizers[name]
        model.train()
        for _ in range(steps):
            optimizer.zero_grad(set_to_none=True)
            logits, regulariser = model(points, with_regulariser=True)
            loss = F.cross_entropy(logits, labels) + regulariser
            loss.backward()
            optimizer.step()
        synchronise()

    def infer_steps(name: str) -> None:
        model = models[name]
        model.eval()
        with torch.inference_mode():
            for _ in range(steps):
                model(points)
        synchronise()

    results = {name: {} for name in models}
    for mode, run in (("train", train_steps), ("inference", infer_steps)):
        timings = interleaved({name: (lambda name=name, run=run: run(name)) for name in models}, rounds)
        for name, timing in timings.items():
            results[name][mode] = batch * steps / timing.median
            results[name][f"{mode}_spread"] = timing.spread
    return results


def train_same_recipe(model: nn.Module, epochs: int, shapes_per_class: int, seed: int = 0):
    """Train with `pointfield classify train`'s recipe through the same loop; test accuracy."""
    torch.manual_seed(seed)
    train_set = SyntheticShapes("train", shapes_per_class, points=(POINTS, 2 * POINTS),
                                seed=seed, transform=training_transform(POINTS))
    test_set = SyntheticShapes("test", max(1, round(shapes_per_class * 0.3)),
                               points=(POINTS, 2 * POINTS), seed=seed,
                               transform=evaluation_transform(POINTS))
    collate = CloudCollate()
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3, weight_decay=1e-4)
    scheduler = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, epochs, eta_min=1e-5)

    def batches(epoch: int):
        train_set.set_epoch(epoch)
        generator = torch.Generator().manual_seed(seed * 100_003 + epoch)
        return torch.utils.data.DataLoader(
            train_set, batch_size=32, collate_fn=collate, drop_last=True,
            sampler=torch.utils.data.RandomSampler(train_set, generator=generator),
        )

    def step(batch):
        logits, regulariser = model(batch.points, with_regulariser=True)
        return F.cross_entropy(logits, batch.labels) + regulariser, {}

    start = time.perf_counter()
    fit(model, optimizer, step, batches, epochs, scheduler=scheduler, progress=True,
        log=lambda line: print("   ", line, flush=True))
    seconds = time.perf_counter() - start
    config = {"batch_size": 32, "task": "classify", "classes": list(train_set.classes)}
    confusion, _ = confusion_on(model, test_set, "classify", config, collate, torch.device("cpu"))
    return accuracy(confusion), seconds


def recipe_accuracy(model: str, out: Path, shapes_per_class: int | None, epochs: int | None):
    import pointfield.classify

    run = out / f"synthetic-{model}"
    shutil.rmtree(run, ignore_errors=True)
    start = time.perf_counter()
    metrics = pointfield.classify.train(
        model=model, out=run, epochs=epochs, shapes_per_class=shapes_per_class, device="cpu"
    )
    return metrics, time.perf_counter() - start


# ---------------------------------------------------------------------------------------------


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="a smoke run of every part")
    parser.add_argument("--full", action="store_true",
                        help="also train both models with the default recipe (long)")
    parser.add_argument("--only", choices=("params", "speed", "compare", "accuracy"),
                        help="run one part only")
    parser.add_argument("--compare-epochs", type=int, default=4,
                        help="epochs of the same-recipe accuracy comparison (default 4)")
    parser.add_argument("--out", type=Path, default=Path("bench-output"), help="run folders of the accuracy part")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    if args.only:
        parts = {args.only}
    elif args.full or args.quick:
        parts = {"params", "speed", "compare", "accuracy"}
    else:
        parts = {"params", "speed", "compare"}
    record = Record(
        "pointnet", "PointNet family on the CPU", issue="3",
        about="pointfield's PointNet against the same network written the way the lesson writes it (Conv1d "
              "layers on (B, C, N), same layer sizes), batch 32 x 1,024 points, 10 classes, the two interleaved; "
              "both trained with the same recipe on the same synthetic shapes for the accuracy comparison. Also: "
              "parameter counts, the speed of PointNet with T-Nets and of PointNet++ SSG / MSG, and (with --full) "
              "the test accuracy of `pointfield classify train`'s default recipe.")
    results = record.figures
    if args.quick:
        record.note("A smoke run (--quick): few rounds, shapes and epochs; its verdicts do not test the claims.")
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, CPU")

    if "params" in parts:
        results["parameters"] = parameter_counts()
        record.table(["model", "parameters"], [[name, f"{count:,}"] for name, count in results["parameters"].items()],
                     title="Parameters (measured)")

    if "speed" in parts:
        rounds, steps = (3, 1) if args.quick else (7, 2)
        torch.manual_seed(0)
        lesson = {"lesson reference (Conv1d)": LessonPointNet(CLASSES),
                  "pointfield PointNet, same sizes": lesson_sized_pointnet(CLASSES)}
        lesson_speed = speed(lesson, 32, rounds, steps)
        (_, ref), (_, pf) = lesson_speed.items()
        ratios = {mode: pf[mode] / ref[mode] for mode in ("train", "inference")}
        others = {"PointNet, both T-Nets (batch 32)": PointNetClassifier(CLASSES)}
        other_speed = speed(others, 32, max(3, rounds // 2), 1)
        family = {"PointNet++ SSG (batch 16)": PointNet2Classifier(CLASSES),
                  "PointNet++ MSG (batch 16)": PointNet2Classifier(CLASSES, multi_scale=True)}
        family_speed = speed(family, 16, 3, 1)
        everything = {**lesson_speed, **other_speed, **family_speed}
        record.table(
            ["model", "train samples/s", "spread", "inference samples/s", "spread"],
            [[name, f"{value['train']:.1f}", f"{value['train_spread']:.0%}", f"{value['inference']:.1f}",
              f"{value['inference_spread']:.0%}"] for name, value in everything.items()],
            title=f"Speed: batch 32 x {POINTS} points (PointNet++: 16), {CLASSES} classes; lesson and pointfield: "
                  f"median of {rounds} interleaved rounds of {steps} steps",
        )
        for mode in ("train", "inference"):
            record.verdict(f"pointfield PointNet, {mode}: >= 1.3x the lesson reference's samples/s",
                           ratios[mode] >= 1.3, f"{ratios[mode]:.2f}x")
        results["speed"] = {**everything, "speed-up": ratios}

    if "compare" in parts:
        epochs = 1 if args.quick else args.compare_epochs
        shapes = 10 if args.quick else 100
        comparison = {}
        for name, factory in (("lesson reference (Conv1d)", LessonPointNet),
                              ("pointfield PointNet, same sizes", lesson_sized_pointnet)):
            torch.manual_seed(0)
            print(f"  training {name}", flush=True)
            score, seconds = train_same_recipe(factory(CLASSES), epochs, shapes)
            comparison[name] = {"accuracy": score, "seconds": seconds}
        record.table(["model", "test accuracy", "training s"],
                     [[name, f"{value['accuracy']:.1%}", f"{value['seconds']:.0f}"] for name, value in comparison.items()],
                     title=f"Same recipe, same data ({shapes * CLASSES} training shapes, {epochs} epochs)")
        results["same_recipe"] = comparison

    if "accuracy" in parts:
        shapes, epochs = (10, 1) if args.quick else (None, None)
        accuracy_results, rows = {}, []
        for model, claim in (("pointnet", 0.95), ("pointnet2", 0.97)):
            metrics, seconds = recipe_accuracy(model, args.out, shapes, epochs)
            accuracy_results[model] = {**metrics, "wall_seconds": seconds, "claim": claim}
            rows.append([model, f"{metrics['accuracy']:.1%}", f"{metrics['epochs']}", f"{seconds / 60:.1f}"])
        record.table(["model", "test accuracy", "epochs", "minutes"], rows,
                     title="Synthetic shapes, 10 classes, 1,024 points: `pointfield classify train` default recipe"
                           + (" (--quick: 10 shapes a class, 1 epoch)" if args.quick else ""))
        for model, result in accuracy_results.items():
            record.verdict(f"{model} reaches {result['claim']:.0%} test accuracy", result["accuracy"] >= result["claim"],
                           f"{result['accuracy']:.1%}")
        results["synthetic_accuracy"] = accuracy_results

    return record.finish()


if __name__ == "__main__":
    sys.exit(main())
