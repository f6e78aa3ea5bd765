"""nerfstudio / instant-ngp ``transforms.json``, and the frame parser the Blender format shares.

The file (one JSON object)::

    {"camera_model": "OPENCV",                  # or OPENCV_FISHEYE; instant-ngp: "is_fisheye"
     "fl_x": 1375.5, "fl_y": 1374.5,            # or "camera_angle_x" / "camera_angle_y" (radians)
     "cx": 554.6, "cy": 965.3, "w": 1080, "h": 1920,
     "k1": 0.058, "k2": -0.081, "p1": -0.001, "p2": 0.0002,   # k3; fisheye: k1..k4
     "aabb_scale": 4,                           # instant-ngp
     "frames": [{"file_path": "images/0001.jpg",
                 "transform_matrix": [[...4 numbers...] x 4]}, ...],
     "train_filenames": [...], "test_filenames": [...],        # optional nerfstudio splits
     "ply_file_path": "sparse_pc.ply"}          # optional sparse points, same world frame

Intrinsics and distortion may sit at the top level (shared) or in each frame (a frame's value
wins). ``transform_matrix`` is camera-to-world in the **OpenGL** convention (x right, y up,
looking down -z); the reader converts it to pointfield's OpenCV convention,
``c2w_cv = c2w_gl @ diag(1, -1, -1, 1)``, and the writer converts back.

Image paths are relative to the JSON file's folder; a ``file_path`` without a file behind it
gets ".png" appended (Blender writes them extension-less). Frames whose image is missing are
skipped with one warning that counts them (instant-ngp's fox lists 67 frames, ships 50 images).
When the file declares no image size, the images' own headers give it, and they must agree.

pointfield extensions, ignored by other tools: per-frame ``depth_file_path`` (z-depth,
nerfstudio's key; multiplied by top-level ``depth_unit_scale_factor``, default 1 for ``.npy``
and 0.001 -- millimetres -- for PNG, as in nerfstudio) and ``object_mask_path`` (True on objects;
deliberately not nerfstudio's ``mask_path``, whose zeros mean "ignore this pixel in the loss");
``near`` / ``far`` (top level or per frame) and ``aabb`` ``[[min xyz], [max xyz]]``.
instant-ngp's ``aabb_scale`` becomes ``scene.aabb`` in world units:
``(0.5 -+ aabb_scale / 2 - offset) / scale`` with its defaults scale 0.33, offset 0.5.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.formats import read, write
from pointfield.errors import FormatError
from pointfield.scenes.cameras import CAMERA_MODELS, Cameras, opencv_to_opengl, opengl_to_opencv
from pointfield.scenes.formats.export import export_frame, unique_stem
from pointfield.scenes.formats.registry import SceneFormat, register
from pointfield.scenes.formats.validation import (
    MissingImage,
    image_side,
    image_size,
    keep_frames,
    load_json,
    number,
    pose_matrix,
)
from pointfield.scenes.scene import Frame, Scene

FISHEYE_MODELS = {"OPENCV_FISHEYE", "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE"}
PERSPECTIVE_MODELS = {"SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "PERSPECTIVE"}
DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")
INSTANT_NGP_SCALE = 0.33
INSTANT_NGP_OFFSET = 0.5
SPLIT_NAMES = ("train", "val", "test")


@dataclass
class _FrameRecord:
    """What one JSON frame says, before intrinsics that depend on the image size are resolved."""

    source: Path
    index: int
    name: str
    split: str | None
    pose: np.ndarray
    values: dict[str, Any]
    image_path: Path | None
    declared_size: tuple[int, int] | None
    image_size: tuple[int, int] | None
    depth_path: Path | None = None
    depth_scale: float = 1.0
    mask_path: Path | None = None
    near_far: tuple[float, float] | None = None


@dataclass
class ParsedFrames:
    """Frames of one or more transforms files, cameras in the OpenCV convention."""

    cameras: Cameras
    frames: list[Frame]
    frame_splits: list[str | None]
    near_far: np.ndarray | None
    listed: int


def parse_transforms(
    sources: list[tuple[str | None, Path, dict[str, Any]]], missing_images: str, folder: Path
) -> ParsedFrames:
    """Parse the frames of ``(split, json_path, document)`` sources into cameras and frames.

    Applies the missing-image policy over all sources together (one warning), checks image sizes
    against declared ones (or against each other when none is declared) and that all kept frames
    use one camera model.
    """
    records: list[_FrameRecord] = []
    for split, json_path, document in sources:
        records.extend(_frame_records(split, json_path, document))
    if not records:
        raise FormatError(sources[0][1] if sources else folder, "lists no frames")
    missing = [
        MissingImage(r.source, r.index, r.name, r.image_path or r.source.parent / r.name)
        for r in records
        if r.image_size is None
    ]
    keep = keep_frames([r.image_size is not None for r in records], missing, missing_images, folder)
    kept = [r for r, k in zip(records, keep) if k]
    common_size = _common_image_size(kept)
    fisheye = [_is_fisheye(r) for r in kept]
    if kept and any(f != fisheye[0] for f in fisheye):
        odd = kept[fisheye.index(not fisheye[0])]
        raise FormatError(
            odd.source, f"frame {odd.index} ({odd.name}): mixes fisheye and perspective cameras in one scene"
        )
    model_kind = "OPENCV_FISHEYE" if kept and fisheye[0] else "OPENCV"
    rows = [_intrinsics(r, common_size, model_kind) for r in kept]
    distortion = np.array([row[6] for row in rows], dtype=np.float64).reshape(
        len(rows), len(CAMERA_MODELS[model_kind])
    )
    if model_kind == "OPENCV" and not np.any(distortion):
        model_kind, distortion = "PINHOLE", np.zeros((len(rows), 0))
    poses = np.stack([r.pose for r in kept]) if kept else np.zeros((0, 3, 4))
    cameras = Cameras(
        torch.from_numpy(poses),
        [row[0] for row in rows],
        [row[1] for row in rows],
        [row[2] for row in rows],
        [row[3] for row in rows],
        [row[4] for row in rows],
        [row[5] for row in rows],
        model_kind,
        torch.from_numpy(distortion),
    )
    frames = [
        Frame(
            r.name,
            r.image_path if r.image_size else None,
            depth_path=r.depth_path,
            depth_scale=r.depth_scale,
            mask_path=r.mask_path,
        )
        for r in kept
    ]
    near_far = None
    if kept and all(r.near_far is not None for r in kept):
        near_far = np.array([r.near_far for r in kept], dtype=np.float64)
    return ParsedFrames(cameras, frames, [r.split for r in kept], near_far, len(records))


def _frame_records(split: str | None, json_path: Path, document: dict[str, Any]) -> list[_FrameRecord]:
    frames = document.get("frames")
    if not isinstance(frames, list):
        raise FormatError(json_path, 'expected a "frames" list')
    root = json_path.parent
    shared = {k: v for k, v in document.items() if k != "frames"}
    depth_unit = document.get("depth_unit_scale_factor")
    records = []
    for index, frame in enumerate(frames):
        if not isinstance(frame, dict):
            raise FormatError(json_path, f"frame {index}: expected an object, found {type(frame).__name__}")
        file_path = frame.get("file_path")
        if not isinstance(file_path, str) or not file_path.strip():
            raise FormatError(json_path, f'frame {index}: missing or empty "file_path"')
        where = f"frame {index} ({file_path})"
        if "transform_matrix" not in frame:
            raise FormatError(json_path, f'{where}: missing "transform_matrix"')
        pose = opengl_to_opencv(_as_4x4(pose_matrix(frame["transform_matrix"], json_path, where)))[:3]
        values = {**shared, **frame}
        image_path = resolve_image_path(root, file_path)
        size = image_size(image_path, where) if image_path is not None else None
        declared = None
        if "w" in values or "h" in values:
            if "w" not in values or "h" not in values:
                raise FormatError(json_path, f'{where}: declares only one of "w" and "h"')
            declared = (
                image_side(values["w"], json_path, f"{where}: w"),
                image_side(values["h"], json_path, f"{where}: h"),
            )
            if size is not None and size != declared:
                raise FormatError(
                    json_path,
                    f"{where}: image {image_path.name} is {size[0]}x{size[1]} "
                    f"but the file declares {declared[0]}x{declared[1]}",
                )
        record = _FrameRecord(json_path, index, file_path, split, pose, values, image_path, declared, size)
        if "depth_file_path" in frame:
            record.depth_path = _relative_path(
                root, frame["depth_file_path"], json_path, f"{where}: depth_file_path"
            )
            default_unit = 1.0 if record.depth_path.suffix.lower() == ".npy" else 1e-3
            record.depth_scale = (
                number(depth_unit, json_path, "depth_unit_scale_factor", positive=True)
                if depth_unit is not None
                else default_unit
            )
        if "object_mask_path" in frame:
            record.mask_path = _relative_path(
                root, frame["object_mask_path"], json_path, f"{where}: object_mask_path"
            )
        if "near" in values and "far" in values:
            near = number(values["near"], json_path, f"{where}: near")
            far = number(values["far"], json_path, f"{where}: far")
            if not 0 <= near < far:
                raise FormatError(
                    json_path, f"{where}: near {near} and far {far} must satisfy 0 <= near < far"
                )
            record.near_far = (near, far)
        records.append(record)
    return records


def resolve_image_path(root: Path, file_path: str) -> Path | None:
    """The image file ``file_path`` names (relative to ``root``), trying ".png" after the bare name.

    Returns the path to look for even when nothing exists there, for the missing-image report;
    None only for names that cannot be a path (NUL bytes).
    """
    if "\x00" in file_path:
        return None
    path = root / file_path
    if path.is_file() or path.suffix:
        return Path(os.path.normpath(path))
    return Path(os.path.normpath(path.with_name(path.name + ".png")))


def _relative_path(root: Path, value: Any, json_path: Path, where: str) -> Path:
    if not isinstance(value, str) or not value or "\x00" in value:
        raise FormatError(json_path, f"{where}: expected a file path")
    return Path(os.path.normpath(root / value))


def _as_4x4(pose: np.ndarray) -> np.ndarray:
    return np.concatenate([pose, [[0.0, 0.0, 0.0, 1.0]]])


def _is_fisheye(record: _FrameRecord) -> bool:
    model = record.values.get("camera_model")
    if model is not None:
        if not isinstance(model, str) or model not in FISHEYE_MODELS | PERSPECTIVE_MODELS:
            known = ", ".join(sorted(FISHEYE_MODELS | PERSPECTIVE_MODELS))
            raise FormatError(
                record.source,
                f"frame {record.index} ({record.name}): camera_model {model!r} is not supported (supported: {known})",
            )
        return model in FISHEYE_MODELS
    return record.values.get("is_fisheye") is True


def _common_image_size(records: list[_FrameRecord]) -> tuple[int, int] | None:
    """The one image size of the frames that declare none (they share a focal, so share a size)."""
    common = None
    for record in records:
        if record.declared_size is None and record.image_size is not None:
            if common is None:
                common, first = record.image_size, record
            elif record.image_size != common:
                raise FormatError(
                    record.source,
                    f"frame {record.index} ({record.name}): image is {record.image_size[0]}x{record.image_size[1]} "
                    f"but frame {first.index} ({first.name})'s is {common[0]}x{common[1]}; without declared "
                    f'"w"/"h" all images must have one size',
                )
    return common


def _intrinsics(record: _FrameRecord, common_size: tuple[int, int] | None, model: str) -> tuple:
    """``(fx, fy, cx, cy, width, height, distortion)`` of one frame."""
    where = f"frame {record.index} ({record.name})"
    path, values = record.source, record.values
    size = record.declared_size or record.image_size or common_size
    if size is None:
        raise FormatError(
            path, f'{where}: image is missing and no "w"/"h" is declared, so its size is unknown'
        )
    width, height = size
    if "fl_x" in values:
        fx = number(values["fl_x"], path, f"{where}: fl_x", positive=True)
    elif "camera_angle_x" in values:
        fx = _focal_from_angle(values["camera_angle_x"], width, path, f"{where}: camera_angle_x")
    else:
        raise FormatError(path, f'{where}: no focal length (expected "fl_x" or "camera_angle_x")')
    if "fl_y" in values:
        fy = number(values["fl_y"], path, f"{where}: fl_y", positive=True)
    elif "camera_angle_y" in values and "fl_x" not in values:
        fy = _focal_from_angle(values["camera_angle_y"], height, path, f"{where}: camera_angle_y")
    else:
        fy = fx
    cx = number(values["cx"], path, f"{where}: cx") if "cx" in values else width / 2
    cy = number(values["cy"], path, f"{where}: cy") if "cy" in values else height / 2
    k = {
        key: number(values[key], path, f"{where}: {key}") if key in values else 0.0 for key in DISTORTION_KEYS
    }
    if model == "OPENCV_FISHEYE":
        if k["p1"] or k["p2"]:
            raise FormatError(path, f"{where}: fisheye cameras have no tangential distortion (p1, p2)")
        distortion = [k["k1"], k["k2"], k["k3"], k["k4"]]
    else:
        if k["k4"]:
            raise FormatError(path, f"{where}: k4 is a fisheye coefficient but the camera is perspective")
        distortion = [k["k1"], k["k2"], k["p1"], k["p2"], k["k3"]]
    return fx, fy, cx, cy, width, height, distortion


def _focal_from_angle(angle: Any, side: int, path: Path, where: str) -> float:
    """Focal length from a field of view: ``f = 0.5 * side / tan(0.5 * angle)``."""
    angle = number(angle, path, where, positive=True)
    if angle >= math.pi:
        raise FormatError(path, f"{where}: field of view {angle} rad is not below pi")
    return 0.5 * side / math.tan(0.5 * angle)


def instant_ngp_aabb(document: dict[str, Any], path: Path) -> np.ndarray | None:
    """World-space ``(2, 3)`` box of instant-ngp's ``aabb_scale`` (see the module docstring)."""
    if "aabb_scale" not in document:
        return None
    aabb_scale = number(document["aabb_scale"], path, "aabb_scale", positive=True)
    scale = number(document.get("scale", INSTANT_NGP_SCALE), path, "scale", positive=True)
    offset = document.get("offset", INSTANT_NGP_OFFSET)
    offset = np.array(
        [number(v, path, "offset") for v in offset]
        if isinstance(offset, list)
        else [number(offset, path, "offset")] * 3
    )
    if offset.shape != (3,):
        raise FormatError(path, "offset must be one number or three")
    return np.stack([(0.5 - aabb_scale / 2 - offset) / scale, (0.5 + aabb_scale / 2 - offset) / scale])


