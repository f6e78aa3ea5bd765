"""The router's rules: from what was given (an :class:`~.inputs.Input`) and what is wanted (a task)
to the representation that fits, why, and the pointfield commands to run next.

The rules, with the costs behind them, are tabled in ``docs/route.md``. In short: what is already
explicit (clouds, meshes, splats, trained runs) is used as it is, converted only when the task
needs another form; photos, video and posed datasets go through the hash-grid field (``ngp``) --
or through Gaussian splats when the task is real-time viewing, or new views of a real capture
that has sparse points to start splats from, where pointfield's own benchmarks show splats ahead.
"""

from __future__ import annotations

import os
import re
import shlex
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pointfield.errors import PointfieldError
from pointfield.route.inputs import Input, inspect_path
from pointfield.viewer.clouds import DEFAULT_MAX_POINTS

POINT_CLOUD = "point cloud"
MESH = "mesh"
VOXELS = "voxels"
RADIANCE_FIELD = "radiance field"
SPLATS = "Gaussian splats"
REPRESENTATIONS = (POINT_CLOUD, MESH, VOXELS, RADIANCE_FIELD, SPLATS)

TASKS: dict[str, tuple[str, tuple[str, ...]]] = {
    "classify": ("say what object a cloud is",
                 (r"classif", r"recogni[sz]", r"categor", r"what (object|it) is", r"identify")),
    "segment": ("label every point (parts, classes)",
                (r"segment", r"\bparts?\b", r"per[- ]point", r"semantic", r"\blabel")),
    "reconstruct": ("reconstruct the scene in 3D",
                    (r"reconstruct", r"3d model", r"digiti[sz]", r"captur", r"photogrammetry", r"\bscan")),
    "novel-views": ("render new views",
                    (r"novel", r"new views?", r"other views?", r"render", r"turntable", r"fly[- ]?through",
                     r"\borbit", r"\bvideo")),
    "mesh": ("a mesh: game engine, CAD, 3D printing",
             (r"\bmesh", r"\bgames?\b", r"engine", r"unity", r"unreal", r"godot", r"3d print", r"\bcad\b",
              r"\bglb\b", r"gltf", r"\bobj\b", r"\bstl\b", r"triangle")),
    "measure": ("measure distances, sizes, volumes",
                (r"measur", r"distance", r"dimension", r"\bsizes?\b", r"length", r"volume", r"\barea\b",
                 r"survey", r"metric")),
    "realtime": ("view it interactively, in real time",
                 (r"real[- ]?time", r"interactiv", r"\bvr\b", r"\bar\b", r"viewer", r"\bview(ing)?\b",
                  r"explore", r"\bfps\b", r"\bweb\b", r"look at")),
    "collision": ("a robot's collision / occupancy map",
                  (r"collision", r"robot", r"occupan", r"obstacle", r"navigat", r"path[- ]?planning",
                   r"planner", r"voxel")),
}
"""Task name -> (what it means, word patterns that name it in ``--task WORDS``)."""

TASK_PRECEDENCE = ("collision", "mesh", "realtime", "measure", "segment", "classify", "novel-views", "reconstruct")
"""When words name several tasks, the most specific wins: "real-time views of the reconstruction" is realtime."""

SCHEMA = 1
"""Version of :meth:`Route.to_dict`'s layout; it changes only when a key changes meaning or goes away."""

TRAINING_SIDE = 256
"""Longest image side to train at on a CPU: --downscale is the power of two (at most 8) that gets there."""

HOLDOUT_EVERY = 10
"""Every N-th view held out to score a scene that has no test split (as the benchmarks do)."""

MESH_FACES = 200_000
"""Triangles of an exported mesh: light enough for a game engine, enough for a scanned object."""

VOXEL = 0.05
"""Voxel side of a collision map, in the file's units (5 cm for lidar and LAS, which are metres)."""
MAX_RANGE = 30
"""Metres a lidar ray is trusted to in an occupancy map (OctoMap's maxrange): farther, it frees space only."""

