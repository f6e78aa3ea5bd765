"""Photos or a video in, a posed scene out: structure from motion through pycolmap, stage by stage.

The stages, each timed, each with its own progress bar::

    images        gather and check the photos (or pick the sharpest video frames)   photos.py, video.py
    features      SIFT on images resized to ``max_size`` (keypoints in original pixels)
    matching      choose pairs (pairs.py), SIFT matching, two-view geometric verification
    mapping       incremental (COLMAP) or global (GLOMAP) mapping; the largest model is kept
    undistortion  images and cameras undistorted to PINHOLE
    scene         transforms.json, colmap/sparse/0, points3D.ply, images_2/4/8, report

All work happens in ``<out>.partial/`` beside the output folder, which appears only when every
stage has finished (one rename), so a failed or killed run never leaves a half-written scene.
A killed run restarts from the last finished stage: ``state.json`` there records each finished
stage with the options it depended on, and a stage re-runs (with every stage after it) when its
inputs or options changed -- so after "only 5 of 40 images registered", a second try with
``matching="exhaustive"`` reuses the features.

Choices (measured in benchmarks/bench_sfm.py; see the README's "Photos and video in"):

- SIFT starts at the image's own resolution (``first_octave = 0``) rather than COLMAP's doubled
  one when features are computed at :data:`DOUBLING_BELOW` pixels or more: on images resized to
  800 px it is 2-3x faster with no loss of registration or accuracy on the fox and lego. Smaller
  images (video frames, thumbnails) keep the doubled octave: they need its features, and it is
  cheap for them.
- One camera per image size (CameraMode.SINGLE within each size group): photos from one phone
  share their intrinsics, and estimating one focal length from every photo is what pins it down.
- Pairs: exhaustive up to ``EXHAUSTIVE_UP_TO`` photos, above that retrieval (pairs.py); video:
  each frame with the next ``overlap`` ones plus retrieval neighbours, which finds the loops
  where a walk-around returns to its start.
- Mapper "auto": incremental; where it leaves images out, global too, keeping the model with
  more images (incremental on a tie). On the fox and lego both register everything; incremental was as accurate in every
  run, global in most but not all (its random start once left lego cameras 24 degrees off). On
  the LLFF milk photos and COLMAP's tiny phone scene incremental registered too few images to go
  on, where global registered all but one.
- Registration below half the images is an error (the scene would not be the one photographed);
  between half and all, a warning lists the images left out.
"""

from __future__ import annotations

import json
import os
import shutil
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pointfield.atomic import atomic_path
from pointfield.scenes.sfm import pairs as pairing
from pointfield.scenes.sfm.errors import PosingError
from pointfield.scenes.sfm.photos import Photo, gather_photos, natural_key

STAGES = ("images", "features", "matching", "mapping", "undistortion", "scene")
MATCHING = ("auto", "exhaustive", "retrieval", "sequential")
MAPPERS = ("auto", "incremental", "global")
CAMERA_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")
EXHAUSTIVE_UP_TO = 30
"""Photo sets up to this size are matched all against all (435 pairs at 30: seconds)."""
FEATURES_FOR_RETRIEVAL = 256
DOUBLING_BELOW = 640
"""Images whose features are computed at a longer side under this many pixels get SIFT's doubled first octave."""
FEATURE_BATCH = 8
MATCH_BLOCK = 64