def explicit_aabb(document: dict[str, Any], path: Path) -> np.ndarray | None:
    """pointfield's ``aabb`` key ``[[min x, y, z], [max x, y, z]]`` as ``(2, 3)``, or None."""
    if "aabb" not in document:
        return None
    value = document["aabb"]
    if (
        not isinstance(value, list)
        or len(value) != 2
        or not all(isinstance(c, list) and len(c) == 3 for c in value)
    ):
        raise FormatError(path, "aabb must be [[min x, y, z], [max x, y, z]]")
    box = np.array([[number(v, path, "aabb") for v in corner] for corner in value])
    if np.any(box[0] > box[1]):
        raise FormatError(path, f"aabb minimum {box[0].tolist()} exceeds its maximum {box[1].tolist()}")
    return box


# -- nerfstudio / instant-ngp reader and writer ---------------------------------------------------


BLENDER_FILE = re.compile(r"transforms_(train|val|test)\.json", re.IGNORECASE)


def detect_nerfstudio(path: Path) -> bool:
    if path.is_dir():
        return (path / "transforms.json").is_file()
    return path.suffix.lower() == ".json" and not BLENDER_FILE.fullmatch(path.name)


def read_nerfstudio(path: Path, missing_images: str = "skip") -> Scene:
    """Read a nerfstudio / instant-ngp ``transforms.json`` (or the folder holding one)."""
    json_path = path / "transforms.json" if path.is_dir() else path
    document = load_json(json_path)
    parsed = parse_transforms([(None, json_path, document)], missing_images, json_path)
    splits = _splits_from_filename_lists(document, json_path, parsed)
    points = None
    if "ply_file_path" in document:
        ply_path = _relative_path(json_path.parent, document["ply_file_path"], json_path, "ply_file_path")
        points = read(ply_path)
    aabb = explicit_aabb(document, json_path)
    if aabb is None:
        aabb = instant_ngp_aabb(document, json_path)
    metadata = {
        "path": str(json_path),
        "root": str(json_path.parent),
        "frames_listed": parsed.listed,
    }
    if "aabb_scale" in document:
        metadata["aabb_scale"] = document["aabb_scale"]
    return Scene(parsed.cameras, parsed.frames, splits, points, parsed.near_far, aabb, metadata=metadata)


