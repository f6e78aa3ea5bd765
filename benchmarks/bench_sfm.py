"""Camera poses from photos (``pointfield scene from-images``) against known poses and against COLMAP's CLI.

The claims (issue 13), each on real images from ../shared/data with their given poses withheld
from the solver:

- the instant-ngp fox (50 photos, 1080x1920) and the NeRF-synthetic lego training views (100
  renders, 800x800): every image registered, median rotation error at most 0.25 degrees, median
  centre error at most 0.5 % (fox) and 1 % (lego) of the extent of the given centres, the scene
  written end to end in at most 60 s (fox) and 120 s (lego);
- the LLFF milk photos and COLMAP's tiny phone scene reported the same way;
- side by side, in the same run: the command-line COLMAP pipeline that nerfstudio's
  ``ns-process-data images`` runs (Debian's ``colmap``), on the same images at the same feature
  size (``benchmarks/colmap_cli.py``);
- the incremental and the global mapper, to choose the default;
- with ``--training``: the hash-grid field and splats trained on the SfM-posed fox reach a
  held-out PSNR within 1 dB of the same training on the given poses (same budget, same held-out
  views), and splats started from the SfM points against today's random start.

Errors are measured after one similarity alignment (:mod:`pointfield.scenes.alignment`): rotation
by the chordal mean of ``R_given R_found^T``, scale and translation by least squares on the
centres. Poses are read back from the written scene (transforms.json), so the figure covers the
whole path a user's scene takes. Time is wall-clock of the whole call, stage times beside it.

Run: ``make bench-sfm`` (= ``python benchmarks/bench_sfm.py``), e.g. ``--scenes fox`` or
``--no-peer``; the record goes to ``benchmarks/records/sfm.json``.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from harness import Record

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


@dataclass(frozen=True)
class Dataset:
    """Images to pose and where their given poses come from."""

    name: str
    images: Path
    given: Path
    given_format: str | None
    goal_seconds: float | None = None
    goal_centre_percent: float | None = None


DATASETS = {
    "fox": Dataset("fox", DATA / "nerf/fox_instant_ngp/images", DATA / "nerf/fox_instant_ngp", None, 60, 0.5),
    "lego": Dataset("lego", DATA / "nerf/lego_blender/train", DATA / "nerf/lego_blender", None, 120, 1.0),
    "milk": Dataset("milk", DATA / "llff/milk/images", DATA / "llff/milk", "llff"),
    "phone": Dataset("phone", DATA / "colmap/tiny_phone_scene/fotos", DATA / "colmap/tiny_phone_scene", "colmap"),
}
GOAL_ROTATION_DEGREES = 0.25


def given_poses(dataset: Dataset) -> dict[str, np.ndarray]:
    """Image file name -> given camera-to-world ``(3, 4)`` (OpenCV convention)."""
    from pointfield.scenes import read_scene

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the fox lists 17 frames without images
        scene = read_scene(dataset.given, format=dataset.given_format)
    poses = scene.cameras.camera_to_world.double().numpy()
    return {Path(frame.image_path).name: poses[i] for i, frame in enumerate(scene.frames) if frame.image_path}


def accuracy(found: dict[str, np.ndarray], given: dict[str, np.ndarray]) -> dict[str, float] | None:
    from pointfield.scenes.alignment import pose_errors

    common = sorted(set(found) & set(given))
    if len(common) < 2:
        return None
    errors = pose_errors(np.stack([found[n] for n in common]), np.stack([given[n] for n in common]))
    return {"compared": len(common), **errors.summary()}


def found_poses(scene_folder: Path) -> dict[str, np.ndarray]:
    from pointfield.scenes import read_scene

    scene = read_scene(scene_folder)
    poses = scene.cameras.camera_to_world.double().numpy()
    return {Path(frame.image_path).name: poses[i] for i, frame in enumerate(scene.frames)}


def run_pointfield(dataset: Dataset, mapper: str, out: Path) -> dict:
    from pointfield.scenes.sfm import PosingOptions, pose_images

    shutil.rmtree(out, ignore_errors=True)
    started = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        report = pose_images(dataset.images, out, options=PosingOptions(mapper=mapper), progress=False)
    seconds = time.perf_counter() - started
    stages = report.stage_seconds
    return {
        "pipeline": f"pointfield ({mapper}{': ' + report.mapper if mapper == 'auto' else ''})",
        "seconds": seconds,
        "features": stages["features"],
        "matching": stages["matching"],
        "mapping": stages["mapping"],
        "rest": seconds - stages["features"] - stages["matching"] - stages["mapping"],
        "registered": report.registered,
        "images": report.images,
        "pairs": report.pairs,
        "poses": found_poses(out),
    }


def run_peer(dataset: Dataset, work: Path) -> dict:
    from colmap_cli import run_colmap_cli

    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    started = time.perf_counter()
    result = run_colmap_cli(dataset.images, work, max_image_size=800)
    seconds = time.perf_counter() - started
    stages = result.stage_seconds
    return {
        "pipeline": f"{result.version.split(' -- ')[0]} CLI (ns-process-data)",
        "seconds": seconds,
        "features": stages.get("features", 0.0),
        "matching": stages.get("matching", 0.0),
        "mapping": stages.get("mapping", 0.0),
        "rest": seconds - sum(stages.get(k, 0.0) for k in ("features", "matching", "mapping")),
        "registered": len(result.camera_to_world),
        "images": result.images,
        "pairs": len(result.camera_to_world) and result.images * (result.images - 1) // 2,
        "poses": result.camera_to_world,
    }


def pose_table(record: Record, args, datasets: list[Dataset]) -> dict[str, dict[str, dict]]:
    rows, results = [], {}
    for dataset in datasets:
        given = given_poses(dataset)
        results[dataset.name] = {}
        contenders = [(m, lambda d=dataset, m=m: run_pointfield(d, m, args.out / f"{d.name}-{m}")) for m in args.mappers]
        if args.peer and dataset.name in args.peer_scenes:
            contenders.append(("colmap-cli", lambda d=dataset: run_peer(d, args.out / f"{d.name}-colmap-cli")))
        for key, contender in contenders:
            print(f"{dataset.name}: {key} ...", flush=True)
            try:
                result = contender()
            except Exception as error:  # noqa: BLE001 -- a pipeline failing on a scene is a result, not a crash
                record.note(f"{dataset.name}: {key} failed: {error}")
                continue
            result["accuracy"] = accuracy(result.pop("poses"), given)
            results[dataset.name][key] = result
            error = result["accuracy"] or {}
            rows.append([
                dataset.name, result["pipeline"], f"{result['seconds']:.1f}", f"{result['features']:.1f}",
                f"{result['matching']:.1f}", f"{result['mapping']:.1f}", f"{result['rest']:.1f}",
                f"{result['registered']}/{result['images']}", result["pairs"],
                f"{error.get('median_rotation_degrees', float('nan')):.3f}",
                f"{error.get('median_centre_percent', float('nan')):.3f}",
                f"{error.get('max_rotation_degrees', float('nan')):.3f}",
            ])
    record.table(
        ["scene", "pipeline", "seconds", "features", "matching", "mapping", "rest", "registered", "pairs",
         "median rotation (deg)", "median centre (% extent)", "max rotation (deg)"],
        rows,
        title="Poses against the given ones, after one similarity alignment (same images, same run)",
    )
    record.figures["poses"] = results
    return results


def pose_verdicts(record: Record, results: dict[str, dict[str, dict]], datasets: list[Dataset], mapper: str) -> None:
    for dataset in datasets:
        if dataset.goal_seconds is None or mapper not in results[dataset.name]:
            continue
        result = results[dataset.name][mapper]
        error = result["accuracy"] or {}
        all_registered = result["registered"] == result["images"]
        record.verdict(f"{dataset.name}: every image registered ({mapper})", all_registered,
                       f"{result['registered']}/{result['images']}")
        rotation = error.get("median_rotation_degrees", float("inf"))
        record.verdict(f"{dataset.name}: median rotation error <= {GOAL_ROTATION_DEGREES} deg",
                       rotation <= GOAL_ROTATION_DEGREES, f"{rotation:.3f} deg")
        centre = error.get("median_centre_percent", float("inf"))
        record.verdict(f"{dataset.name}: median centre error <= {dataset.goal_centre_percent} % of the extent",
                       centre <= dataset.goal_centre_percent, f"{centre:.3f} %")
        record.verdict(f"{dataset.name}: scene written in <= {dataset.goal_seconds:.0f} s",
                       result["seconds"] <= dataset.goal_seconds, f"{result['seconds']:.1f} s")
        peer = results[dataset.name].get("colmap-cli")
        if peer:
            record.note(f"{dataset.name}: pointfield ({mapper}) took {peer['seconds'] / result['seconds']:.1f}x less time "
                        f"than the COLMAP CLI pipeline ({result['seconds']:.1f} s against {peer['seconds']:.1f} s).")


def undistorted_given(dataset: Dataset, out: Path, sfm_scene: Path) -> Path:
    """The dataset with its given poses, as like the SfM scene as it can be but for the poses.

    The given cameras are written as a COLMAP text model (one OPENCV camera) and undistorted by
    ``pycolmap.undistort_images``, as SfM scenes are. The given poses come with no sparse points,
    and training needs near/far bounds (ngp) and starts splats from points: the SfM scene's
    points are carried into the given world by the similarity that aligns the SfM cameras onto
    the given ones, and near/far computed from them as the COLMAP reader does. The result is
    written as a nerfstudio scene in ``out``.
    """
    import pycolmap
    from scipy.spatial.transform import Rotation

    from pointfield.clouds.cloud import PointCloud
    from pointfield.scenes import read_scene
    from pointfield.scenes.alignment import pose_errors
    from pointfield.scenes.formats.colmap.scene import _near_far_from_points
    from pointfield.scenes.formats.transforms_json import write_nerfstudio

    if (out / "transforms.json").is_file():
        return out
    undistorted = out.with_name(out.name + "-colmap")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scene = read_scene(dataset.given, format=dataset.given_format)
    cameras = scene.cameras.to(dtype=__import__("torch").float64)
    model = out.with_name(out.name + "-model")
    shutil.rmtree(model, ignore_errors=True)
    model.mkdir(parents=True)
    distortion = [float(value) for value in cameras.distortion[0]]
    if cameras.model != "OPENCV" or any(distortion[4:]):
        raise ValueError(f"undistorted_given handles OPENCV cameras with k1 k2 p1 p2 only, not {cameras.model}")
    # pointfield's OPENCV has k1 k2 p1 p2 k3; COLMAP's takes the first four.
    params = [float(cameras.fx[0]), float(cameras.fy[0]), float(cameras.cx[0]), float(cameras.cy[0]), *distortion[:4]]
    (model / "cameras.txt").write_text(
        f"1 {cameras.model} {int(cameras.width[0])} {int(cameras.height[0])} {' '.join(f'{v:.17g}' for v in params)}\n")
    lines = []
    for index, frame in enumerate(scene.frames):
        camera_to_world = cameras.camera_to_world[index].numpy()
        rotation = camera_to_world[:, :3].T
        translation = -rotation @ camera_to_world[:, 3]
        x, y, z, w = Rotation.from_matrix(rotation).as_quat()
        pose = " ".join(f"{float(v):.17g}" for v in (w, x, y, z, *translation))
        lines.append(f"{index + 1} {pose} 1 {Path(frame.image_path).name}\n\n")
    (model / "images.txt").write_text("".join(lines))
    (model / "points3D.txt").write_text("")
    shutil.rmtree(undistorted, ignore_errors=True)
    pycolmap.undistort_images(undistorted, model, Path(scene.frames[0].image_path).parent)
    given = read_scene(undistorted, format="colmap")
    found = read_scene(sfm_scene)
    found_by_name = {Path(f.image_path).name: i for i, f in enumerate(found.frames)}
    order = [found_by_name[Path(f.image_path).name] for f in given.frames]
    alignment = pose_errors(found.cameras.camera_to_world[order].double().numpy(),
                            given.cameras.camera_to_world.double().numpy())
    points = alignment.scale * found.points.points.astype(np.float64) @ alignment.rotation.T + alignment.translation
    given.points = PointCloud(points, {"colors": found.points.fields["colors"]})
    given.near_far = _near_far_from_points(given.cameras, points)
    write_nerfstudio(given, out, points_file="points3D.ply")
    return out


def heldout_names(scene_path: Path) -> list[str]:
    from pointfield.scenes.heldout import open_scene, training_and_heldout

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scene = open_scene(scene_path, holdout_every=8)
    _, heldout = training_and_heldout(scene)
    return [Path(scene.frames[int(i)].image_path).name for i in heldout]


def training_table(record: Record, args) -> None:
    """ngp and splats on the fox with given and with SfM poses; splats from SfM points vs at random."""
    from pointfield.fields.train import train as train_field
    from pointfield.splats.train import train as train_splats

    sfm_scene = args.out / f"fox-{args.mappers[0]}"
    if not (sfm_scene / "transforms.json").is_file():
        run_pointfield(DATASETS["fox"], args.mappers[0], sfm_scene)
    scenes = {"given poses": undistorted_given(DATASETS["fox"], args.out / "fox-given", sfm_scene), "SfM poses": sfm_scene}
    heldout = {label: heldout_names(scene) for label, scene in scenes.items()}
    same_views = heldout["given poses"] == heldout["SfM poses"]
    record.verdict("both trainings hold out the same views", same_views, ", ".join(heldout["given poses"]))
    common = {"downscale": args.downscale, "holdout_every": 8, "max_training_time": args.training_seconds, "progress": False}

    def field_run(scene: Path, out: str):
        return lambda: train_field(scene, model="ngp", out=args.out / out, eval_views=10, steps=10**6, **common)

    def splat_run(scene: Path, out: str, init: str = "auto"):
        return lambda: train_splats(scene, out=args.out / out, eval_views=10, steps=10**6, init=init, **common)

    runs = []
    for number, (label, scene) in enumerate(scenes.items()):
        runs.append(("ngp", label, "-", field_run(scene, f"ngp-{number}")))
        runs.append(("splat", label, "auto", splat_run(scene, f"splat-{number}")))
    runs.append(("splat", "SfM poses", "random", splat_run(sfm_scene, "splat-random", init="random")))
    rows, psnr = [], {}
    for model, label, init, run in runs:
        print(f"training {model} on the fox, {label}, init {init} ...", flush=True)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            metrics = run()
        psnr[(model, label, init)] = metrics["psnr"]
        rows.append([model, label, init, f"{metrics['psnr']:.2f}", f"{metrics['ssim']:.3f}", metrics["steps"],
                     f"{metrics['seconds']:.0f}"])
    record.table(["model", "poses", "splat init", "held-out PSNR", "SSIM", "steps", "seconds"], rows,
                 title=f"Fox at 1/{args.downscale} size, every 8th view held out, {args.training_seconds:.0f} s of "
                       "training each")
    for model, init in (("ngp", "-"), ("splat", "auto")):
        gap = psnr[(model, "given poses", init)] - psnr[(model, "SfM poses", init)]
        record.verdict(f"{model} on SfM poses within 1 dB of given poses", gap <= 1.0, f"{gap:+.2f} dB (given - SfM)")
    record.note(f"splats from the SfM points: {psnr[('splat', 'SfM poses', 'auto')]:.2f} dB; from a random start: "
                f"{psnr[('splat', 'SfM poses', 'random')]:.2f} dB (same budget).")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default="fox,lego,milk,phone", help="comma-separated: fox, lego, milk, phone")
    parser.add_argument("--mappers", default="auto,global", help="pointfield mappers to run (first = default)")
    parser.add_argument("--no-peer", dest="peer", action="store_false", help="skip the COLMAP CLI pipeline")
    parser.add_argument("--peer-scenes", help="scenes to run the COLMAP CLI on (default: all; lego takes ~20 min)")
    parser.add_argument("--training", action="store_true",
                        help="only train ngp and splats on the fox with given and SfM poses (record sfm-training)")
    parser.add_argument("--training-seconds", type=float, default=120.0, help="training budget per run (default 120)")
    parser.add_argument("--downscale", type=int, default=8, help="fox image downscale for training (default 8)")
    parser.add_argument("--out", type=Path, default=Path("bench-output/sfm"), help="where scenes and runs go")
    args = parser.parse_args()
    args.mappers = args.mappers.split(",")
    args.peer_scenes = (args.peer_scenes or args.scenes).split(",")
    missing = [d for d in DATASETS.values() if not d.images.is_dir()]
    if missing:
        print(f"shared data missing ({missing[0].images}); nothing to measure", file=sys.stderr)
        return 1
    if args.training:
        return training_record(args)
    if args.peer:
        from colmap_cli import colmap_available

        if colmap_available() is None:
            print("colmap is not installed (make bench-sfm installs Debian's package); use --no-peer", file=sys.stderr)
            return 1
    args.out.mkdir(parents=True, exist_ok=True)
    import pycolmap

    record = Record("sfm", "Camera poses from photos: pycolmap inside pointfield against known poses and COLMAP's CLI",
                    issue="13",
                    about="Poses of real photos found with their given poses withheld, then compared after one "
                          "similarity alignment; each pipeline runs on the same images in the same run, features on "
                          f"images resized to 800 px. pycolmap {pycolmap.__version__} (CPU build).")
    datasets = [DATASETS[name] for name in args.scenes.split(",")]
    results = pose_table(record, args, datasets)
    pose_verdicts(record, results, datasets, args.mappers[0])
    if len(args.mappers) > 1:
        for dataset in datasets:
            by_mapper = {m: results[dataset.name].get(m) for m in args.mappers}
            record.note(f"{dataset.name}: by mapper: " + ", ".join(
                f"{m} {r['registered']}/{r['images']} registered, {r['seconds']:.1f} s, median "
                f"{r['accuracy']['median_rotation_degrees']:.3f} deg / {r['accuracy']['median_centre_percent']:.3f} %"
                if r and r["accuracy"] else f"{m} failed" for m, r in by_mapper.items()))
    return record.finish()


def training_record(args) -> int:
    record = Record("sfm-training", "Training on SfM poses against the given ones, and splats from SfM points",
                    issue="13",
                    about="The fox, posed by `scene from-images` (default options) and with its given poses; both "
                          "undistorted by the same COLMAP undistorter, so that both trainings see the same kind of "
                          "images; every 8th view held out (the same views on both sides); the same time budget.")
    args.out.mkdir(parents=True, exist_ok=True)
    training_table(record, args)
    return record.finish()


if __name__ == "__main__":
    sys.exit(main())