@dataclass(frozen=True)
class PosingOptions:
    """How to pose: feature size, pairing, mapper, camera model. Defaults suit phone photos.

    - ``max_size``: the longer image side, in pixels, that features are computed at (poses and
      intrinsics always apply to the original images).
    - ``features``: at most this many SIFT features per image.
    - ``matching``: one of :data:`MATCHING`; "auto" picks exhaustive for up to
      :data:`EXHAUSTIVE_UP_TO` photos, retrieval above, sequential plus retrieval for video.
    - ``neighbours``: retrieval partners per image; ``overlap``: following frames per frame.
    - ``mapper``: "auto" (incremental; where it leaves images out, global too, and the model with
      more images is kept), "incremental" (COLMAP's classic) or "global" (GLOMAP, in COLMAP 4).
    - ``camera_model``: COLMAP's model for the unknown cameras, one of :data:`CAMERA_MODELS`.
    - ``downscales``: the factors of the images_N folders written beside images/.
    - ``threads``: CPU threads for pycolmap (-1: all).
    """

    max_size: int = 800
    features: int = 8192
    matching: str = "auto"
    neighbours: int = 10
    overlap: int = 10
    mapper: str = "auto"
    camera_model: str = "SIMPLE_RADIAL"
    downscales: tuple[int, ...] = (2, 4, 8)
    threads: int = -1

    def __post_init__(self) -> None:
        if self.matching not in MATCHING:
            raise PosingError(f"matching must be one of {', '.join(MATCHING)}, got {self.matching!r}")
        if self.mapper not in MAPPERS:
            raise PosingError(f"mapper must be one of {', '.join(MAPPERS)}, got {self.mapper!r}")
        if self.camera_model not in CAMERA_MODELS:
            raise PosingError(
                f"camera model must be one of {', '.join(CAMERA_MODELS)}, got {self.camera_model!r}"
            )
        for name in ("max_size", "features", "neighbours", "overlap"):
            if getattr(self, name) < 1:
                raise PosingError(f"{name.replace('_', '-')} must be at least 1, got {getattr(self, name)}")
        if any(int(f) < 2 for f in self.downscales):
            raise PosingError(f"downscale factors must be 2 or more, got {list(self.downscales)}")


# Which options each stage's result depends on: changing one re-runs that stage and those after it.
STAGE_OPTIONS = {
    "images": ("frames",),
    "features": ("max_size", "features", "camera_model"),
    "matching": ("matching", "neighbours", "overlap"),
    "mapping": ("mapper",),
    "undistortion": (),
    "scene": ("downscales",),
}


@dataclass
class PosingReport:
    """What structure from motion found; written to ``report.json`` in the scene and printed.

    ``reprojection_error`` is the mean over all observations, in pixels of the original images;
    ``track_length`` the mean number of images that see a sparse point.
    """

    out: str
    images: int
    registered: int
    unregistered: list[str]
    reprojection_error: float
    track_length: float
    points: int
    pairs: int
    matching: str
    mapper: str
    models: int
    cameras: list[dict[str, Any]]
    stage_seconds: dict[str, float]
    device: str
    exif_rotated: list[str] = field(default_factory=list)

    @property
    def seconds(self) -> float:
        return float(sum(self.stage_seconds.values()))

    def format(self) -> str:
        """The report as the lines the command prints."""
        lines = [
            f"posed {self.registered} of {self.images} images -> {self.out}",
            (
                f"  mean reprojection error {self.reprojection_error:.3f} px, mean track length "
                f"{self.track_length:.2f}, {self.points} sparse points"
            ),
            f"  {self.pairs} pairs matched ({self.matching}), {self.mapper} mapping, features on {self.device}",
        ]
        for camera in self.cameras:
            params = ", ".join(f"{v:.6g}" for v in camera["params"])
            lines.append(f"  camera {camera['model']} {camera['width']}x{camera['height']}: {params}")
        if self.unregistered:
            shown = ", ".join(self.unregistered[:10]) + (" ..." if len(self.unregistered) > 10 else "")
            lines.append(f"  not registered ({len(self.unregistered)}): {shown}")
        if self.exif_rotated:
            lines.append(
                f"  {len(self.exif_rotated)} photos carry an EXIF rotation, which is ignored "
                "(poses are for the pixels as stored)"
            )
        lines.append(
            "  seconds: "
            + ", ".join(f"{name} {seconds:.1f}" for name, seconds in self.stage_seconds.items())
            + f" (total {self.seconds:.1f})"
        )
        return "\n".join(lines)