def _splits_from_filename_lists(
    document: dict[str, Any], json_path: Path, parsed: ParsedFrames
) -> dict[str, np.ndarray]:
    """nerfstudio's ``train_filenames`` / ``val_filenames`` / ``test_filenames`` as frame indices."""
    lists = {name: document[f"{name}_filenames"] for name in SPLIT_NAMES if f"{name}_filenames" in document}
    if not lists:
        return {}
    root = json_path.parent
    position = {str(resolve_image_path(root, frame.name)): i for i, frame in enumerate(parsed.frames)}
    listed_names = {str(resolve_image_path(root, r)) for r in _all_frame_names(document)}
    splits = {}
    for name, entries in lists.items():
        if not isinstance(entries, list) or not all(isinstance(e, str) for e in entries):
            raise FormatError(json_path, f"{name}_filenames must be a list of file paths")
        indices = []
        for entry in entries:
            key = str(resolve_image_path(root, entry))
            if key in position:
                indices.append(position[key])
            elif key not in listed_names:
                raise FormatError(
                    json_path, f"{name}_filenames lists {entry!r}, which is no frame's file_path"
                )
        splits[name] = np.array(sorted(indices), dtype=np.int64)
    return splits


def _all_frame_names(document: dict[str, Any]) -> list[str]:
    return [
        f["file_path"]
        for f in document.get("frames", [])
        if isinstance(f, dict) and isinstance(f.get("file_path"), str)
    ]


