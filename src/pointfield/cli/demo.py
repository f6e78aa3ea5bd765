"""``pointfield demo``: built-in clouds through every format, checked and drawn; a scene reconstructed.

``pointfield demo`` (and ``make demo``) calls :func:`run_demo`. It generates the clouds of
:mod:`pointfield.clouds.synthetic`, writes each in every registered format and encoding, reads
it back and checks that what came back is what went in, prints one table row per file, and
draws every cloud to PNG, with a contact sheet of all of them. Then it makes a synthetic scene,
trains the hash-grid field and Gaussian splats on it, prints their held-out PSNR, renders a
turntable GIF of each and exports the field's mesh and cloud (:func:`reconstruct_scene`); it
ends with what to look at and the commands to try next.

What "came back" means depends on what the format can hold:

- points and fields keep their dtype and values exactly (NaN included), except in formats that
  carry no dtype (:data:`VALUE_ONLY_FORMATS`), where the values must come back exactly once cast
  to the original dtype, and in LAS, whose coordinates are integers times a scale: there each
  coordinate must come back within half its scale;
- a mesh whose format stores each triangle's corners rather than shared vertices (STL) comes back
  with its vertices renumbered: there its triangles are compared corner by corner, with the
  corners' fields;
- anything a format cannot hold (a field, faces, NaN points for LAS) or has to change (LAS
  colours become uint16) must be named in a warning; something lost or changed without a
  warning is a failure.
"""

from __future__ import annotations

import argparse
import inspect
import os
import shutil
import sys
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pointfield.clouds import synthetic
from pointfield.clouds.cloud import PointCloud, Records
from pointfield.clouds.formats import Format, formats, read, write
from pointfield.clouds.mesh import Mesh
from pointfield.errors import PointfieldError
from pointfield.viz.render import image_grid, render_cloud, save_image

# Formats without dtypes: text has none, velodyne .bin stores every value as float32, and the
# mesh formats read through trimesh come back as float64 whatever they stored.
VALUE_ONLY_FORMATS = frozenset({"text", "off", "velodyne", "e57", "ptx", "obj", "stl", "gltf"})
# Formats that store coordinates as integers times a per-axis scale (metadata["scales"]).
SCALED_FORMATS = frozenset({"las"})


@dataclass(frozen=True)
class SceneSettings:
    """How the demo makes its synthetic scene, trains both scene models on it and exports geometry."""

    scene: str  # a `scene make` name
    views: int  # rendered (one in ten held out)
    size: int  # pixels square
    ngp_steps: int
    splat_steps: int
    frames: int  # of each turntable
    resolution: int  # TSDF voxels along the mesh box's longest side
    points: int  # in the exported cloud


# Measured in the README ("Two commands"), held out on the cube: the field 32.3 dB after 300
# steps, splats 30.9 dB after 700 (before the cube's box had room: 31.4, and 32.1 after 1000,
# which took the demo past 3 minutes).
SCENE_SETTINGS = SceneSettings(
    scene="cube", views=60, size=100, ngp_steps=300, splat_steps=700, frames=36, resolution=128, points=50_000
)
# The test suite's: seconds, and nothing to recognise.
SCENE_QUICK_SETTINGS = SceneSettings(
    scene="cube", views=12, size=16, ngp_steps=6, splat_steps=6, frames=3, resolution=24, points=500
)
TURNTABLE = "turntable.gif"


def demo_clouds(quick: bool = False) -> dict[str, PointCloud]:
    """The clouds of the demo by name; ``quick`` makes them about ten times smaller."""
    count = 1000 if quick else 20_000
    return {
        "sphere": synthetic.sphere(count, seed=0),
        "torus": synthetic.torus(count, seed=1),
        "cube": synthetic.cube_surface(count, seed=2),
        "lidar": synthetic.lidar_scan(16, 128, seed=3) if quick else synthetic.lidar_scan(seed=3),
        "rgbd": synthetic.depth_camera(30, 40, seed=4) if quick else synthetic.depth_camera(seed=4),
        "icosphere": synthetic.icosphere(1 if quick else 3),
    }


@dataclass
class RoundTrip:
    """One file of the demo: a cloud written in one format and encoding, then read back."""

    cloud: str
    format: str
    encoding: str
    path: Path
    bytes: int = 0
    points: int = 0
    fields_kept: int = 0
    fields_total: int = 0
    extras_kept: list[str] = field(default_factory=list)  # "faces", "grid"
    write_ms: float = 0.0
    read_ms: float = 0.0
    notes: list[str] = field(default_factory=list)  # what the format dropped or changed, warned
    problems: list[str] = field(default_factory=list)  # failures of the round trip
    skipped: str = ""  # why the format refused the cloud, if it did

    @property
    def ok(self) -> bool:
        return not self.problems


