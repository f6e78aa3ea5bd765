"""Scans with their sensor origins, as an :class:`~pointfield.volumes.OccupancyMap` takes them.

A scan is ``(points (N, 3), origin (3,))`` in one world frame. They come from

- point-cloud files in one frame, each seen from ``origin`` (a scan in its sensor's own frame, as a
  lidar's, has its sensor at ``(0, 0, 0)``);
- point-cloud files and the poses ``cloud align`` wrote (``OUT.poses.json``:
  :meth:`pointfield.registration.multiway.AlignResult.as_dict`, ``q = R p + t`` into the
  reference scan's frame): each scan's points and its sensor origin moved by its pose;
- a scene's depth frames (``scene from-rgbd``'s output, or any scene whose frames carry depth):
  every ``stride``-th pixel of each frame back-projected at its z-depth
  (:meth:`pointfield.scenes.cameras.Cameras.unproject`), seen from its camera's centre.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from pointfield.errors import FormatError, PointfieldError

Scan = tuple[np.ndarray, np.ndarray]


def read_poses(path: str | os.PathLike[str]) -> list[tuple[str, np.ndarray | None]]:
    """``[(scan name, (4, 4) pose or None when cloud align left it out), ...]`` from a ``poses.json``.

    A pose must be a finite rigid motion (rows ``[R | t]`` then ``0 0 0 1``, ``R`` orthonormal to
    1e-4); anything else raises :class:`~pointfield.errors.FormatError` naming the file and the scan.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    try:
        document = json.loads(path.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise FormatError(path, f"not a poses file: invalid JSON ({error})") from None
    scans = document.get("scans") if isinstance(document, dict) else None
    if not isinstance(scans, list) or not scans:
        raise FormatError(path, "not a poses file: expected cloud align's {\"scans\": [{\"scan\": NAME, \"pose\": "
                          "4 x 4 or null}, ...]}")
    out = []
    for index, entry in enumerate(scans):
        if not isinstance(entry, dict) or not isinstance(entry.get("scan"), str) or "pose" not in entry:
            raise FormatError(path, f"scan {index}: expected {{\"scan\": NAME, \"pose\": 4 x 4 or null}}")
        if entry["pose"] is None:
            out.append((entry["scan"], None))
            continue
        try:
            pose = np.asarray(entry["pose"], np.float64)
        except (TypeError, ValueError):
            pose = np.zeros(0)
        if pose.shape != (4, 4) or not np.isfinite(pose).all():
            raise FormatError(path, f"scan {index} ({entry['scan']}): the pose must be 4 x 4 finite numbers")
        rotation = pose[:3, :3]
        if not np.allclose(pose[3], [0, 0, 0, 1]) or not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-4):
            raise FormatError(path, f"scan {index} ({entry['scan']}): the pose is not a rigid motion (a rotation, "
                              "a translation and a last row 0 0 0 1)")
        out.append((entry["scan"], pose))
    return out


def scans_from_files(files: Sequence[str | os.PathLike[str]], origin: Sequence[float] = (0.0, 0.0, 0.0),
                     poses: Sequence[np.ndarray | None] | None = None) -> list[Scan]:
    """Each file's points and its sensor ``origin`` (in the file's frame), moved by its pose when ``poses``.

    A scan whose pose is None (left out by ``cloud align``) is skipped.
    """
    import pointfield

    if poses is not None and len(poses) != len(files):
        raise PointfieldError(f"{len(files)} scans but {len(poses)} poses")
    origin = np.asarray(origin, np.float64).reshape(3)
    out = []
    for index, file in enumerate(files):
        pose = np.eye(4) if poses is None else poses[index]
        if pose is None:
            continue
        points = np.asarray(pointfield.read(file).points, np.float64)
        out.append((points @ pose[:3, :3].T + pose[:3, 3], pose[:3, :3] @ origin + pose[:3, 3]))
    return out


def scans_from_scene(scene, stride: int = 4, depth_max: float | None = None) -> list[Scan]:
    """Per frame of ``scene`` (a :class:`~pointfield.scenes.Scene`) with depth: every ``stride``-th pixel
    across and down back-projected at its depth (0 = no reading; beyond ``depth_max`` dropped) in world
    units, and the camera's centre."""
    import torch

    if stride < 1:
        raise PointfieldError(f"--stride must be at least 1, got {stride}")
    cameras = scene.cameras.to(dtype=torch.float64)
    out = []
    for index in range(len(scene)):
        depth = scene.depth(index)
        if depth is None:
            continue
        depth = depth[stride // 2 :: stride, stride // 2 :: stride].astype(np.float64)
        v, u = np.nonzero((depth > 0) & (depth <= (np.inf if depth_max is None else depth_max)))
        pixels = torch.as_tensor(np.stack([u * stride + stride // 2 + 0.5, v * stride + stride // 2 + 0.5], axis=1))
        points = cameras.unproject(index, pixels, torch.as_tensor(depth[v, u]))
        out.append((points.cpu().numpy(), cameras.centers[index].cpu().numpy()))
    if not out:
        raise PointfieldError(f"{scene.metadata.get('path', 'the scene')}: no frame has depth; an occupancy map "
                              "from a scene needs depth frames (scene from-rgbd writes them)")
    return out
