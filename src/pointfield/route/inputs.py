"""What the router was given: each path inspected cheaply -- headers, names and sizes.

==========  ================================================================  =========================
kind        what                                                              found by
==========  ================================================================  =========================
``cloud``   one point-cloud file (PLY, PCD, LAS/LAZ, E57, XYZ/PTS, NPY, ...)  the format registry
``mesh``    one file with faces (PLY, OFF)                                    its face count
``splats``  a Gaussian-splat ``.ply`` (``f_dc_*``, ``opacity``, ``scale_*``)  its vertex properties
``clouds``  a folder of clouds / meshes (one subfolder per class), or files   ``CloudFolder``'s layouts
``photos``  photos without poses: image files, or a folder of them            their suffixes
``video``   a video file                                                      its suffix (and ffmpeg)
``scene``   a posed-image dataset: Blender, nerfstudio, LLFF, COLMAP, npz     the scene format registry
``run``     a run folder: classify, segment, nerf or splat                    ``config.json``'s task
==========  ================================================================  =========================

Files with a header (PLY, PCD, LAS / LAZ, E57, NPY, NPZ) are described from it alone, and a
``.bin`` scan from its size and a sample of its values (KITTI's 4 columns or nuScenes' 5), so a
100-million-point file costs what its first kilobytes cost.
Text formats (XYZ / PTS / TXT, PTX, OFF) are read whole only up to
:data:`FULL_READ_LIMIT`; beyond it their points are estimated from the first lines.
``details["read"]`` says which was done: ``"header"``, ``"size"``, ``"whole file"`` or
``"estimate"``.
"""

from __future__ import annotations

import math
import os
import warnings
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import laspy
from PIL import Image

from pointfield.clouds.cloud import Records
from pointfield.clouds.datasets.folder import discover
from pointfield.clouds.datasets.modelnet import modelnet_source
from pointfield.clouds.formats import format_of, read
from pointfield.clouds.formats.e57.layout import check_file_header
from pointfield.clouds.formats.e57.library import library_errors as e57_errors
from pointfield.clouds.formats.e57.library import load_pye57
from pointfield.clouds.formats.las.layout import check_layout
from pointfield.clouds.formats.las.library import library_errors as las_errors
from pointfield.clouds.formats.npy import POINT_KEYS, read_array_header
from pointfield.clouds.formats.npz import (
    METADATA_KEY,
    points_members,
    read_member_headers,
)
from pointfield.clouds.formats.pcd import header as pcd_header
from pointfield.clouds.formats.ply import header as ply_header
from pointfield.clouds.formats.velodyne import LAYOUT_NAMES, guess_columns
from pointfield.clouds.mesh import Mesh
from pointfield.errors import FormatError, PointfieldError
from pointfield.runs import RUN_CLASSES
from pointfield.scenes.formats import detect_scene_format, read_scene
from pointfield.scenes.tools import describe_scene
from pointfield.training.run import RunDirectory, read_json

KINDS = ("cloud", "mesh", "splats", "clouds", "photos", "video", "scene", "run")

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp", ".webp")
VIDEO_SUFFIXES = (".mp4", ".mov", ".m4v", ".avi", ".mkv", ".webm", ".mts")

FULL_READ_LIMIT = 64 << 20
"""Text files (XYZ / PTS / TXT, PTX, OFF) up to this many bytes are read whole to describe them."""

ESTIMATE_BYTES = 1 << 20
"""Bytes of a larger headerless file whose lines estimate its number of points."""

RUN_SCORES = ("psnr", "ssim", "accuracy", "miou", "steps", "epochs")
"""What a run's ``metrics.json`` holds that the router reports."""

VELODYNE_FIELDS = {4: ["x", "y", "z", "intensity"], 5: ["x", "y", "z", "intensity", "ring"]}
"""KITTI's and nuScenes' layouts, the two :func:`~pointfield.clouds.formats.velodyne.guess_columns` tells apart."""


@dataclass(frozen=True)
class Input:
    """What the router was given: its ``kind`` (one of :data:`KINDS`), paths and ``details``.

    ``details`` is JSON-ready; which keys it has depends on the kind (``points``, ``fields``,
    ``format``, ``frames``, ``task``, ...). :meth:`describe` is one line for people.
    """

    kind: str
    paths: tuple[Path, ...]
    details: dict[str, Any]

    @property
    def path(self) -> Path:
        """The first (usually the only) path."""
        return self.paths[0]

    def describe(self) -> str:
        return _DESCRIBE[self.kind](self.details)