@dataclass
class SceneDemo:
    """The reconstruction half of the demo: the scene, each model's run, scores and turntable, geometry."""

    data: Path  # the synthetic scene, a Blender-format folder
    runs: dict[str, Path]  # "ngp", "splats" -> run folder
    metrics: dict[str, dict[str, Any]]  # model -> metrics.json (held-out "psnr", "ssim", "steps", ...)
    turntables: dict[str, Path]
    mesh: Path  # exported from the ngp field
    cloud: Path
    pictures: list[Path]  # of the mesh and the cloud


@dataclass
class DemoReport:
    """Everything :func:`run_demo` did: round trips, renders, contact sheet, the NeRF if trained."""

    round_trips: list[RoundTrip]
    renders: list[Path]
    contact_sheet: Path
    scene: SceneDemo | None = None

    @property
    def all_ok(self) -> bool:
        return all(trip.ok for trip in self.round_trips)


def run_demo(
    out_dir: str | os.PathLike[str] = "demo-output",
    quick: bool = False,
    progress: bool = True,
    print_fn: Callable[[str], Any] = print,
    scene: bool = True,
) -> DemoReport:
    """Round-trip the demo clouds through every format, print a table, draw them; reconstruct a scene.

    Files go to ``out_dir/files``, one PNG per cloud to ``out_dir/renders`` and the contact sheet
    to ``out_dir/clouds.png``; with ``scene``, :func:`reconstruct_scene` trains the hash-grid
    field and splats on a synthetic scene and exports the field's mesh and cloud. ``quick`` uses
    small clouds, images and runs (the test suite's setting). Returns the :class:`DemoReport`;
    ``report.all_ok`` is False if any round trip failed.
    """
    out_dir = Path(out_dir)
    files_dir, renders_dir = out_dir / "files", out_dir / "renders"
    files_dir.mkdir(parents=True, exist_ok=True)
    renders_dir.mkdir(parents=True, exist_ok=True)
    clouds = demo_clouds(quick)
    jobs = [
        (name, fmt, encoding)
        for name in clouds
        for fmt in formats()
        if fmt.write is not None
        for encoding in fmt.encodings
    ]
    trips = []
    for name, fmt, encoding in _progress(jobs, progress, "round trips"):
        path = files_dir / f"{name}-{encoding}{_suffix(fmt, encoding)}"
        trips.append(round_trip(name, clouds[name], fmt, encoding, path))
    print_fn(format_table(trips))

    width, height = (240, 180) if quick else (480, 360)
    images, renders = [], []
    for name, cloud in _progress(list(clouds.items()), progress, "renders"):
        image = render_cloud(cloud, width, height)
        renders.append(save_image(renders_dir / f"{name}.png", image))
        images.append(image)
    sheet = save_image(out_dir / "clouds.png", image_grid(images, list(clouds), columns=3))
    failed = sum(not trip.ok for trip in trips)
    print_fn(
        f"\n{len(trips) - failed} of {len(trips)} round trips ok"
        + (f", {failed} FAILED" if failed else "")
        + f"\nfiles:   {files_dir}\nrenders: {renders_dir} ({len(renders)} PNG)"
        + f"\nsheet:   {sheet}"
    )
    report = DemoReport(trips, renders, sheet)
    if scene:
        settings = SCENE_QUICK_SETTINGS if quick else SCENE_SETTINGS
        report.scene = reconstruct_scene(out_dir, settings, progress, print_fn)
    print_fn(next_steps(out_dir, report.scene))
    return report