LABEL_FIELDS = ("label", "labels", "classification", "class", "semantic", "scalar_label")
"""Per-point fields that hold segmentation labels, as scans name them (LAS: classification)."""


@dataclass(frozen=True)
class Plan:
    """What a rule decides: a representation (one of :data:`REPRESENTATIONS`), why, and the steps."""

    representation: str
    reason: str
    commands: list[str]
    python: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class Route:
    """The router's answer for ``input`` and ``task`` (None: none given): :class:`Plan`'s fields."""

    input: Input
    task: str | None
    task_words: str | None
    representation: str
    reason: str
    commands: tuple[str, ...]
    python: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """The JSON form (``pointfield route --json``); its keys are stable (:data:`SCHEMA`).

        ``schema``, ``inputs`` (paths), ``input_kind`` (one of :data:`~.inputs.KINDS`),
        ``details`` (what inspection found; keys by kind), ``task`` (a :data:`TASKS` name or
        None), ``task_words`` (as given), ``representation``, ``reason`` (one line),
        ``commands`` (shell lines, in order), ``python`` (lines of one Python program, to run after
        the commands, for a step no command does; else empty), ``notes`` (caveats, and what the
        upper-case placeholders such as ``DATA`` stand for; else empty).
        """
        return {
            "schema": SCHEMA,
            "inputs": [str(path) for path in self.input.paths],
            "input_kind": self.input.kind,
            "details": self.input.details,
            "task": self.task,
            "task_words": self.task_words,
            "representation": self.representation,
            "reason": self.reason,
            "commands": list(self.commands),
            "python": list(self.python),
            "notes": list(self.notes),
        }


def parse_task(words: str | None) -> str | None:
    """The :data:`TASKS` name that ``words`` ask for; None for no words.

    A task's own name works ("novel-views", "realtime"), and so do plain words: "mesh for a
    game engine" is mesh, "a robot's collision map" collision. Words that name no task are a
    :class:`PointfieldError` listing the tasks.
    """
    if words is None or not words.strip():
        return None
    text = " ".join(words.lower().split())
    if text.replace(" ", "-") in TASKS:
        return text.replace(" ", "-")
    named = {task for task, (_, patterns) in TASKS.items() if any(re.search(p, text) for p in patterns)}
    for task in TASK_PRECEDENCE:
        if task in named:
            return task
    known = "; ".join(f"{task} ({meaning})" for task, (meaning, _) in TASKS.items())
    raise PointfieldError(f"--task {words!r} names no task pointfield knows; say one of: {known}")


def plan(given: Input, task: str | None) -> Plan:
    """The rule for ``given``'s kind applied to ``task``."""
    return _RULES[given.kind](given, task)


# -- explicit inputs: a cloud, a mesh, splats, a folder of clouds ------------------------------