def pose_images(
    photos: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    out: str | os.PathLike[str],
    *,
    options: PosingOptions | None = None,
    overwrite: bool = False,
    progress: bool = True,
) -> PosingReport:
    """Pose a folder (or list) of photos and write the scene to ``out`` (module docstring).

    Raises :class:`PosingError` for bad input (fewer than 3 images, unreadable files) and for
    photos that share too little to be posed together.
    """
    source = [Path(p) for p in photos] if isinstance(photos, (list, tuple)) else Path(photos)
    fingerprint = _fingerprint(source if isinstance(source, list) else _folder_files(source))

    def gather(images: Path) -> list[Photo]:
        found = gather_photos(source)
        return _link_photos(found, images)

    return _run(gather, fingerprint, "images", out, options or PosingOptions(), overwrite, progress, None)


def pose_video(
    clip: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    frames: int = 150,
    options: PosingOptions | None = None,
    overwrite: bool = False,
    progress: bool = True,
) -> PosingReport:
    """Pose ``frames`` frames of a video (the sharpest of each stretch) and write the scene to ``out``."""
    from pointfield.scenes.sfm.video import extract_frames

    clip = Path(clip)
    if not clip.is_file():
        raise PosingError(f"{clip}: no such video file")

    def gather(images: Path) -> list[Photo]:
        paths = extract_frames(clip, images, frames, progress=progress)
        return gather_photos(paths)

    return _run(gather, _fingerprint([clip]), "video", out, options or PosingOptions(), overwrite, progress, frames)


# -- the stages -----------------------------------------------------------------------------------


class _Work:
    """The ``<out>.partial`` folder: its paths and ``state.json`` of finished stages."""

    def __init__(self, out: Path, fingerprint: list, settings: dict[str, Any]):
        self.root = out.with_name(out.name + ".partial")
        self.images = self.root / "images"
        self.database = self.root / "database.db"
        self.sparse = self.root / "sparse"
        self.undistorted = self.root / "undistorted"
        self.scene = self.root / "scene"
        self.settings = settings
        self.state_path = self.root / "state.json"
        state = self._read_state()
        if state.get("fingerprint") != fingerprint:
            # Other photos (or a first run): nothing in an old partial folder can be reused.
            shutil.rmtree(self.root, ignore_errors=True)
            state = {}
        self.root.mkdir(parents=True, exist_ok=True)
        self.state = {"fingerprint": fingerprint, "stages": state.get("stages", {}), "data": state.get("data", {})}
        self._forget_changed_stages()

    def _read_state(self) -> dict[str, Any]:
        try:
            return json.loads(self.state_path.read_text())
        except (OSError, ValueError):
            return {}

    def _forget_changed_stages(self) -> None:
        for index, stage in enumerate(STAGES):
            done = self.state["stages"].get(stage)
            if done is None or done["options"] != self._stage_options(stage):
                for later in STAGES[index:]:
                    self.state["stages"].pop(later, None)
                return

    def _stage_options(self, stage: str) -> dict[str, Any]:
        return {name: self.settings[name] for name in STAGE_OPTIONS[stage]}

    def done(self, stage: str) -> bool:
        return stage in self.state["stages"]

    def seconds(self) -> dict[str, float]:
        return {stage: self.state["stages"][stage]["seconds"] for stage in STAGES if self.done(stage)}

    def finish(self, stage: str, seconds: float, **data: Any) -> None:
        self.state["stages"][stage] = {"seconds": seconds, "options": self._stage_options(stage)}
        self.state["data"].update(data)
        with atomic_path(self.state_path) as tmp:
            tmp.write_text(json.dumps(self.state, indent=1))