def reconstruct_scene(
    out_dir: Path,
    settings: SceneSettings = SCENE_SETTINGS,
    progress: bool = True,
    print_fn: Callable[[str], Any] = print,
) -> SceneDemo:
    """Make a synthetic scene, train the hash-grid field and splats on it, export the field's geometry.

    Into ``out_dir``, for scene ``cube``: the scene (``scene-cube/``, as ``scene make`` writes it),
    the two runs (``ngp-cube/``, ``splats-cube/``, each with a turntable of colour | depth |
    opacity), and the field's mesh and cloud (``cube-mesh.ply``, ``cube-cloud.ply``) with a
    picture of each. Runs a previous demo left are replaced; a run folder holding anything else
    is refused.
    """
    # torch is imported only when this part runs, so other commands start fast (see cli/).
    from pointfield.fields.train import train as train_field
    from pointfield.geometry import export_cloud, export_mesh
    from pointfield.runs import load_run
    from pointfield.scenes.synthetic import make_scene
    from pointfield.splats.train import train as train_splats
    from pointfield.viz.render import render_file

    name = settings.scene
    runs = {"ngp": out_dir / f"ngp-{name}", "splats": out_dir / f"splats-{name}"}
    for run_dir in runs.values():
        _clear_previous_run(run_dir)
    data = make_scene(name, out_dir / f"scene-{name}", views=settings.views, size=settings.size, overwrite=True)
    print_fn(f"\nscene:   the synthetic {settings.scene}, {settings.views} views of {settings.size} x "
             f"{settings.size} pixels with depth and alpha ({data})")
    trainers = {
        "ngp": lambda out: train_field(str(data), model="ngp", out=out, steps=settings.ngp_steps, progress=progress),
        "splats": lambda out: train_splats(str(data), out=out, steps=settings.splat_steps, progress=progress),
    }
    described = {"ngp": "the hash-grid field (Instant-NGP)", "splats": "Gaussian splats"}
    metrics, turntables = {}, {}
    for model, run_dir in runs.items():
        label = f"{model}:".ljust(9)
        print_fn(f"{label}training {described[model]}")
        began = time.perf_counter()
        metrics[model] = trainers[model](run_dir)
        turntables[model] = Path(load_run(run_dir).render_path("orbit", frames=settings.frames, out=run_dir / TURNTABLE,
                                                               progress=progress)["out"])
        print_fn(f"{label}held-out PSNR {metrics[model]['psnr']:.2f} dB, SSIM "
                 f"{metrics[model]['ssim']:.3f} on {metrics[model]['views']} views "
                 f"({metrics[model]['steps']} steps, {time.perf_counter() - began:.0f} s with the turntable)")
    mesh, cloud = out_dir / f"{name}-mesh.ply", out_dir / f"{name}-cloud.ply"
    export_mesh(runs["ngp"], mesh, resolution=settings.resolution, progress=progress)
    export_cloud(runs["ngp"], cloud, points=settings.points, progress=progress)
    pictures = [render_file(path, path.with_suffix(".png"), width=480, height=360, up="z") for path in (mesh, cloud)]
    print_fn(f"geometry: mesh {mesh} and cloud {cloud} from the ngp field (pictures beside them)")
    return SceneDemo(data, runs, metrics, turntables, mesh, cloud, pictures)


def next_steps(out_dir: Path, scene: SceneDemo | None) -> str:
    """What to look at and what to try next, printed last."""
    lines = ["\nLook at:", f"  {out_dir / 'clouds.png'}  every demo cloud, drawn"]
    commands = ["pointfield cloud info ../shared/data/...            any scan: PLY, PCD, LAS/LAZ, E57, ..."]
    if scene is not None:
        for model, turntable in scene.turntables.items():
            lines.append(f"  {turntable}  {model}: colour | depth | opacity")
        lines += [f"  {picture}" for picture in scene.pictures]
        commands += [
            f"pointfield view {scene.runs['splats']} {scene.mesh}   turn them around in the browser",
            f"pointfield nerf export {scene.runs['ngp']} --mesh mesh.glb --faces 20000 --method density   an object's field, meshed from its density",
            "pointfield scene make still-life --out still-life && pointfield splat train still-life --max-time 300",
            "pointfield route PATH --task 'mesh for a game engine'   which representation fits your data",
        ]
    return "\n".join([*lines, "Next:", *(f"  {command}" for command in commands)])


def _clear_previous_run(run_dir: Path) -> None:
    from pointfield.training.run import (
        RunDirectory,  # torch: only when the scene part runs
    )

    if not run_dir.exists():
        return
    run = RunDirectory(run_dir)
    if run.exists() and run.read_config().get("task") in ("nerf", "splat"):
        shutil.rmtree(run_dir)
    elif not run_dir.is_dir() or any(run_dir.iterdir()):
        raise PointfieldError(
            f"{run_dir} holds something other than a run of the demo; move it away or choose another --out"
        )