def _cloud(given: Input, task: str | None) -> Plan:
    source, name, details = str(given.path), _name(given.path), given.details
    look = [_pf("cloud", "info", source), _pf("view", source)]
    if task == "classify":
        notes = [("DATA: your labelled clouds, one subfolder per class (or ModelNet); without DATA, "
                  "classify train learns pointfield's synthetic shapes, not your classes")]
        if _is_scene_scale(details):
            notes.append(f"PointNet names one object per cloud; {name} looks like a whole scene "
                         f"({_points_text(details)}): crop the objects out, or segment it instead")
        return Plan(POINT_CLOUD, "PointNet classifies the points as they are: one shared MLP per point, then a "
                    "max-pool, so their order and number do not matter; it needs a model trained on your classes",
                    [_pf("classify", "train", "DATA", "--model", "pointnet", "--out", "runs/classify"),
                     _pf("classify", "predict", "runs/classify", source)], notes=notes)
    if task == "segment":
        label = next((f for f in details.get("fields", []) if f.lower() in LABEL_FIELDS), None)
        notes = ["DATA: a folder of clouds whose points carry integer labels"]
        if label:
            notes.append(f"{name} has a {label!r} field: clouds like it are training data as they are")
        return Plan(POINT_CLOUD, "Segmentation labels points, so it runs on the points themselves: PointNet's "
                    "per-point features joined with the global one",
                    [_pf("segment", "train", "DATA", "--label-field", label or "label", "--out", "runs/segment"),
                     _predict("segment", "runs/segment", source)], notes=notes)
    if task == "mesh":
        notes = [("cloud poisson closes one watertight surface through points with normals (Poisson "
                  "reconstruction): right for a scanned object; an open scan (a room, a street) gets closed where "
                  "nothing was seen, so for those route the photos with --task mesh")]
        python = [] if _has_normals(details) else [
            "import pointfield",
            "from pointfield.clouds.ops import farthest_point_subset",
            "from pointfield.clouds.transforms import EstimateNormals",
            f"cloud = pointfield.read({source!r})",
            "cloud = EstimateNormals(16)(cloud.select(farthest_point_subset(cloud.points, 100_000)))  # thinned, spread",
            f"pointfield.write({name + '-normals.ply'!r}, cloud)  # x y z nx ny nz: what meshers take",
        ]
        commands = [_pf("cloud", "info", source)]
        if _has_normals(details) and details["format"] != "ply":
            commands.append(_pf("cloud", "convert", source, f"{name}-normals.ply"))
        meshed = source if _has_normals(details) else f"{name}-normals.ply"  # the Python below writes it
        commands.append(_pf("cloud", "poisson", meshed, f"{name}-mesh.ply", "--depth", "8"))
        return Plan(MESH, "A game engine wants triangles, and a surface through scanned points needs their normals "
                    "to know inside from outside", commands, python, notes)
    if task == "collision":
        commands = [_pf("cloud", "info", source), _pf("cloud", "voxelize", source, f"{name}-voxels.npz", "--voxel",
                                                      str(VOXEL))]
        notes = [f"voxel side {VOXEL} in the file's units (metres for lidar and LAS): choose your robot's resolution"]
        if details["format"] == "velodyne":  # a sweep in its sensor's frame: the rays start at the origin
            commands.append(_pf("cloud", "occupancy", source, "--voxel", str(VOXEL), "--max-range", MAX_RANGE,
                                "--out", f"{name}.bt"))
            notes.append(f"cloud occupancy casts each point's ray from the sensor (at the scan's origin): free and "
                         f"unknown space too, as OctoMap's .bt, within {MAX_RANGE} m")
        return Plan(VOXELS, "A planner asks whether a cell is free: an occupancy grid answers that in constant time, "
                    "in memory bounded by the volume, not by how densely the sensor sampled it", commands,
                    _voxel_python(f"pointfield.read({source!r})", f"{name}-voxels.npz"), notes)
    if task == "measure":
        return Plan(POINT_CLOUD, "Scanned points are metric and explicit: measure on them directly, with no model in "
                    "between to smooth the geometry (LAS keeps float64 coordinates)", look,
                    notes=["cloud info prints the bounds; the viewer measures between points"])
    if task == "novel-views":
        return Plan(POINT_CLOUD, "Points render from any viewpoint as they are; photoreal new views need the photos "
                    "(a radiance field or splats), not the scan",
                    [_pf("cloud", "render", source, "--out", f"{name}.png"), _pf("view", source)])
    notes = []
    if isinstance(details.get("points"), int) and details["points"] > DEFAULT_MAX_POINTS:
        notes.append(f"{_points_text(details)}: view shows a subset of {DEFAULT_MAX_POINTS:,} (--max-points to change)")
    reasons = {
        "realtime": "Points draw at interactive rates directly: nothing to train, nothing to convert",
        "reconstruct": "A scan is already a 3D reconstruction, explicit and metric; radiance fields and splats are "
                       "for photos, not points",
        None: "It is already explicit geometry: look at it, measure it, or feed it to PointNet as it is",
    }
    return Plan(POINT_CLOUD, reasons[task], [*look, _pf("cloud", "render", source, "--out", f"{name}.png")],
                notes=notes)


