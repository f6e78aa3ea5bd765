"""Synthetic scan sets with known poses: sectors of one bumpy surface seen from stations around a ring.

Scan i covers the sector of an annulus (radii 0.12 to 0.5 about (0.5, 0.5)) centred on
``360 i / count`` degrees and ``width`` degrees wide; with 4 scans 150 degrees wide, neighbours
share 60 degrees (40 % of a scan) and opposite scans nothing, so the pairs that overlap are the
chain 0-1-2-3 and one loop closure, 3-0. Each scan is stored in its own frame: moved by the
inverse of its pose, which maps it back into scan 0's frame.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from pointfield.clouds.cloud import PointCloud


def height(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The surface: the bumps, dip and step of scan_pairs' surface, and 40 smaller bumps, so that
    every sector has shape to register on."""
    z = (0.25 * np.exp(-((x - 0.3) ** 2 + (y - 0.35) ** 2) / 0.02) + 0.15 * np.exp(-((x - 0.7) ** 2 + (y - 0.6) ** 2) / 0.05)
         - 0.1 * np.exp(-((x - 0.55) ** 2 + (y - 0.15) ** 2) / 0.01) + 0.08 * (y > 0.8) + 0.05 * x * y)
    bumps = np.random.default_rng(3).uniform([0, 0, -0.08, 0.03], [1, 1, 0.15, 0.09], (40, 4))
    for cx, cy, h, w in bumps:
        z = z + h * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / w**2)
    return z


def ring_scans(count: int = 4, points: int = 3000, noise: float = 0.002, width: float = 150.0,
               degrees: float = 5.0, shift: float = 0.02, seed: int = 0) -> tuple[list[PointCloud], list[np.ndarray]]:
    """``(scans, poses)``: float32 scans with a ``colors`` field, each in its own frame, and the ``(4, 4)``
    pose of each (scan i into scan 0's frame): a rotation of up to ``degrees`` about a random axis
    and a translation of ``shift`` per axis (normal), scan 0's the identity."""
    rng = np.random.default_rng(seed)
    scans, poses = [], []
    for i in range(count):
        angle = np.radians(360.0 * i / count + rng.uniform(-width / 2, width / 2, points))
        radius = np.sqrt(rng.uniform(0.12**2, 0.5**2, points))
        x, y = 0.5 + radius * np.cos(angle), 0.5 + radius * np.sin(angle)
        surface = np.stack([x, y, height(x, y)], axis=1) + rng.normal(0, noise, (points, 3))
        pose = np.eye(4)
        if i:
            axis = rng.normal(size=3)
            pose[:3, :3] = Rotation.from_rotvec(np.radians(rng.uniform(0, degrees)) * axis / np.linalg.norm(axis)).as_matrix()
            pose[:3, 3] = rng.normal(0, shift, 3)
        inverse = np.linalg.inv(pose)
        grey = (127 + 120 * np.sin(9 * x) * np.cos(7 * y)).astype(np.uint8)
        scans.append(PointCloud((surface @ inverse[:3, :3].T + inverse[:3, 3]).astype(np.float32),
                                {"colors": np.stack([grey, grey, grey], axis=1)}))
        poses.append(pose)
    return scans, poses


def pose_errors(found: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """``(degrees, distance)`` of ``found truth^-1``."""
    delta = found @ np.linalg.inv(truth)
    return (float(np.degrees(np.arccos(np.clip((np.trace(delta[:3, :3]) - 1) / 2, -1, 1)))),
            float(np.linalg.norm(delta[:3, 3])))