def write_nerfstudio(scene: Scene, directory: Path, points_file: str = "sparse_pc.ply") -> None:
    """Write ``scene`` as ``transforms.json`` plus its images, readable by nerfstudio and instant-ngp.

    Images keep their path relative to the source dataset's folder (copied unchanged unless
    downscaled); intrinsics go at the top level when every camera shares them, else in each
    frame; splits other than a single all-frames "train" become ``<split>_filenames`` lists;
    sparse points are written to ``points_file`` (nerfstudio's ``sparse_pc.ply`` by default).
    """
    cameras = scene.cameras
    document: dict[str, Any] = {"camera_model": cameras.model}
    intrinsics = [camera_intrinsics_json(cameras, i) for i in range(len(cameras))]
    shared = (
        {k: v for k, v in intrinsics[0].items() if all(row.get(k) == v for row in intrinsics)}
        if intrinsics
        else {}
    )
    document.update(shared)
    root = Path(scene.metadata.get("root", "."))
    taken: set[str] = set()
    frames, relative_images = [], []
    for index, frame in enumerate(scene.frames):
        stem = unique_stem(_output_stem(frame, root), taken)
        written = export_frame(scene, index, directory, stem, copy_suffixes=(".png", ".jpg", ".jpeg"))
        entry: dict[str, Any] = {"file_path": written.get("image", stem + ".png")}
        entry.update({k: v for k, v in intrinsics[index].items() if k not in shared})
        entry["transform_matrix"] = opengl_matrix(cameras, index)
        if "depth" in written:
            entry["depth_file_path"] = written["depth"]
        if "mask" in written:
            entry["object_mask_path"] = written["mask"]
        frames.append(entry)
        relative_images.append(entry["file_path"])
    _add_bounds(document, frames, scene)
    if any(f.has_depth for f in scene.frames):
        document["depth_unit_scale_factor"] = 1.0
    if "aabb_scale" in scene.metadata:
        document["aabb_scale"] = scene.metadata["aabb_scale"]
    document["frames"] = frames
    if set(scene.splits) != {"train"} or len(scene.splits["train"]) != len(scene):
        for name, indices in scene.splits.items():
            if name in SPLIT_NAMES:
                document[f"{name}_filenames"] = [relative_images[i] for i in indices]
    if scene.points is not None:
        write(directory / points_file, _narrow_ids(scene.points))
        document["ply_file_path"] = points_file
    write_json(directory / "transforms.json", document)