def _mesh(given: Input, task: str | None) -> Plan:
    source, name = str(given.path), _name(given.path)
    if task in ("classify", "segment"):
        root = _modelnet_root(given.path)
        data, run = (str(root), f"runs/{root.name}") if root and task == "classify" else ("DATA", f"runs/{task}")
        labels = "one subfolder per class" if task == "classify" else "integer per-point labels"
        notes = [] if data != "DATA" else [f"DATA: a folder of labelled meshes or clouds ({labels})"]
        return Plan(POINT_CLOUD, "PointNet takes points: the mesh is sampled uniformly over its surface area "
                    f"(what {task} train and predict do to meshes by themselves)",
                    [_pf(task, "train", data, "--model", "pointnet", "--out", run), _predict(task, run, source)],
                    notes=notes)
    if task == "collision":
        return Plan(VOXELS, "A planner asks whether a cell is free: the voxels the mesh's surface passes through "
                    "and those it encloses (found by its winding number, so small holes do not leak)",
                    [_pf("cloud", "info", source),
                     _pf("cloud", "voxelize", source, f"{name}-voxels.binvox", "--voxel", str(VOXEL), "--fill")],
                    ["import pointfield",
                     "from pointfield.volumes import voxelize_mesh, write_voxels",
                     f"grid = voxelize_mesh(pointfield.read({source!r}), {VOXEL}, fill=True)",
                     f"write_voxels({name + '-voxels.binvox'!r}, grid)"],
                    [f"voxel side {VOXEL} in the mesh's units: choose your robot's resolution"])
    if task == "mesh":
        return Plan(MESH, "It is already a mesh: convert it to what the engine imports (PLY here; GLB or OBJ "
                    "through trimesh)", [_pf("cloud", "info", source), _pf("cloud", "convert", source, f"{name}.ply")],
                    ["import pointfield",
                     "from pointfield.geometry.meshes import write_mesh",
                     f"write_mesh({name + '.glb'!r}, pointfield.read({source!r}))"])
    reasons = {
        "measure": "A mesh is explicit and keeps its units: measure on its vertices and faces directly",
        "novel-views": "A mesh rasterises from any viewpoint as it is",
        "realtime": "A mesh rasterises in real time on any GPU: nothing to train",
        "reconstruct": "It is already a surface: nothing to reconstruct",
        None: "It is already a mesh, the most explicit representation: look at it, convert it, or sample it into "
              "a cloud for PointNet",
    }
    return Plan(MESH, reasons[task], [_pf("cloud", "info", source), _pf("view", source),
                                      _pf("cloud", "render", source, "--out", f"{name}.png")])


def _splats(given: Input, task: str | None) -> Plan:
    source, name = str(given.path), _name(given.path)
    if task == "mesh":
        return Plan(MESH, "A mesh is fused from rendered depth, which needs the splats' run (its cameras), not "
                    "the .ply alone", [_pf("splat", "export", "RUN", "--mesh", f"{name}.glb", "--faces", MESH_FACES)],
                    notes=["RUN: the run folder that trained these splats (pointfield splat train)"])
    if task in ("classify", "segment", "measure", "collision"):
        # A splat .ply reads as a cloud of the Gaussians' centres, with their parameters as fields.
        as_cloud = _cloud(given, task)
        return Plan(as_cloud.representation, f"{as_cloud.reason} (a splat .ply reads as the cloud of its centres)",
                    as_cloud.commands, as_cloud.python, as_cloud.notes)
    return Plan(SPLATS, "They are Gaussian splats already: they rasterise in real time, in pointfield's viewer or "
                "any splat viewer, and render new views as they are",
                [_pf("view", source), _pf("splat", "render", source, "--scene", "SCENE", "--out", f"{name}.gif")],
                notes=["SCENE: the posed dataset the splats were trained on (splat render takes its cameras)"])


