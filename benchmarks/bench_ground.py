"""Ground in aerial lidar with the provider's labels: the cloth simulation filter against learned models.

Claims checked: issue 44 asks for ``pointfield cloud ground``'s ground IoU on ``las/autzen_trim.laz``
against the file's own classification, with the CSF settings stated; issue 45 asks for a model
trained on one half of the same file (split in x) and predicted on the other, its ground IoU beside a
cloth simulation filter's on the same half, in the same run.

The file (110,000 points in feet, classes 1 "unclassified" and 2 "ground" as the provider left them) is
cut at the middle of its x range into a west and an east half, written as LAZ with their classes.
``segment train`` gets the west half in ``train/`` and, in ``test/``, the tenth of the east half nearest
the cut (the labelled-files layout): the scores printed after each epoch are on that strip, so that
they stay cheap; the figures below are those of the whole east half. Then, in one run:

- CSF (:func:`pointfield.segmentation.ground_mask`) with ``cloud ground``'s defaults (cloth resolution
  twice the mean x-y spacing, threshold half of it, rigidness 2, slope smoothing), on the whole file
  and on the east half alone;
- each model trained by ``pointfield segment train`` on the west half for ``--epochs`` epochs of
  ``--crops`` crops (a fixed amount of work, so that a busy machine changes the time, not the
  model), on a ``--grid`` of 1 ft with crops of ``--radius`` ft, then ``segment predict`` of the east
  half: every point of it labelled.

Ground IoU is ``|predicted ground & class 2| / |predicted ground | class 2|`` over every point of the
half (or file); accuracy is the share of points whose ground / not-ground answer matches the file's.
The file's labels are not a full ground truth (docs/registration.md: about half of its class-1 points
lie on the bare ground), which is what a learned model can pick up and CSF cannot.

Run: ``make bench-ground`` (= ``python benchmarks/bench_ground.py``); the record goes to
``benchmarks/records/ground.json``.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import pointfield
from pointfield.clouds.scene_tasks import train_scenes
from pointfield.segmentation import default_cloth_resolution, ground_mask, iou

from harness import Record

AUTZEN = Path(__file__).resolve().parents[2] / "shared" / "data" / "las" / "autzen_trim.laz"
GROUND = 2
MODELS = {"pointnet2": "PointNet++ SSG", "ptv3": "Point Transformer V3"}


def scores(predicted_ground: np.ndarray, classification: np.ndarray) -> tuple[float, float]:
    """Ground IoU and ground / not-ground accuracy of a boolean mask against LAS classes."""
    truth = classification == GROUND
    return iou(predicted_ground, truth), float((predicted_ground == truth).mean())


def cloth(points: np.ndarray) -> tuple[np.ndarray, dict[str, float], float]:
    """CSF with ``cloud ground``'s defaults: the mask, the settings, the seconds it took."""
    resolution = default_cloth_resolution(points)
    settings = {"resolution": resolution, "threshold": resolution / 2, "rigidness": 2, "slope_smooth": True}
    started = time.perf_counter()
    mask = ground_mask(points, cloth_resolution=resolution, class_threshold=resolution / 2, rigidness=2,
                       slope_smooth=True)
    return mask, settings, time.perf_counter() - started


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", choices=tuple(MODELS), default=list(MODELS))
    parser.add_argument("--epochs", type=int, default=6, help="training epochs per model (default 6)")
    parser.add_argument("--grid", type=float, default=1.0, help="grid of the scan, in the file's units (feet)")
    parser.add_argument("--radius", type=float, default=40.0, help="crop radius, in the file's units (feet)")
    parser.add_argument("--points", type=int, default=2048, help="points per crop")
    parser.add_argument("--crops", type=int, default=256, help="crops per epoch (default 256)")
    args = parser.parse_args()
    if not AUTZEN.exists():
        print(f"skipped: {AUTZEN} is absent", file=sys.stderr)
        return 0
    record = Record("ground", "Ground in aerial lidar: CSF against models trained on the provider's labels",
                    issue="44, 45", about=(
                        f"`las/autzen_trim.laz` cut at the middle of its x range; CSF with `cloud ground`'s defaults "
                        f"on the whole file and on the east half; {', '.join(MODELS[m] for m in args.models)} "
                        f"trained by `segment train` on the west half for {args.epochs} epochs of {args.crops} crops "
                        f"each (grid {args.grid:g} ft, crops of {args.radius:g} ft, {args.points} points), then "
                        "`segment predict` of the east half. Ground IoU and "
                        "ground / not-ground accuracy over every point, against the file's class 2."))
    cloud = pointfield.read(AUTZEN)
    classification = np.asarray(cloud.fields["classification"])
    x = cloud.points[:, 0]
    middle = (float(x.min()) + float(x.max())) / 2
    east = x >= middle
    work = Path(tempfile.mkdtemp(prefix="bench-ground-"))
    rows = []
    try:
        strip = east & (x < middle + (float(x.max()) - middle) / 10)
        for path, keep in ((work / "data" / "train" / "west.laz", ~east), (work / "data" / "test" / "strip.laz", strip),
                           (work / "east.laz", east)):
            path.parent.mkdir(parents=True, exist_ok=True)
            pointfield.write(path, cloud.select(np.flatnonzero(keep)))
        truth_east = classification[east]
        for part, points, truth in (("whole file", cloud.points, classification),
                                    ("east half", cloud.points[east], truth_east)):
            mask, settings, seconds = cloth(points)
            ground_iou, accuracy = scores(mask, truth)
            rows.append([part, "CSF (`cloud ground` defaults)",
                         (f"resolution {settings['resolution']:.2f} ft, threshold {settings['threshold']:.2f} ft, "
                          "rigidness 2, slope smoothing"), f"{ground_iou:.3f}", f"{accuracy:.3f}", f"{seconds:.1f}"])
            record.figures[f"csf {part}"] = {"ground_iou": ground_iou, "accuracy": accuracy, "seconds": seconds,
                                             **settings, "points": int(len(points))}
        csf_east = record.figures["csf east half"]["ground_iou"]
        for model in args.models:
            out = work / f"run-{model}"
            metrics = train_scenes([work / "data"], out=out, model=model, grid=args.grid, radius=args.radius,
                                   points=args.points, crops=args.crops, epochs=args.epochs,
                                   label_field="classification", progress=False, device="cpu")
            started = time.perf_counter()
            pointfield.load_run(out, device="cpu").predict([work / "east.laz"], out=work / f"east-{model}.laz")
            predict_seconds = time.perf_counter() - started
            predicted = np.asarray(pointfield.read(work / f"east-{model}.laz").fields["classification"])
            ground_iou, accuracy = scores(predicted == GROUND, truth_east)
            rows.append(["east half", f"{MODELS[model]}, trained on the west half",
                         f"{metrics['epochs']} epochs in {metrics['training_seconds']:.0f} s",
                         f"{ground_iou:.3f}", f"{accuracy:.3f}", f"{predict_seconds:.1f} (prediction)"])
            record.figures[model] = {"ground_iou": ground_iou, "accuracy": accuracy,
                                     "training_seconds": metrics["training_seconds"],
                                     "prediction_seconds": predict_seconds, "epochs": metrics.get("epochs"),
                                     "strip_grid_miou": metrics.get("miou")}
            record.verdict(f"{MODELS[model]}'s ground IoU on the east half beats CSF's on the same half",
                           ground_iou > csf_east, f"{ground_iou:.3f} against {csf_east:.3f}")
        record.table(["points", "method", "settings", "ground IoU", "accuracy", "seconds"], rows)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return record.finish()


if __name__ == "__main__":
    sys.exit(main())