def _narrow_ids(points: PointCloud) -> PointCloud:
    """COLMAP's 64-bit ``point_id`` (and any 64-bit integer field) as int32 where every value fits,
    which PLY holds and which reads back equal: otherwise the PLY writer would warn a user about a
    detail of a file pointfield chose to write."""
    fields = dict(points.fields)
    for name, values in fields.items():
        wide = values.dtype.kind in "iu" and values.dtype.itemsize == 8 and values.size
        if wide and np.iinfo(np.int32).min <= int(values.min()) and int(values.max()) <= np.iinfo(np.int32).max:
            fields[name] = values.astype(np.int32)
    return replace(points, fields=fields)


def _output_stem(frame: Frame, root: Path) -> str:
    """Where a frame's files go, without suffix: its path inside the source folder when it has one."""
    if frame.image_path is not None:
        try:
            relative = frame.image_path.resolve().relative_to(root.resolve())
            return relative.with_suffix("").as_posix()
        except ValueError:
            return "images/" + frame.image_path.stem
    name = Path(frame.name.replace("\\", "/")).name
    return "images/" + (Path(name).stem or "frame")


def camera_intrinsics_json(cameras: Cameras, index: int) -> dict[str, Any]:
    """One camera's intrinsics under the transforms.json keys (w, h, fl_x, fl_y, cx, cy, k1, ...)."""
    values: dict[str, Any] = {
        "w": int(cameras.width[index]),
        "h": int(cameras.height[index]),
        "fl_x": float(cameras.fx[index]),
        "fl_y": float(cameras.fy[index]),
        "cx": float(cameras.cx[index]),
        "cy": float(cameras.cy[index]),
    }
    for name, value in zip(CAMERA_MODELS[cameras.model], cameras.distortion[index].tolist()):
        values[name] = value
    return values