def _clouds(given: Input, task: str | None) -> Plan:
    details = given.details
    folder = given.path if given.path.is_dir() else None
    files = [str(path) for path in given.paths] if folder is None else ["FILE"]
    name = _name(folder) if folder is not None else "clouds"
    run = f"runs/{name}"
    if task == "segment" and folder is not None:
        return Plan(POINT_CLOUD, "A folder of labelled clouds is a segmentation dataset as it is",
                    [_pf("segment", "train", folder, "--label-field", "label", "--out", run),
                     _pf("segment", "eval", run), _predict("segment", run, *files)],
                    notes=["every cloud needs an integer per-point label field (--label-field names it)",
                           "FILE: the clouds or meshes to label"])
    if task in (None, "classify") and (len(details["classes"]) >= 2 or details.get("modelnet") == "h5"):
        return Plan(POINT_CLOUD, "One subfolder per class is a classification dataset as it is: PointNet learns "
                    "from the points (meshes are sampled over their surface)",
                    [_pf("classify", "train", folder, "--model", "pointnet", "--out", run),
                     _pf("classify", "eval", run), _pf("classify", "predict", run, *files)],
                    notes=["FILE: the clouds or meshes to classify"])
    if task in ("classify", "segment"):
        return Plan(POINT_CLOUD, f"PointNet {_DOES[task]} the points as they are; it needs a model trained on your "
                    "labels",
                    [_pf(task, "train", "DATA", "--out", f"runs/{task}"), _predict(task, f"runs/{task}", *files)],
                    notes=["DATA: labelled clouds (classify: one subfolder per class; segment: per-point labels)"])
    if task == "collision" and folder is None and len(files) >= 2:
        return Plan(VOXELS, "A planner asks whether a cell is free: align the scans, then cast each point's ray from "
                    "its scan's sensor through the aligned frame (OctoMap's occupied, free and unknown)",
                    [_pf("cloud", "align", *files, "--out", f"{name}.ply"),
                     _pf("cloud", "occupancy", "--poses", f"{name}.poses.json", "--voxel", str(VOXEL),
                         "--out", f"{name}.bt", "--out", f"{name}-occupied.npz"),
                     _pf("cloud", "occupancy-query", f"{name}.bt", "--points", "X,Y,Z")],
                    notes=[(f"each scan's sensor at its own origin (a lidar's frame; --origin X,Y,Z otherwise); "
                            f"voxel side {VOXEL} in the scans' units"), "X,Y,Z: a point a planner asks about"])
    if folder is not None and details["first"] is None:
        raise PointfieldError(f"{folder}: ModelNet's HDF5 files are training data for classify; --task {task} "
                              f"needs clouds or meshes")
    first = Path(details["first"]) if folder is not None else given.path
    one = plan(inspect_path(first), task)
    return Plan(one.representation, one.reason, one.commands, one.python,
                [*one.notes, f"shown for {first}: the same for each of the {details['files']} files"])


# -- captures: photos, video, posed datasets --------------------------------------------------


@dataclass(frozen=True)
class _Capture:
    """Photos, a video or a posed dataset on their way to a trained scene model."""

    steps: list[str]  # the commands that pose them (none for a posed dataset)
    scene: str  # the posed scene, as the commands name it
    name: str
    options: list[str]  # --downscale, --holdout-every
    points: bool  # whether the scene has sparse points to start splats from
    object: bool  # an object on a transparent background (a bounded scene)
    notes: list[str]


def _capture(given: Input) -> _Capture:
    details = given.details
    if given.kind == "scene":
        held_out = any(split in details["splits"] for split in ("test", "val"))
        notes = [] if details["frames"] >= 20 else [f"only {details['frames']} posed views: expect a rough model"]
        folder = given.path if given.path.is_dir() else given.path.parent  # transforms.json, poses_bounds.npy
        return _Capture([], str(given.path), _name(folder),
                        _training_options(details["width"], details["height"], held_out),
                        bool(details["points"]), bool(details["object"]), notes)
    if given.kind == "video":
        name = _name(given.path)
        scene = f"{name}-scene"
        return _Capture([_pf("scene", "from-video", given.path, "--out", scene, "--frames", 150)], scene, name,
                        _training_options(details["width"], details["height"], False), True, False, [])
    folder = details["folder"]
    name = _name(Path(folder) if folder else given.path.parent)
    scene = f"{name}-scene"
    notes = []
    if details["photos"] < 20:
        notes.append(f"{details['photos']} photo{'s' if details['photos'] != 1 else ''}: structure from motion "
                     "needs many overlapping views (20 to 100, each scene point in three or more)")
    return _Capture([_pf("scene", "from-images", *given.paths, "--out", scene)], scene, name,
                    _training_options(details["width"], details["height"], False), True, False, notes)