def inspect_inputs(paths: Sequence[str | os.PathLike[str]]) -> Input:
    """One :class:`Input` for everything given: a path, or several files of one kind.

    Several photos become one ``photos`` input and several cloud or mesh files one ``clouds``
    input; anything else mixed is a :class:`PointfieldError` naming what each path is.
    """
    if not paths:
        raise PointfieldError("route needs at least one input: a file or a folder")
    inputs = [inspect_path(path) for path in paths]
    if len(inputs) == 1:
        return inputs[0]
    kinds = [item.kind for item in inputs]
    files = all(item.path.is_file() for item in inputs)
    if files and set(kinds) == {"photos"}:
        return _photos([item.path for item in inputs], folder=None)
    if files and set(kinds) <= {"cloud", "mesh"}:
        return Input("clouds", tuple(item.path for item in inputs), {
            "files": len(inputs), "classes": [], "splits": [],
            "formats": sorted({item.details["format"] for item in inputs}),
            "meshes": kinds.count("mesh"), "inputs": [item.details for item in inputs],
        })
    described = ", ".join(f"{item.path} is {_ARTICLE[item.kind]}" for item in inputs)
    raise PointfieldError(f"route takes one kind of input at a time (photos, or clouds and meshes): {described}")


def inspect_path(path: str | os.PathLike[str]) -> Input:
    """The :class:`Input` of one file or folder, from its headers, names and size."""
    path = Path(path)
    if not path.exists():
        raise PointfieldError(f"{path}: no such file or folder")
    if path.is_dir():
        return _folder(path)
    suffix = path.suffix.lower()
    if suffix in VIDEO_SUFFIXES:
        return _video(path)
    if suffix in IMAGE_SUFFIXES:
        return _photos([path], folder=None)
    if suffix == ".json" or path.name == "poses_bounds.npy" or (suffix == ".npz" and _is_npz_scene(path)):
        return _scene(path)
    return _cloud_file(path)


# -- point-cloud files ---------------------------------------------------------------------------


def _cloud_file(path: Path) -> Input:
    try:
        fmt = format_of(path)
    except FormatError as error:
        raise PointfieldError(
            f"{path}: pointfield cannot identify this file: {error.reason}; nor is it a photo "
            f"({', '.join(IMAGE_SUFFIXES)}), a video ({', '.join(VIDEO_SUFFIXES)}) or a scene's "
            f"transforms.json"
        ) from None
    details: dict[str, Any] = {"path": str(path), "bytes": path.stat().st_size, "format": fmt.name}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        described = _HEADER_READERS.get(fmt.name, _headerless)(path)
    details.update(described)
    kind = details.pop("kind")
    if kind == "records":
        raise PointfieldError(
            f"{path}: holds records without x, y, z coordinates ({', '.join(details['fields'][:6])}): "
            f"no geometry to route"
        )
    return Input(kind, (path,), details)