def _run(
    gather: Callable[[Path], list[Photo]],
    fingerprint: list,
    kind: str,
    out: str | os.PathLike[str],
    options: PosingOptions,
    overwrite: bool,
    progress: bool,
    frames: int | None,
) -> PosingReport:
    import pycolmap

    out = Path(out)
    if out.exists() and not overwrite:
        raise PosingError(f"{out} already exists; choose another --out or pass --overwrite")
    if not out.parent.is_dir():
        raise PosingError(f"{out.parent}: no such folder to write the scene into")
    settings = {**asdict(options), "downscales": list(options.downscales), "frames": frames, "kind": kind}
    work = _Work(out, fingerprint, settings)
    _log_to(work.root / "logs")
    device = pycolmap.Device.cuda if pycolmap.has_cuda else pycolmap.Device.cpu
    stages: dict[str, Callable[[], dict[str, Any]]] = {
        "images": lambda: _images_stage(work, gather),
        "features": lambda: _features_stage(work, options, device, progress),
        "matching": lambda: _matching_stage(work, options, kind, device, progress),
        "mapping": lambda: _mapping_stage(work, options, progress),
        "undistortion": lambda: _undistortion_stage(work, options),
        "scene": lambda: _scene_stage(work, options, progress),
    }
    for stage in STAGES:
        if work.done(stage):
            continue
        start = time.perf_counter()
        data = stages[stage]()
        work.finish(stage, time.perf_counter() - start, **data)
    report = _report(work, out, options, "cuda" if device == pycolmap.Device.cuda else "cpu")
    _write_report(work.scene, report)
    _joined_logs(work.root / "logs", work.scene / "colmap" / "colmap.log")
    _move_into_place(work, out, overwrite)
    return report


def _images_stage(work: _Work, gather: Callable[[Path], list[Photo]]) -> dict[str, Any]:
    shutil.rmtree(work.images, ignore_errors=True)
    work.images.mkdir(parents=True)
    photos = gather(work.images)
    return {
        "photos": [[p.path.name, p.width, p.height] for p in photos],
        "exif_rotated": [p.path.name for p in photos if p.exif_rotated],
    }


def _features_stage(work: _Work, options: PosingOptions, device, progress: bool) -> dict[str, Any]:
    import pycolmap
    from tqdm.auto import tqdm

    work.database.unlink(missing_ok=True)
    photos = work.state["data"]["photos"]
    by_size: dict[tuple[int, int], list[str]] = {}
    for name, width, height in photos:
        by_size.setdefault((width, height), []).append(name)
    with tqdm(total=len(photos), desc="features", unit="image", disable=not progress) as bar:
        for (width, height), names in by_size.items():
            extraction = pycolmap.FeatureExtractionOptions()
            extraction.max_image_size = options.max_size
            extraction.num_threads = options.threads
            extraction.sift.max_num_features = options.features
            extraction.sift.first_octave = 0 if min(max(width, height), options.max_size) >= DOUBLING_BELOW else -1
            camera_id = -1
            # In batches so that the bar moves; every batch after the first joins the size
            # group's camera, so a group has one camera whatever the batch size.
            for start in range(0, len(names), FEATURE_BATCH):
                batch = names[start : start + FEATURE_BATCH]
                reader = pycolmap.ImageReaderOptions()
                reader.camera_model = options.camera_model
                reader.existing_camera_id = camera_id
                pycolmap.extract_features(
                    work.database,
                    work.images,
                    image_names=batch,
                    camera_mode=pycolmap.CameraMode.SINGLE,
                    reader_options=reader,
                    extraction_options=extraction,
                    device=device,
                )
                if camera_id == -1:
                    with pycolmap.Database.open(work.database) as database:
                        camera_id = database.read_image_with_name(batch[0]).camera_id
                bar.update(len(batch))
    with pycolmap.Database.open(work.database) as database:
        counts = [database.num_keypoints_for_image(image.image_id) for image in database.read_all_images()]
    if len(counts) < len(photos):
        raise PosingError(
            f"features: only {len(counts)} of {len(photos)} images could be read by COLMAP; "
            f"see the log in {work.root / 'logs'}"
        )
    return {"mean_features": float(np.mean(counts)) if counts else 0.0}