def _captured(given: Input, task: str | None) -> Plan:
    capture = _capture(given)
    name, steps, notes = capture.name, capture.steps, list(capture.notes)
    run, splat_run = f"runs/{name}", f"runs/{name}-splats"
    ngp = _pf("nerf", "train", capture.scene, "--model", "ngp", *capture.options, "--out", run)
    splats = _pf("splat", "train", capture.scene, *capture.options, "--out", splat_run)
    cloud = f"{name}-cloud.ply"
    if task == "realtime":
        if not capture.points:
            notes.append("the scene has no sparse points, so splats start at random: on the fox that cost 11 dB "
                         "(benchmarks/RESULTS.md); pose its photos with scene from-images to get points")
        return Plan(SPLATS, "Real-time viewing wants splats: they rasterise where a radiance field marches rays "
                    "(22 against 10 fps at 100 x 100 on 2 CPU cores), and every splat viewer reads their .ply",
                    [*steps, splats, _pf("splat", "export", splat_run, "--out", f"{name}-splats.ply"),
                     _pf("view", f"{name}-splats.ply")], notes=notes)
    if task == "novel-views" and capture.points and not capture.object:
        return Plan(SPLATS, "New views of a real capture with sparse points: splats started from them beat the "
                    "hash grid in the same time (fox: 24.5 against 23.1 dB in 120 s) and render in real time",
                    [*steps, splats, _pf("splat", "render", splat_run, "--path", "orbit", "--out", f"{name}.gif")],
                    notes=notes)
    if task == "mesh":
        mesh = ("nerf", "export", run, "--mesh", f"{name}.glb", "--faces", MESH_FACES)
        if capture.object:
            # An object in a box: marching cubes on the field's own density, no depth fused.
            return Plan(MESH, "A game engine wants triangles: train the hash-grid field, then mesh its density "
                        "(marching cubes), decimated and coloured, written as GLB: for an object in a box this is "
                        "at least as close to the true surface as fused depth (0.43 % against 0.48 % of the "
                        "diagonal, Chamfer, on the geometry benchmark's textured cube) in less time (41 s against "
                        "59 s): it renders the training views only coarsely, to fill what they do not see",
                        [*steps, ngp, _pf(*mesh, "--method", "density")], notes=notes)
        return Plan(MESH, "A game engine wants triangles: train the hash-grid field, then fuse its rendered depth "
                    "into a decimated, coloured mesh (TSDF, marching cubes) written as GLB",
                    [*steps, ngp, _pf(*mesh)], notes=notes)
    export = _pf("nerf", "export", run, "--cloud", cloud)
    if task == "measure":
        notes.append("poses from structure from motion (and most datasets' poses) fix the scene only up to scale: "
                     "multiply by a known length over its length in the cloud before reading metres")
        return Plan(POINT_CLOUD, "Measuring wants explicit points: reconstruct with the hash-grid field, then "
                    "back-project its rendered depth into a cloud", [*steps, ngp, export, _pf("cloud", "info", cloud)],
                    notes=notes)
    if task in ("classify", "segment"):
        notes.append(f"DATA: labelled clouds for the {task} model")
        return Plan(POINT_CLOUD, "PointNet works on points: reconstruct, export the geometry as a cloud, then "
                    f"{task} it like any scan",
                    [*steps, ngp, export, _pf(task, "train", "DATA", "--out", f"runs/{task}"),
                     _predict(task, f"runs/{task}", cloud)], notes=notes)
    if task == "collision":
        notes.append(f"voxel side {VOXEL} in the scene's units, which structure from motion leaves unscaled")
        return Plan(VOXELS, "A planner asks whether a cell is free: reconstruct, export a cloud, and keep one point "
                    "per occupied voxel", [*steps, ngp, export],
                    _voxel_python(f"pointfield.read({cloud!r})", f"{name}-voxels.npz"), notes)
    if task == "novel-views":
        why = ("an object on a transparent background, where the hash grid is the most accurate (lego: 32.7 against "
               "splats' 30.1 dB)" if capture.object else "no sparse points to start splats from")
        return Plan(RADIANCE_FIELD, f"New views from a radiance field: {why}",
                    [*steps, ngp, _pf("nerf", "render", run, "--path", "orbit", "--out", f"{name}.gif")], notes=notes)
    return Plan(RADIANCE_FIELD, "Photos hold appearance, not geometry: a radiance field fits them -- the hash-grid "
                "field in minutes on a CPU -- then renders any view and yields depth, clouds and meshes",
                [*steps, ngp, _pf("nerf", "eval", run),
                 _pf("nerf", "render", run, "--path", "orbit", "--out", f"{name}.gif")],
                notes=notes)