def round_trip(name: str, cloud: PointCloud, fmt: Format, encoding: str, path: Path) -> RoundTrip:
    """Write ``cloud`` to ``path`` as ``fmt`` / ``encoding``, read it back and compare.

    A format that refuses the cloud with a :class:`PointfieldError` is recorded as skipped; any
    other exception while writing, and any while reading back, is a failure of the round trip.
    """
    trip = RoundTrip(name, fmt.name, encoding, path)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        start = time.perf_counter()
        try:
            write(path, cloud, format=fmt.name, encoding=encoding)
        except PointfieldError as error:
            trip.skipped = str(error)
            return trip
        except Exception as error:  # noqa: BLE001 - reported in the table, the demo goes on
            trip.problems.append(f"writing raised {type(error).__name__}: {error}")
            return trip
        trip.write_ms = 1000 * (time.perf_counter() - start)
        trip.bytes = path.stat().st_size
        start = time.perf_counter()
        try:
            back = read(path, format=fmt.name, **_read_options(fmt, trip.bytes, cloud))
        except Exception as error:  # noqa: BLE001 - reported in the table, the demo goes on
            trip.problems.append(f"reading back raised {type(error).__name__}: {error}")
            return trip
        trip.read_ms = 1000 * (time.perf_counter() - start)
    warned = " ".join(str(w.message) for w in caught)
    compare(cloud, back, fmt.name, warned, trip)
    return trip


def compare(
    original: PointCloud, back: Any, format_name: str, warned: str, trip: RoundTrip
) -> None:
    """Fill ``trip`` with what ``back`` kept of ``original``, what it lost, and any failure.

    ``warned`` is the text of the warnings raised while writing and reading: a field, the faces
    or NaN points that did not survive must be named there.
    """
    if isinstance(back, Records):
        trip.problems.append("came back without coordinates")
        return
    trip.points = len(back)
    renumbered = _renumbered(original, back)
    if renumbered:  # STL stores each triangle's corners, not shared vertices: compare the triangles
        trip.notes.append("vertices renumbered; triangles compared corner by corner")
        original, back = _corners(original), _corners(back)
    keep = np.arange(len(original))
    if len(back) != len(original):
        finite = np.flatnonzero(np.isfinite(original.points).all(axis=1))
        if len(back) == len(finite) and "NaN" in warned:
            keep = finite
            trip.notes.append(f"{len(original) - len(finite)} NaN points dropped")
        else:
            trip.problems.append(f"{len(original)} points came back as {len(back)}")
            return

    same_points = _same_points(original.points[keep], back, format_name)
    if not same_points:
        trip.problems.append(f"points changed ({original.points.dtype} -> {back.points.dtype})")
    if renumbered and same_points:
        trip.extras_kept.append("faces")

    trip.fields_total = len(original.fields)
    for field_name, values in original.fields.items():
        values = values[keep]
        returned = back.fields.get(field_name)
        if returned is not None and _same_values(values, returned, format_name):
            trip.fields_kept += 1
        elif field_name in warned:
            trip.notes.append(f"{field_name} {'changed' if returned is not None else 'dropped'}")
        elif returned is None:
            trip.problems.append(f"{field_name} lost without a warning")
        else:
            trip.problems.append(f"{field_name} changed ({values.dtype} -> {returned.dtype})")

    if isinstance(original, Mesh) and len(original.faces):
        if isinstance(back, Mesh) and np.array_equal(original.faces, back.faces):
            trip.extras_kept.append("faces")
        elif "faces" in warned:
            trip.notes.append("faces dropped")
        else:
            trip.problems.append("faces lost or changed without a warning")
    if original.shape is not None and back.shape == original.shape:
        trip.extras_kept.append("grid")


def _renumbered(original: PointCloud, back: Any) -> bool:
    """Whether ``back`` is ``original``'s mesh with as many triangles but its vertices in another order."""
    return (isinstance(original, Mesh) and isinstance(back, Mesh) and len(original.faces) > 0
            and len(back.triangles()) == len(original.triangles())
            and not np.array_equal(original.faces, back.faces))


def _corners(mesh: Mesh) -> PointCloud:
    """Each triangle's three corners in order, with their fields: ``(3F, 3)`` points."""
    corners = mesh.triangles().reshape(-1)
    return PointCloud(mesh.points[corners], {name: values[corners] for name, values in mesh.fields.items()})


def _same_points(points: np.ndarray, back: PointCloud, format_name: str) -> bool:
    if format_name in SCALED_FORMATS:
        scales = np.asarray(back.metadata.get("scales", (0.0, 0.0, 0.0)), np.float64)
        error = np.abs(back.points.astype(np.float64) - points.astype(np.float64))
        return bool((error <= scales / 2 * (1 + 1e-9) + 1e-12).all())
    return _same_values(points, back.points, format_name)