def _matching_stage(work: _Work, options: PosingOptions, kind: str, device, progress: bool) -> dict[str, Any]:
    import pycolmap
    from tqdm.auto import tqdm

    with pycolmap.Database.open(work.database) as database:
        database.clear_matches()
        database.clear_two_view_geometries()
        images = sorted(database.read_all_images(), key=lambda image: natural_key(image.name))
        mode = _matching_mode(options.matching, kind, len(images))
        chosen = _choose_pairs(database, images, mode, options)
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = options.threads
    pair_file = work.root / "pairs.txt"
    with tqdm(total=len(chosen), desc="matching", unit="pair", disable=not progress) as bar:
        for start in range(0, len(chosen), MATCH_BLOCK):
            block = chosen[start : start + MATCH_BLOCK]
            pair_file.write_text("".join(f"{images[i].name} {images[j].name}\n" for i, j in block))
            pycolmap.match_image_pairs(
                work.database,
                matching_options=matching,
                pairing_options=pycolmap.ImportedPairingOptions(match_list_path=str(pair_file)),
                device=device,
            )
            bar.update(len(block))
    return {"pairs": len(chosen), "matching_mode": mode}


def _matching_mode(requested: str, kind: str, count: int) -> str:
    if requested != "auto":
        return requested
    if kind == "video":
        return "sequential"
    return "exhaustive" if count <= EXHAUSTIVE_UP_TO else "retrieval"


def _choose_pairs(database, images, mode: str, options: PosingOptions) -> list[tuple[int, int]]:
    if mode == "exhaustive":
        return pairing.exhaustive_pairs(len(images))

    def retrieved() -> list[tuple[int, int]]:
        strongest = [
            pairing.strongest_features(
                database.read_keypoints(image.image_id),
                np.asarray(database.read_descriptors(image.image_id).data),
                FEATURES_FOR_RETRIEVAL,
            )
            for image in images
        ]
        return pairing.retrieval_pairs(strongest, options.neighbours)

    if mode == "retrieval":
        return retrieved()
    # Sequential: neighbours in time, plus retrieval to close loops (a walk-around coming back).
    return sorted(set(pairing.sequential_pairs(len(images), options.overlap)) | set(retrieved()))


def _mapping_stage(work: _Work, options: PosingOptions, progress: bool) -> dict[str, Any]:
    photos = work.state["data"]["photos"]
    order = {"auto": ("incremental", "global"), "incremental": ("incremental",), "global": ("global",)}
    best: tuple[int, str, Any, int] | None = None
    for mapper in order[options.mapper]:
        models = _map(work, mapper, options, len(photos), progress)
        largest = max(models.values(), key=lambda model: model.num_reg_images(), default=None)
        count = largest.num_reg_images() if largest is not None else 0
        if best is None or count > best[0]:
            best = (count, mapper, largest, len(models))
        if count == len(photos):
            break  # "auto" tries the global mapper only where incremental left images out
    registered, mapper, largest, model_count = best
    _check_registration(registered, len(photos), options, work)
    # The kept model goes to sparse/0 alone: pycolmap numbers the models it writes from 0.
    for child in work.sparse.iterdir():
        shutil.rmtree(child)
    (work.sparse / "0").mkdir()
    largest.write(work.sparse / "0")
    names = {image.name for image in largest.images.values() if image.has_pose}
    return {
        "registered": sorted(names, key=natural_key),
        "mapper_used": mapper,
        "models": model_count,
        "reprojection_error": float(largest.compute_mean_reprojection_error()),
        "track_length": float(largest.compute_mean_track_length()),
        "points": int(largest.num_points3D()),
        "cameras": [
            {"model": camera.model.name, "width": camera.width, "height": camera.height, "params": list(map(float, camera.params))}
            for camera in largest.cameras.values()
        ],
    }