# -- runs ----------------------------------------------------------------------------------------


def _run(given: Input, task: str | None) -> Plan:
    details, source, name = given.details, str(given.path), _name(given.path)
    notes = [] if details["finished"] else [
        "the run has no metrics.json: still training or stopped; its train command with --resume continues it"]
    if details["task"] in ("classify", "segment"):
        verb = details["task"]
        if task not in (None, verb):
            notes.append(f"this run {_DOES[verb]} clouds; for {task}, route the data instead")
        return Plan(POINT_CLOUD, f"A trained {details['model']} {verb} run: score it on its test data, then apply it "
                    "to any cloud or mesh", [_pf(verb, "eval", source), _predict(verb, source, "FILE")],
                    notes=[*notes, f"FILE: the clouds or meshes to {verb}"])
    group = "nerf" if details["task"] == "nerf" else "splat"
    cloud = f"{name}-cloud.ply"
    export = _pf(group, "export", source, "--cloud", cloud)
    if task == "mesh":
        return Plan(MESH, "A trained scene model gives a mesh: its rendered depth fused into a TSDF, marching cubes, "
                    "decimated", [_pf(group, "export", source, "--mesh", f"{name}.glb", "--faces", MESH_FACES)],
                    notes=notes)
    if task == "measure":
        return Plan(POINT_CLOUD, "Measuring wants explicit points: back-project the run's rendered depth into a cloud",
                    [export, _pf("cloud", "info", cloud)],
                    notes=[*notes, "scene units are the poses' units: scale by a known length before reading metres"])
    if task in ("classify", "segment"):
        return Plan(POINT_CLOUD, f"PointNet works on points: export the run's geometry as a cloud, then {task} it",
                    [export, _pf(task, "train", "DATA", "--out", f"runs/{task}"),
                     _predict(task, f"runs/{task}", cloud)],
                    notes=[*notes, f"DATA: labelled clouds for the {task} model"])
    if task == "collision":
        return Plan(VOXELS, "A planner asks whether a cell is free: export the run's geometry as a cloud and keep one "
                    "point per occupied voxel", [export],
                    _voxel_python(f"pointfield.read({cloud!r})", f"{name}-voxels.npz"),
                    [*notes, f"voxel side {VOXEL} in the scene's units"])
    if group == "splat":
        return Plan(SPLATS, "A trained splat run: look at it, export the standard .ply that every splat viewer "
                    "reads, and render it along a path",
                    [_pf("view", source), _pf("splat", "export", source, "--out", f"{name}.ply"),
                     _pf("splat", "render", source, "--path", "orbit", "--out", f"{name}.gif")], notes=notes)
    if task == "realtime":
        scene = [details["scene"]] if details["scene"] else []
        options = [*(["--downscale", details["downscale"]] if (details.get("downscale") or 1) > 1 else []),
                   *(["--holdout-every", details["holdout_every"]] if details.get("holdout_every") else [])]
        splat_run = f"runs/{name}-splats"
        return Plan(SPLATS, "Real-time viewing wants splats, which rasterise, where a radiance field marches rays: "
                    "train them on the same scene", [_pf("splat", "train", *scene, *options, "--out", splat_run),
                                                     _pf("splat", "export", splat_run, "--out", f"{name}-splats.ply"),
                                                     _pf("view", f"{name}-splats.ply")], notes=notes)
    if details["model"] in _RENDER_SECONDS:
        notes.append(f"the hash-grid field renders a 100 x 100 view in 0.1 s, {_RENDER_SECONDS[details['model']]} "
                     "(benchmarks/RESULTS.md): train with --model ngp for speed")
    return Plan(RADIANCE_FIELD, f"A trained radiance field ({details['model']}): score its held-out views, render it "
                "along a path (colour, depth, opacity), or look around it in the browser",
                [_pf("nerf", "eval", source), _pf("nerf", "render", source, "--path", "orbit", "--out", f"{name}.gif"),
                 _pf("view", source)], notes=notes)


