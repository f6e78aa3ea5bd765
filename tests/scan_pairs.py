"""Synthetic scan pairs with a known motion: two samplings of one textured, bumpy surface."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from pointfield.clouds.cloud import PointCloud


def surface(count: int, x_range: tuple[float, float], rng: np.random.Generator, noise: float = 0.0,
            flat: bool = False) -> PointCloud:
    """``count`` points of a 1 x 1 height field with asymmetric bumps and a step (or a flat square), textured.

    Asymmetric, so that no rotation but the identity maps it onto itself (global registration
    has one right answer); textured in both directions, for coloured ICP.
    """
    x = rng.uniform(*x_range, count)
    y = rng.uniform(0.0, 1.0, count)
    z = (0.25 * np.exp(-((x - 0.3) ** 2 + (y - 0.35) ** 2) / 0.02) + 0.15 * np.exp(-((x - 0.7) ** 2 + (y - 0.6) ** 2) / 0.05)
         - 0.1 * np.exp(-((x - 0.55) ** 2 + (y - 0.15) ** 2) / 0.01) + 0.08 * (y > 0.8) + 0.05 * x * y)
    z = np.zeros_like(z) if flat else z
    points = np.stack([x, y, z], axis=1) + rng.normal(0, noise, (count, 3))
    grey = 0.5 + 0.25 * np.sin(12 * x) + 0.25 * np.sin(9 * y + 3 * x)
    colors = (np.stack([grey, 0.5 * grey + 0.25, 1 - grey], axis=1) * 255).astype(np.uint8)
    return PointCloud(points.astype(np.float32), {"colors": colors})


def motion(angle_degrees: float, translation: tuple[float, float, float], axis=(0.3, -0.5, 0.8)) -> np.ndarray:
    """``(4, 4)`` rotation by ``angle_degrees`` about ``axis``, then ``translation``."""
    out = np.eye(4)
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    out[:3, :3] = Rotation.from_rotvec(np.radians(angle_degrees) * axis).as_matrix()
    out[:3, 3] = translation
    return out


def moved(cloud: PointCloud, transformation: np.ndarray) -> PointCloud:
    points = cloud.points.astype(np.float64) @ transformation[:3, :3].T + transformation[:3, 3]
    return PointCloud(points.astype(cloud.points.dtype), dict(cloud.fields))


def pair(angle: float, translation=(0.05, -0.03, 0.02), overlap_split: float = 0.67, noise: float = 0.002,
         count: int = 3000, seed: int = 0, flat: bool = False) -> tuple[PointCloud, PointCloud, np.ndarray]:
    """``(source, target, truth)``: target covers x in [1 - split, 1], source x in [0, split] (50 % of it
    overlapping at the default), sampled apart, then moved by the inverse of ``truth`` so that
    ``truth`` maps source onto target."""
    rng = np.random.default_rng(seed)
    target = surface(count, (1 - overlap_split, 1.0), rng, noise, flat)
    source = surface(count, (0.0, overlap_split), rng, noise, flat)
    truth = motion(angle, translation)
    return moved(source, np.linalg.inv(truth)), target, truth


def errors(found: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """``(degrees, distance)`` between two motions: the angle of ``found truth^-1`` and its translation."""
    delta = found @ np.linalg.inv(truth)
    angle = np.degrees(np.arccos(np.clip((np.trace(delta[:3, :3]) - 1) / 2, -1, 1)))
    return float(angle), float(np.linalg.norm(delta[:3, 3]))