def _map(work: _Work, mapper: str, options: PosingOptions, count: int, progress: bool) -> dict:
    """Run one mapper into an empty ``sparse/``; its models by index (kept in memory, so a later
    mapper may overwrite the folder)."""
    import pycolmap
    from tqdm.auto import tqdm

    shutil.rmtree(work.sparse, ignore_errors=True)
    work.sparse.mkdir(parents=True)
    with tqdm(total=count, desc=f"mapping ({mapper})", unit="image", disable=not progress) as bar:
        if mapper == "incremental":
            pipeline = pycolmap.IncrementalPipelineOptions()
            pipeline.num_threads = options.threads
            # COLMAP drops models under min(10, 0.8 N) images; how many is enough is decided
            # here, for every mapper alike (_check_registration).
            pipeline.min_model_size = 3
            models = pycolmap.incremental_mapping(
                work.database, work.images, work.sparse, pipeline, next_image_callback=lambda: bar.update(1)
            )
        else:
            pipeline = pycolmap.GlobalPipelineOptions()
            pipeline.num_threads = options.threads
            pipeline.min_model_size = 3
            models = pycolmap.global_mapping(work.database, work.images, work.sparse, pipeline)
        bar.n = max((model.num_reg_images() for model in models.values()), default=0)
        bar.refresh()
    return models