def _same_values(original: np.ndarray, returned: np.ndarray, format_name: str) -> bool:
    """Same dtype and values (NaN == NaN); value-only formats may change the dtype."""
    if original.shape != returned.shape:
        return False
    if original.dtype != returned.dtype:
        if format_name not in VALUE_ONLY_FORMATS:
            return False
        with np.errstate(invalid="ignore", over="ignore"):
            returned = returned.astype(original.dtype)
    return bool(np.array_equal(original, returned, equal_nan=original.dtype.kind in "fc"))


def _read_options(fmt: Format, size: int, cloud: PointCloud) -> dict[str, Any]:
    """Options the reader needs to read back what was written.

    A raw float32 scan has no header to say how many values each point has; the demo knows the
    point count it wrote, so the file size tells it.
    """
    if fmt.name == "velodyne" and "columns" in inspect.signature(fmt.read).parameters:
        return {"columns": size // (4 * max(len(cloud), 1))}
    return {}


def _suffix(fmt: Format, encoding: str) -> str:
    """The file suffix for an encoding: ``.laz`` for LAS's ``laz``, else the format's first."""
    return f".{encoding}" if f".{encoding}" in fmt.suffixes else fmt.suffixes[0]


def _progress(items: list, enabled: bool, description: str):
    from tqdm import tqdm

    return tqdm(items, desc=description, unit="", leave=False, disable=not enabled, file=sys.stderr)


def format_table(trips: list[RoundTrip]) -> str:
    """One aligned row per round trip, then the notes and failures under it."""
    header = (
        "cloud",
        "format",
        "encoding",
        "size",
        "points",
        "fields kept",
        "write ms",
        "read ms",
        "ok",
    )
    rows = []
    for trip in trips:
        if trip.skipped:
            rows.append(
                (trip.cloud, trip.format, trip.encoding, "-", "-", "-", "-", "-", "skipped")
            )
            continue
        kept = f"{trip.fields_kept}/{trip.fields_total}" + "".join(
            f" +{e}" for e in trip.extras_kept
        )
        rows.append(
            (
                trip.cloud,
                trip.format,
                trip.encoding,
                _size(trip.bytes),
                f"{trip.points:,}",
                kept,
                f"{trip.write_ms:.1f}",
                f"{trip.read_ms:.1f}",
                "ok" if trip.ok else "FAILED",
            )
        )
    widths = [max(len(row[i]) for row in [header, *rows]) for i in range(len(header))]
    numeric = {3, 4, 6, 7}
    lines = []
    previous_cloud = None
    for row in [header, *rows]:
        if previous_cloud is not None and row[0] != previous_cloud:
            lines.append("")
        previous_cloud = row[0] if row is not header else None
        lines.append(
            "  ".join(
                c.rjust(w) if i in numeric else c.ljust(w)
                for i, (c, w) in enumerate(zip(row, widths, strict=True))
            ).rstrip()
        )
    for trip in trips:
        details = [f"skipped: {trip.skipped}"] if trip.skipped else []
        details += trip.notes + [f"FAILED: {p}" for p in trip.problems]
        if details:
            lines.append(f"  {trip.path.name}: " + "; ".join(details))
    return "\n".join(lines)


def _size(count: int) -> str:
    if count < 1000:
        return f"{count} B"
    return f"{count / 1000:.1f} kB" if count < 1_000_000 else f"{count / 1_000_000:.1f} MB"


# -- the command ---------------------------------------------------------------------------------


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Add ``demo`` to the ``pointfield`` parser."""
    demo = subparsers.add_parser(
        "demo",
        help="round-trip clouds through every format and draw them; train a field and splats, export a mesh",
        description="Generate a few clouds and a mesh, write each in every format and encoding "
        "that can hold it, read them back and check that nothing was lost, print a summary "
        "table and write PNG renders. Then make a synthetic scene, train the hash-grid field "
        "(ngp) and Gaussian splats on it (about two minutes on a 2-core CPU), print their held-out "
        "PSNR, write turntable GIFs, and export the field's mesh and point cloud with pictures. "
        "Exits non-zero if any round trip failed.",
    )
    demo.add_argument(
        "--out", type=Path, default=Path("demo-output"), help="output folder (default: demo-output)"
    )
    demo.add_argument(
        "--quick", action="store_true",
        help="small clouds, images and runs: seconds instead of minutes",
    )
    demo.add_argument(
        "--clouds-only", action="store_true", help="only the clouds: no scene, no training",
    )
    demo.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    report = run_demo(args.out, quick=args.quick, scene=not args.clouds_only)
    return 0 if report.all_ok else 1