_DOES = {"classify": "classifies", "segment": "segments"}

_RENDER_SECONDS = {"tiny": "TinyNeRF in 1.9 s", "nerf": "NeRF in 46.6 s"}
"""One 100 x 100 lego view, 2 CPU cores (benchmarks/RESULTS.md), of the models slower than ngp."""

_RULES = {"cloud": _cloud, "mesh": _mesh, "splats": _splats, "clouds": _clouds, "photos": _captured,
          "video": _captured, "scene": _captured, "run": _run}


# -- helpers -------------------------------------------------------------------------------------


def _pf(*words: Any) -> str:
    """A pointfield command line, each word quoted for a POSIX shell where it needs it."""
    return "pointfield " + " ".join(shlex.quote(str(word)) for word in words)


def _predict(task: str, run: str, *files: Any) -> str:
    """``classify predict`` prints; ``segment predict`` writes labelled clouds, here into ``labelled/``."""
    return _pf(task, "predict", run, *files, *(["--out", "labelled"] if task == "segment" else []))


def _name(path: Path) -> str:
    """A short name for outputs: the file's stem, or the folder's name (its parent's for ``sparse/0``, ``images``)."""
    path = Path(os.path.abspath(path))
    if not path.is_dir():
        return re.sub(r"[^A-Za-z0-9_.-]+", "-", path.stem).strip("-.") or "input"
    name = path.name
    while (name.isdigit() or name in ("sparse", "text", "images")) and path.parent != path:
        path = path.parent
        name = path.name
    return re.sub(r"[^A-Za-z0-9_.-]+", "-", name).strip("-.") or "input"


def _training_options(width: int | None, height: int | None, held_out: bool) -> list[str]:
    options = []
    if width and height:
        factor = 1
        while max(width, height) / factor > TRAINING_SIDE and factor < 8:
            factor *= 2
        if factor > 1:
            options += ["--downscale", str(factor)]
    if not held_out:
        options += ["--holdout-every", str(HOLDOUT_EVERY)]
    return options


def _voxel_python(cloud: str, out: str) -> list[str]:
    return [
        "import pointfield",
        "from pointfield.volumes import voxelize_cloud, write_voxels",
        f"grid = voxelize_cloud({cloud}, {VOXEL})  # the occupied voxels, with their point counts",
        f"write_voxels({out!r}, grid)",
    ]


def _has_normals(details: dict[str, Any]) -> bool:
    fields = {name.lower() for name in details.get("fields", [])}
    return "normals" in fields or {"nx", "ny", "nz"} <= fields or {"normal_x", "normal_y", "normal_z"} <= fields


def _is_scene_scale(details: dict[str, Any]) -> bool:
    """A lidar sweep, an organised depth frame or an aerial tile rather than one object."""
    points = details.get("points") or details.get("points_estimate") or 0
    return points > 100_000 or bool(details.get("organised")) or details["format"] in ("las", "velodyne")


def _points_text(details: dict[str, Any]) -> str:
    points = details.get("points") or details.get("points_estimate")
    return f"{points:,} points" if points else "many points"


def _modelnet_root(path: Path) -> Path | None:
    """The ``ModelNet10`` / ``ModelNet40`` folder above a file laid out as ModelNet is, if any."""
    for parent in path.parents:
        if re.fullmatch(r"modelnet\d+", parent.name.lower()):
            return parent
    return None