def _enough(total: int) -> int:
    """Registered images below this are an error: half of them, and at least 3."""
    return max(3, (total + 1) // 2)


def _check_registration(registered: int, total: int, options: PosingOptions, work: _Work) -> None:
    if registered >= _enough(total):
        if registered < total:
            out = work.root.with_name(work.root.name.removesuffix(".partial"))
            warnings.warn(f"{out}: {total - registered} of {total} photos could not be registered; "
                          f"{out / 'report.json'} lists them", stacklevel=3)
        return
    advice = (
        "take overlapping photos (each part of the scene in three or more photos, from nearby viewpoints)"
        if options.matching == "exhaustive" or work.state["data"].get("matching_mode") == "exhaustive"
        else "take overlapping photos, or try --matching exhaustive"
    )
    raise PosingError(
        f"only {registered} of {total} images registered; the photos share too little -- {advice}"
    )


def _undistortion_stage(work: _Work, options: PosingOptions) -> dict[str, Any]:
    import pycolmap

    shutil.rmtree(work.undistorted, ignore_errors=True)
    pycolmap.undistort_images(
        work.undistorted, work.sparse / "0", work.images, num_threads=options.threads
    )
    return {}


def _scene_stage(work: _Work, options: PosingOptions, progress: bool) -> dict[str, Any]:
    from tqdm.auto import tqdm

    from pointfield.scenes.formats.colmap import read_colmap
    from pointfield.scenes.formats.transforms_json import write_nerfstudio

    shutil.rmtree(work.scene, ignore_errors=True)
    work.scene.mkdir(parents=True)
    scene = read_colmap(work.undistorted)
    write_nerfstudio(scene, work.scene, points_file="points3D.ply")
    model = work.scene / "colmap" / "sparse" / "0"
    model.mkdir(parents=True)
    for part in (work.undistorted / "sparse").iterdir():
        if part.is_file():
            shutil.copyfile(part, model / part.name)
    images = sorted((work.scene / "images").iterdir())
    with tqdm(total=len(images) * len(options.downscales), desc="scene", unit="image", disable=not progress) as bar:
        for factor in options.downscales:
            folder = work.scene / f"images_{factor}"
            folder.mkdir()
            for image in images:
                _write_downscaled(image, folder / image.name, factor)
                bar.update(1)
    return {}


def _write_downscaled(source: Path, target: Path, factor: int) -> None:
    """Area-average ``factor`` x ``factor`` blocks (PIL's reduce), keeping the file's format."""
    from PIL import Image

    with Image.open(source) as image:
        reduced = image.reduce(factor)
        options = {"quality": 95} if source.suffix.lower() in (".jpg", ".jpeg") else {}
        reduced.save(target, **options)


def _report(work: _Work, out: Path, options: PosingOptions, device: str) -> PosingReport:
    data = work.state["data"]
    names = [row[0] for row in data["photos"]]
    registered = set(data["registered"])
    return PosingReport(
        out=str(out),
        images=len(names),
        registered=len(registered),
        unregistered=[name for name in names if name not in registered],
        reprojection_error=data["reprojection_error"],
        track_length=data["track_length"],
        points=data["points"],
        pairs=data["pairs"],
        matching=data["matching_mode"],
        mapper=data.get("mapper_used", options.mapper),
        models=data["models"],
        cameras=data["cameras"],
        stage_seconds=work.seconds(),
        device=device,
        exif_rotated=data.get("exif_rotated", []),
    )


def _write_report(scene: Path, report: PosingReport) -> None:
    from pointfield.scenes.tools import plot_cameras

    document = {**asdict(report), "seconds": report.seconds}
    (scene / "report.json").write_text(json.dumps(document, indent=2))
    plot_cameras(scene, scene / "cameras.png")


def _move_into_place(work: _Work, out: Path, overwrite: bool) -> None:
    """Rename the finished scene onto ``out`` (an old one only goes once the new one is whole)."""
    old = None
    if out.exists() and overwrite:
        old = out.with_name(out.name + ".old")
        shutil.rmtree(old, ignore_errors=True)
        os.replace(out, old)
    os.replace(work.scene, out)
    if old is not None:
        shutil.rmtree(old)
    shutil.rmtree(work.root)


# -- helpers --------------------------------------------------------------------------------------


def _log_to(folder: Path) -> None:
    """Send COLMAP's log to files in ``folder`` instead of the terminal.

    glog names each file ``colmap-<time>.<pid>``; the scene gets them joined as colmap/colmap.log.
    """
    import pycolmap

    folder.mkdir(exist_ok=True)
    pycolmap.logging.logtostderr = False
    pycolmap.logging.alsologtostderr = False
    # pointfield says what went wrong in its own words; COLMAP's own errors are in the log.
    pycolmap.logging.stderrthreshold = pycolmap.logging.FATAL
    pycolmap.logging.set_log_destination(pycolmap.logging.INFO, str(folder / "colmap-"))


def _joined_logs(folder: Path, target: Path) -> None:
    with target.open("wb") as joined:
        for part in sorted(folder.glob("colmap-*")):
            joined.write(part.read_bytes())


def _folder_files(folder: Path) -> list[Path]:
    if not folder.is_dir():
        return [folder]
    return sorted((p for p in folder.iterdir() if p.is_file()), key=lambda p: natural_key(p.name))


def _fingerprint(paths: list[Path]) -> list:
    """What identifies the input: each file's path, size and modification time."""
    rows = []
    for path in paths:
        try:
            stat = path.stat()
            rows.append([str(path.resolve()), stat.st_size, stat.st_mtime_ns])
        except OSError:
            rows.append([str(path), None, None])
    return rows


def _link_photos(photos: list[Photo], folder: Path) -> list[Photo]:
    """Hard-link (else copy) the photos into ``folder`` under unique names; COLMAP reads one folder."""
    linked, taken = [], set()
    for photo in photos:
        stem, suffix = photo.path.stem, photo.path.suffix.lower()
        name, counter = stem + suffix, 1
        while name.lower() in taken:
            counter += 1
            name = f"{stem}_{counter}{suffix}"
        taken.add(name.lower())
        target = folder / name
        try:
            os.link(photo.path, target)
        except OSError:
            shutil.copyfile(photo.path, target)
        linked.append(Photo(target, photo.width, photo.height, photo.exif_rotated))
    return linked