def opengl_matrix(cameras: Cameras, index: int) -> list[list[float]]:
    """Camera ``index``'s pose as a 4x4 OpenGL camera-to-world matrix (transforms.json's convention)."""
    pose = np.concatenate([cameras.camera_to_world[index].double().cpu().numpy(), [[0.0, 0.0, 0.0, 1.0]]])
    return opencv_to_opengl(pose).tolist()


def _add_bounds(document: dict[str, Any], frames: list[dict[str, Any]], scene: Scene) -> None:
    if scene.near_far is not None and len(scene.near_far):
        if np.all(scene.near_far == scene.near_far[0]):
            document["near"], document["far"] = (float(v) for v in scene.near_far[0])
        else:
            for entry, (near, far) in zip(frames, scene.near_far):
                entry["near"], entry["far"] = float(near), float(far)
    if scene.aabb is not None:
        document["aabb"] = np.asarray(scene.aabb, dtype=np.float64).tolist()


def write_json(path: Path, document: dict[str, Any]) -> None:
    import json

    path.write_text(json.dumps(document, indent=2, allow_nan=False) + "\n", encoding="utf-8")


register(
    SceneFormat(
        name="nerfstudio",
        description="nerfstudio / instant-ngp transforms.json (OpenGL poses, shared or per-frame intrinsics)",
        detect=detect_nerfstudio,
        read=read_nerfstudio,
        write=write_nerfstudio,
        priority=20,
    )
)
