"""Blender / NeRF-synthetic datasets: ``transforms_{train,val,test}.json`` beside the images.

Each split file holds ``camera_angle_x`` (horizontal field of view, radians) and frames with an
extension-less ``file_path`` (``"./train/r_0"`` means ``train/r_0.png``) and an **OpenGL**
camera-to-world ``transform_matrix``. The focal length follows from the image width,
``f = 0.5 * W / tan(0.5 * camera_angle_x)``, with the principal point at the image centre and no
distortion; W and H come from the PNG headers, so every image must have the same size.
Near and far are NeRF's 2 and 6 unless the file says otherwise (``near`` / ``far`` keys).

The frames are parsed by the transforms.json parser (:mod:`.transforms_json`), so instant-ngp's
extension keys (``fl_x``, ``cx``, ``w``, ``k1``, ...) are honoured too; the writer uses them for
cameras that a bare ``camera_angle_x`` cannot describe, and warns that plain NeRF loaders will
ignore them.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from pointfield.errors import FormatError
from pointfield.scenes.formats.export import export_frame, unique_stem
from pointfield.scenes.formats.registry import SceneFormat, register
from pointfield.scenes.formats.transforms_json import (
    BLENDER_FILE,
    SPLIT_NAMES,
    camera_intrinsics_json,
    explicit_aabb,
    opengl_matrix,
    parse_transforms,
    write_json,
)
from pointfield.scenes.formats.validation import load_json
from pointfield.scenes.scene import Scene

NERF_SYNTHETIC_NEAR_FAR = (2.0, 6.0)


def detect_blender(path: Path) -> bool:
    if path.is_dir():
        return any((path / f"transforms_{split}.json").is_file() for split in SPLIT_NAMES)
    return BLENDER_FILE.fullmatch(path.name) is not None


def read_blender(path: Path, missing_images: str = "skip") -> Scene:
    """Read every split file of a Blender dataset folder (or the one split file ``path`` names)."""
    if path.is_dir():
        folder = path
        files = [(split, path / f"transforms_{split}.json") for split in SPLIT_NAMES]
        files = [(split, file) for split, file in files if file.is_file()]
    else:
        folder = path.parent
        named = BLENDER_FILE.fullmatch(path.name)
        files = [(named.group(1).lower(), path)] if named else []
    if not files:
        raise FormatError(
            path, "no Blender split file (transforms_train.json, transforms_val.json, transforms_test.json)"
        )
    documents = [(split, file, load_json(file)) for split, file in files]
    parsed = parse_transforms(documents, missing_images, folder)
    splits = {
        split: np.array([i for i, s in enumerate(parsed.frame_splits) if s == split], dtype=np.int64)
        for split, _ in files
    }
    near_far = parsed.near_far
    if near_far is None:
        near_far = np.tile(np.array(NERF_SYNTHETIC_NEAR_FAR), (len(parsed.frames), 1))
    aabb = explicit_aabb(documents[0][2], documents[0][1]) if documents else None
    metadata = {"path": str(path), "root": str(folder), "frames_listed": parsed.listed}
    return Scene(parsed.cameras, parsed.frames, splits, None, near_far, aabb, metadata=metadata)


def write_blender(scene: Scene, directory: Path) -> None:
    """Write one ``transforms_<split>.json`` per split, images as ``<split>/<name>.png``.

    Cameras that ``camera_angle_x`` alone describes (one size, fx == fy, centred principal
    point, no distortion) are written the pure Blender way; others also get instant-ngp's keys,
    with a warning.
    """
    cameras = scene.cameras
    intrinsics = [camera_intrinsics_json(cameras, i) for i in range(len(cameras))]
    plain = _plain_blender(intrinsics, cameras.model)
    if not plain:
        warnings.warn(
            "these cameras need more than Blender's camera_angle_x (distortion, off-centre principal point, "
            "fx != fy or several image sizes): wrote instant-ngp's fl_x/fl_y/cx/cy/w/h keys too; "
            "plain NeRF-synthetic loaders ignore them",
            stacklevel=3,
        )
    shared = (
        {k: v for k, v in intrinsics[0].items() if all(row.get(k) == v for row in intrinsics)}
        if intrinsics
        else {}
    )
    covered = np.zeros(len(scene), dtype=bool)
    for split, indices in scene.splits.items():
        covered[indices] = True
        taken: set[str] = set()
        document: dict[str, Any] = {}
        if len(indices):
            first = intrinsics[indices[0]]
            document["camera_angle_x"] = 2 * math.atan(first["w"] / (2 * first["fl_x"]))
        if not plain:
            document["camera_model"] = cameras.model
            document.update(shared)
        if (
            scene.near_far is not None
            and len(indices)
            and np.all(scene.near_far[indices] == scene.near_far[indices[0]])
        ):
            document["near"], document["far"] = (float(v) for v in scene.near_far[indices[0]])
        if scene.aabb is not None:
            document["aabb"] = np.asarray(scene.aabb, dtype=np.float64).tolist()
        if any(scene.frames[i].has_depth for i in indices):
            document["depth_unit_scale_factor"] = 1.0
        frames = []
        for index in indices:
            frame = scene.frames[index]
            stem = unique_stem(f"{split}/{_frame_stem(frame)}", taken)
            written = export_frame(scene, int(index), directory, stem, copy_suffixes=(".png",))
            entry: dict[str, Any] = {"file_path": "./" + stem}
            if not plain:
                entry.update({k: v for k, v in intrinsics[index].items() if k not in shared})
            entry["transform_matrix"] = opengl_matrix(cameras, int(index))
            if scene.near_far is not None and "near" not in document:
                entry["near"], entry["far"] = (float(v) for v in scene.near_far[index])
            if "depth" in written:
                entry["depth_file_path"] = "./" + written["depth"]
            if "mask" in written:
                entry["object_mask_path"] = "./" + written["mask"]
            frames.append(entry)
        document["frames"] = frames
        write_json(directory / f"transforms_{split}.json", document)
    if not covered.all():
        warnings.warn(f"{int((~covered).sum())} frames belong to no split and were not written", stacklevel=3)


def _plain_blender(intrinsics: list[dict[str, Any]], model: str) -> bool:
    if model != "PINHOLE" or not intrinsics:
        return model == "PINHOLE"
    sizes = {(row["w"], row["h"]) for row in intrinsics}
    if len(sizes) != 1:
        return False
    return all(
        math.isclose(row["fl_x"], row["fl_y"], rel_tol=1e-12)
        and math.isclose(row["cx"], row["w"] / 2, rel_tol=1e-12)
        and math.isclose(row["cy"], row["h"] / 2, rel_tol=1e-12)
        and row["fl_x"] == intrinsics[0]["fl_x"]
        for row in intrinsics
    )


def _frame_stem(frame) -> str:
    name = (
        frame.image_path.name
        if frame.image_path is not None
        else frame.name.replace("\\", "/").rsplit("/", 1)[-1]
    )
    return (
        Path(name).stem
        if Path(name).suffix.lower() in (".png", ".jpg", ".jpeg", ".exr", ".tif", ".tiff")
        else name or "frame"
    )


register(
    SceneFormat(
        name="blender",
        description="Blender / NeRF-synthetic transforms_{train,val,test}.json (OpenGL poses, camera_angle_x)",
        detect=detect_blender,
        read=read_blender,
        write=write_blender,
        priority=10,
    )
)