def _ply(path: Path) -> dict[str, Any]:
    with open(path, "rb") as file:
        header = ply_header.parse_header(path, file.read(ply_header.HEADER_LIMIT))
    elements = {element.name: element for element in header.elements}
    vertex, face = elements.get("vertex"), elements.get("face")
    names = [prop.name for prop in vertex.properties] if vertex else []
    faces = face.count if face else 0
    details: dict[str, Any] = {"encoding": header.encoding, "points": vertex.count if vertex else 0,
                               "faces": faces, "organised": None, "fields": names, "read": "header"}
    if not {"x", "y", "z"} <= set(names):
        details["kind"] = "records"
    elif set(ply_header.SPLAT_PROPERTIES) <= set(names):
        rest = sum(name.startswith("f_rest_") for name in names)
        details.update(kind="splats", sh_degree=round(math.sqrt(rest // 3 + 1)) - 1)
    else:
        details["kind"] = "mesh" if faces else "cloud"
    return details


def _pcd(path: Path) -> dict[str, Any]:
    with open(path, "rb") as file:
        header = pcd_header.parse_header(file.read(pcd_header.MAX_HEADER_BYTES), path)
    names = [field.name for field in header.fields if not field.is_padding]
    return {
        "kind": "cloud" if {"x", "y", "z"} <= {name.lower() for name in names} else "records",
        "encoding": header.encoding, "points": header.points, "faces": 0,
        "organised": [header.height, header.width] if header.height > 1 else None,
        "fields": names, "read": "header",
    }


def _las(path: Path) -> dict[str, Any]:
    with open(path, "rb") as file:
        layout = check_layout(path, file, path.stat().st_size)
    with las_errors(path, "laspy could not read its header"), laspy.open(path) as reader:
        header = reader.header
        return {
            "kind": "cloud", "encoding": "laz" if layout.compressed else "las", "points": layout.point_count,
            "faces": 0, "organised": None, "fields": list(header.point_format.dimension_names),
            "version": str(header.version), "point_format": layout.point_format,
            "bounds": {"min": [float(v) for v in header.mins], "max": [float(v) for v in header.maxs]},
            "read": "header",
        }


def _e57(path: Path) -> dict[str, Any]:
    pye57 = load_pye57(path)
    check_file_header(path, path.stat().st_size)
    with e57_errors(path, "libE57 could not read its header"):
        e57 = pye57.E57(str(path), mode="r")
        try:  # a scan header reads the file's XML lazily: everything is taken before closing it
            scans = [(int(header.point_count), list(header.point_fields))
                     for header in map(e57.get_header, range(e57.scan_count))]
        finally:
            e57.close()
    fields = list(dict.fromkeys(name for _, names in scans for name in names))
    return {
        "kind": "cloud", "encoding": "e57", "points": sum(count for count, _ in scans),
        "faces": 0, "scans": len(scans), "fields": fields, "read": "header",
        # A structured (gridded) scan stores each point's row and column: an organised cloud.
        "organised": "rows and columns" if {"rowIndex", "columnIndex"} <= set(fields) else None,
    }


def _npy(path: Path) -> dict[str, Any]:
    with open(path, "rb") as file:
        header = read_array_header(file, path)
    return _array_details(header.shape, header.dtype.names or ())


def _npz(path: Path) -> dict[str, Any]:
    headers = read_member_headers(path)
    found = points_members(headers)  # the points member, or the x, y and z members
    if not found:
        raise FormatError(path, f"an archive of {', '.join(sorted(headers)) or 'no arrays'}: no points "
                                f"(a member named {' / '.join(POINT_KEYS)}, or x, y, z), and not a scene "
                                f"(images, poses, focal)")
    points = found if len(found) == 1 else ()  # x, y and z members are listed among the fields
    fields = [name for name in headers if name not in (*points, METADATA_KEY)]
    return {**_array_details(headers[found[0]].shape, fields), "encoding": None}


def _array_details(shape: tuple[int, ...], names: Sequence[str]) -> dict[str, Any]:
    return {"kind": "cloud", "points": shape[0] if shape else 0, "faces": 0, "organised": None,
            "fields": list(names) or [f"{shape[-1] if len(shape) > 1 else 1} columns"], "read": "header"}


def _velodyne(path: Path) -> dict[str, Any]:
    columns = guess_columns(path)  # from the size, a sample of the values and the name; FormatError if neither
    return {"kind": "cloud", "encoding": "float32", "points": path.stat().st_size // (4 * columns), "faces": 0,
            "organised": None, "fields": VELODYNE_FIELDS[columns], "columns": columns, "read": "size"}


def _headerless(path: Path) -> dict[str, Any]:
    """Text formats: read whole when small, else the points estimated from the first lines."""
    size = path.stat().st_size
    if size > FULL_READ_LIMIT:
        with open(path, "rb") as file:
            head = file.read(ESTIMATE_BYTES)
        lines = head.count(b"\n")
        return {"kind": "cloud", "points": None, "points_estimate": size * lines // len(head) if lines else None,
                "faces": 0, "organised": None, "fields": [], "read": "estimate"}
    cloud = read(path)
    if isinstance(cloud, Records):
        return {"kind": "records", "fields": list(cloud.fields), "read": "whole file"}
    faces = len(cloud.faces) if isinstance(cloud, Mesh) else 0
    return {
        "kind": "mesh" if faces else "cloud", "encoding": cloud.metadata.get("encoding"), "points": len(cloud),
        "faces": faces, "organised": list(cloud.shape) if cloud.shape else None,
        "fields": ["x", "y", "z", *cloud.fields], "read": "whole file",
    }


_HEADER_READERS = {"ply": _ply, "pcd": _pcd, "las": _las, "e57": _e57, "npy": _npy, "npz": _npz,
                   "velodyne": _velodyne}


# -- folders, photos, video, scenes, runs --------------------------------------------------------


def _folder(path: Path) -> Input:
    run = RunDirectory(path)
    if run.exists():
        settings = run.read_config()
        if isinstance(settings, dict) and "task" in settings:
            return _run(run, settings)
    try:
        detect_scene_format(path)
    except FormatError:
        pass
    else:
        return _scene(path)
    photos = _images_in(path)
    if photos:
        return _photos(photos, folder=path)
    found = discover(path)
    source = modelnet_source(path)
    if found or source == "h5":
        return _clouds(path, found, source)
    raise PointfieldError(
        f"{path}: pointfield cannot identify this folder: it holds no run (config.json), no posed "
        f"dataset (transforms.json, transforms_train.json, poses_bounds.npy, a COLMAP model), no "
        f"photos and no point-cloud or mesh files"
    )


def _images_in(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir()
                  if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith("."))


def _photos(files: list[Path], folder: Path | None) -> Input:
    details: dict[str, Any] = {"folder": None if folder is None else str(folder), "photos": len(files),
                               "width": None, "height": None}
    try:
        with Image.open(files[0]) as image:  # reads the header only
            details["width"], details["height"] = image.size
    except (OSError, ValueError) as error:
        raise PointfieldError(f"{files[0]}: not a readable image ({error})") from None
    return Input("photos", (folder,) if folder is not None else tuple(files), details)


def _video(path: Path) -> Input:
    details: dict[str, Any] = {"path": str(path), "bytes": path.stat().st_size, "width": None, "height": None,
                               "seconds": None, "fps": None}
    try:
        import imageio_ffmpeg  # the `video` extra: without it the clip is named, not probed
    except ImportError:
        return Input("video", (path,), details)
    frames = imageio_ffmpeg.read_frames(str(path))
    try:
        meta = next(frames)  # ffmpeg's probe of the container: no frame is decoded
    except (OSError, RuntimeError, StopIteration) as error:
        raise PointfieldError(f"{path}: not a video ffmpeg can read ({str(error).strip().splitlines()[-1:]})") from None
    finally:
        frames.close()
    width, height = meta.get("size") or (None, None)
    details.update(width=width, height=height, seconds=meta.get("duration"), fps=meta.get("fps"))
    return Input("video", (path,), details)


def _is_npz_scene(path: Path) -> bool:
    try:
        with zipfile.ZipFile(path) as archive:
            names = {name.removesuffix(".npy") for name in archive.namelist()}
    except (zipfile.BadZipFile, OSError):
        return False
    return {"images", "poses", "focal"} <= names


def _scene(path: Path) -> Input:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # frames whose images are missing: counted in the details
        scene = read_scene(path)
    info = describe_scene(scene)
    details = {key: info[key] for key in ("format", "frames", "frames_listed", "splits", "camera_model", "points")}
    details["path"] = str(path)
    # Cameras of several sizes list them per frame: the largest decides the downscale.
    details["width"], details["height"] = (max(v) if isinstance(v, list) else v
                                           for v in (info["width"], info["height"]))
    details["object"] = _has_alpha(scene)
    return Input("scene", (path,), details)


def _has_alpha(scene) -> bool:
    """Whether the first view with an image has an alpha channel: an object on a transparent background."""
    frame = next((frame for frame in scene.frames if frame.has_image), None)
    if frame is None:
        return False
    if frame.image is not None:
        return frame.image.ndim == 3 and frame.image.shape[-1] in (2, 4)
    with Image.open(frame.image_path) as image:
        return image.mode in ("RGBA", "LA", "PA") or "transparency" in image.info


def _run(run: RunDirectory, config: dict[str, Any]) -> Input:
    path, task = run.path, config["task"]
    known = [name for run_class in RUN_CLASSES for name in run_class.tasks]
    if task not in known:
        raise PointfieldError(f"{path}: a run of task {task!r}, which pointfield does not open ({', '.join(known)})")
    metrics = read_json(run.final_metrics) if run.final_metrics.is_file() else {}
    details: dict[str, Any] = {
        "path": str(path), "task": task, "model": config.get("model", "splats" if task == "splat" else task),
        "finished": bool(metrics), "scene": config.get("scene"), "data": config.get("data"),
        "downscale": config.get("downscale"), "holdout_every": config.get("holdout_every"),
        # NaN (an SSIM of images too small for its window) is not JSON: None instead.
        "metrics": {key: None if isinstance(value, float) and not math.isfinite(value) else value
                    for key, value in metrics.items() if key in RUN_SCORES},
    }
    return Input("run", (path,), details)


def _clouds(path: Path, found: list[tuple[Path, str | None, str | None]], source: str) -> Input:
    suffixes = sorted({file.suffix.lower() for file, _, _ in found})
    return Input("clouds", (path,), {
        "path": str(path), "files": len(found), "classes": sorted({name for _, name, _ in found if name}),
        "splits": sorted({split for _, _, split in found if split}), "formats": suffixes,
        "modelnet": source if source == "h5" or path.name.lower().startswith("modelnet") else None,
        "first": str(found[0][0]) if found else None,
    })


# -- one line each -------------------------------------------------------------------------------


def _count(value: Any, noun: str) -> str:
    return f"{value:,} {noun}" if isinstance(value, int) else f"? {noun}"


def _describe_cloud(details: dict[str, Any], noun: str = "points") -> str:
    if details.get("points") is not None:
        points = _count(details["points"], noun)
    elif details.get("points_estimate"):
        points = f"about {details['points_estimate']:,} points"
    else:
        points = "points not counted"
    parts = [_format_text(details), points]
    if details.get("faces"):
        parts.append(_count(details["faces"], "faces"))
    organised = details.get("organised")
    if organised:
        parts.append("organised " + (" x ".join(map(str, organised)) if isinstance(organised, list) else organised))
    if details.get("sh_degree") is not None:
        parts.append(f"SH degree {details['sh_degree']}")
    fields = details.get("fields") or []
    shown = " ".join(fields[:12]) + (f" ... ({len(fields)})" if len(fields) > 12 else "")
    return ", ".join(parts) + (f"; fields {shown}" if fields else "")


def _format_text(details: dict[str, Any]) -> str:
    """``PCD binary_compressed``, ``LAZ 1.2``, ``PTS``, ``E57 (2 scans)``, ``KITTI .bin (float32 x y z intensity)``."""
    name, encoding = details["format"], details.get("encoding")
    if name == "las":
        return f"{encoding.upper()} {details['version']}, point format {details['point_format']}"
    if name == "text":
        return Path(details["path"]).suffix[1:].upper()
    if name == "velodyne":
        return f"raw float32 .bin ({LAYOUT_NAMES[details['columns']]})"
    if name == "e57":
        return f"E57, {details['scans']} scan{'s' if details['scans'] != 1 else ''}"
    return name.upper() + (f" {encoding}" if encoding and name in ("ply", "pcd") else "")


def _describe_clouds(details: dict[str, Any]) -> str:
    text = f"{details['files']:,} cloud / mesh files ({', '.join(details['formats'])})"
    if details.get("classes"):
        text += f", {len(details['classes'])} classes ({', '.join(details['classes'][:8])}"
        text += ", ...)" if len(details["classes"]) > 8 else ")"
    if details.get("splits"):
        text += f", splits {' '.join(details['splits'])}"
    return text


def _describe_photos(details: dict[str, Any]) -> str:
    size = f", {details['width']} x {details['height']}" if details.get("width") else ""
    return f"{details['photos']:,} photos without poses{size}"


def _describe_video(details: dict[str, Any]) -> str:
    parts = [f"{details['bytes']:,} bytes"]
    if details.get("width"):
        parts.append(f"{details['width']} x {details['height']}")
    if details.get("seconds"):
        parts.append(f"{details['seconds']:.1f} s at {details['fps']:g} fps")
    return "video, " + ", ".join(parts)


def _describe_scene(details: dict[str, Any]) -> str:
    splits = ", ".join(f"{name} {count}" for name, count in details["splits"].items())
    text = (f"{details['format']} scene, {details['frames']} posed views ({splits}), "
            f"{details['width']} x {details['height']}, {details['camera_model']}")
    if details["points"]:
        text += f", {details['points']:,} sparse points"
    return text + (", an object on a transparent background" if details["object"] else "")


def _describe_run(details: dict[str, Any]) -> str:
    scores = ", ".join(f"{key} {value:.4g}" if isinstance(value, float) else f"{key} {value}"
                       for key, value in details["metrics"].items() if value is not None)
    state = f"finished: {scores}" if details["finished"] else "not finished (no metrics.json)"
    what = "splat run" if details["task"] == "splat" else f"{details['task']} run of {details['model']}"
    return f"{what}, {state}"


_DESCRIBE = {
    "cloud": lambda d: "point cloud, " + _describe_cloud(d),
    "mesh": lambda d: "mesh, " + _describe_cloud(d),
    "splats": lambda d: "Gaussian splats, " + _describe_cloud(d, "splats"),
    "clouds": _describe_clouds,
    "photos": _describe_photos,
    "video": _describe_video,
    "scene": _describe_scene,
    "run": _describe_run,
}

_ARTICLE = {"cloud": "a point cloud", "mesh": "a mesh", "splats": "Gaussian splats", "clouds": "a folder of clouds",
            "photos": "a photo", "video": "a video", "scene": "a posed dataset", "run": "a run folder"}
