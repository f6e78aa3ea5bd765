"""Procedural labelled shapes: the built-in dataset for classification and part segmentation.

Ten classes, each a union of simple surfaces sampled uniformly by area, with a per-point part
label and exact outward normals:

============  ================================  ============  ================================
class         parts                             class         parts
============  ================================  ============  ================================
sphere        sphere                            pyramid       pyramid side, pyramid base
cube          cube                              capsule       capsule body, capsule end
cylinder      cylinder side, cylinder cap       hemisphere    hemisphere dome, hemisphere base
cone          cone side, cone base              mug           mug body, mug handle
torus         torus                             table         table top, table leg
============  ================================  ============  ================================

Part labels are global: :data:`PART_NAMES` lists all 17 parts in one index space (as ShapeNet
part annotations do), so one segmenter serves every class. Parts that a shape's symmetry makes
indistinguishable share a label (both caps of a cylinder are "cylinder cap").

Each shape is drawn with a random pose (any turn about the up axis z, and a tilt up to 15
degrees), a random stretch of each axis by 0.75..1.25, a random offset, Gaussian noise of
0..2 % of its size, and a random number of points; :class:`SyntheticShapes` serves them as a
dataset, deterministically from its seed.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.datasets import CloudDataset

SHAPE_CLASSES = (
    "sphere", "cube", "cylinder", "cone", "torus",
    "pyramid", "capsule", "hemisphere", "mug", "table",
)
SHAPE_PARTS = {
    "sphere": ("sphere",),
    "cube": ("cube",),
    "cylinder": ("cylinder side", "cylinder cap"),
    "cone": ("cone side", "cone base"),
    "torus": ("torus",),
    "pyramid": ("pyramid side", "pyramid base"),
    "capsule": ("capsule body", "capsule end"),
    "hemisphere": ("hemisphere dome", "hemisphere base"),
    "mug": ("mug body", "mug handle"),
    "table": ("table top", "table leg"),
}
PART_NAMES = tuple(part for name in SHAPE_CLASSES for part in SHAPE_PARTS[name])

MAX_TILT_DEGREES = 15.0
STRETCH = (0.75, 1.25)
MAX_NOISE = 0.02
MAX_OFFSET = 0.5

# A surface sampler takes (count, rng) and returns (count, 3) points and (count, 3) unit normals.
Sampler = Callable[[int, np.random.Generator], tuple[np.ndarray, np.ndarray]]


def make_shape(
    name: str, count: int, rng: np.random.Generator, *, posed: bool = True
) -> PointCloud:
    """``count`` points on the surface of shape class ``name``, in a random pose.

    Fields: ``label`` ``(N,)`` int32, the global part index into :data:`PART_NAMES`, and
    ``normals`` ``(N, 3)`` float32 (outward; exact for the noiseless surface). With
    ``posed=False`` the shape is returned in its canonical frame (z up, about unit size)
    without stretch, noise or offset. Points are float32, in no particular order.
    """
    if name not in SHAPE_PARTS:
        raise ValueError(f"unknown shape {name!r}: expected one of {', '.join(SHAPE_CLASSES)}")
    if count <= 0:
        raise ValueError(f"count must be positive, got {count}")
    surfaces = _SURFACES[name]()
    areas = np.array([area for _, area, _ in surfaces])
    per_surface = rng.multinomial(count, areas / areas.sum())
    points, normals, labels = [], [], []
    for (part, _, sampler), n in zip(surfaces, per_surface):
        if n:
            p, q = sampler(int(n), rng)
            points.append(p)
            normals.append(q)
            labels.append(np.full(n, PART_NAMES.index(part), np.int32))
    points, normals, labels = np.concatenate(points), np.concatenate(normals), np.concatenate(labels)
    if posed:
        stretch = rng.uniform(*STRETCH, 3)
        rotation = _random_pose(rng)
        points = (points * stretch) @ rotation.T
        # Normals follow a stretch by its inverse (they must stay perpendicular to the surface).
        normals = (normals / stretch) @ rotation.T
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        size = np.abs(points).max()
        points = points + rng.normal(0, rng.uniform(0, MAX_NOISE) * size, points.shape)
        points = points + rng.uniform(-MAX_OFFSET, MAX_OFFSET, 3)
    return PointCloud(
        points.astype(np.float32),
        {"label": labels, "normals": normals.astype(np.float32)},
        metadata={"shape": name},
    )


class SyntheticShapes(CloudDataset):
    """The procedural shapes as a dataset of ``(cloud, class index)`` pairs.

    ``shapes_per_class`` shapes of each class (item i is of class ``i % len(classes)``, so any
    prefix is balanced), each with a point count drawn uniformly from ``points`` (an int for a
    fixed count, or a ``(low, high)`` range). Item i of a split is the same shape every time:
    it is drawn from a generator seeded with ``(seed, split, i)``; the train and test splits
    are disjoint draws. ``transform`` is applied as in :class:`CloudDataset`. Clouds carry the
    per-point part ``label`` field and ``normals``.
    """

    def __init__(
        self,
        split: str = "train",
        shapes_per_class: int | None = None,
        points: int | tuple[int, int] = (1024, 2048),
        classes: Sequence[str] = SHAPE_CLASSES,
        seed: int = 0,
        transform: Callable | None = None,
    ):
        super().__init__(transform=transform, seed=seed)
        if split not in ("train", "test"):
            raise ValueError(f"split must be 'train' or 'test', got {split!r}")
        unknown = [name for name in classes if name not in SHAPE_PARTS]
        if unknown:
            raise ValueError(f"unknown shapes {unknown}: expected names from {SHAPE_CLASSES}")
        self.split = split
        self.classes = list(classes)
        self.parts = list(PART_NAMES)
        self.category_parts = [tuple(PART_NAMES.index(part) for part in SHAPE_PARTS[name]) for name in self.classes]
        self.shapes_per_class = shapes_per_class or (100 if split == "train" else 30)
        low, high = (points, points) if isinstance(points, int) else points
        if not 0 < low <= high:
            raise ValueError(f"points must be positive and low <= high, got {points}")
        self.point_range = (low, high)
        self.root = None

    def __len__(self) -> int:
        return self.shapes_per_class * len(self.classes)

    def class_labels(self) -> np.ndarray:
        return np.arange(len(self)) % len(self.classes)

    def load(self, index: int) -> tuple[PointCloud, int]:
        if not 0 <= index < len(self):
            raise IndexError(f"index {index} out of range for {len(self)} shapes")
        label = index % len(self.classes)
        rng = np.random.default_rng([self.seed, 0 if self.split == "train" else 1, index])
        count = int(rng.integers(self.point_range[0], self.point_range[1] + 1))
        return make_shape(self.classes[label], count, rng), label

    def describe(self) -> str:
        low, high = self.point_range
        count = f"{low}" if low == high else f"{low}..{high}"
        return (
            f"synthetic shapes ({self.split}): {len(self)} shapes, {len(self.classes)} classes, "
            f"{count} points each, seed {self.seed}"
        )


# ---------------------------------------------------------------------------------------------
# The classes, as (part, area, sampler) surfaces in a canonical frame: z up, about unit size.
# ---------------------------------------------------------------------------------------------


def _sphere() -> list:
    return [("sphere", *_sphere_zone(np.zeros(3), 0.9, -0.9))]


def _cube() -> list:
    return [("cube", *_box((-0.6, -0.6, -0.6), (0.6, 0.6, 0.6)))]


def _cylinder() -> list:
    radius, half = 0.6, 0.8
    return [
        ("cylinder side", *_cylinder_side(radius, -half, half)),
        ("cylinder cap", *_disk(radius, half, up=True)),
        ("cylinder cap", *_disk(radius, -half, up=False)),
    ]


def _cone() -> list:
    return [
        ("cone side", *_cone_side(0.7, -0.6, 0.8)),
        ("cone base", *_disk(0.7, -0.6, up=False)),
    ]


def _torus() -> list:
    return [("torus", *_torus_surface(0.7, 0.25, np.pi))]


def _pyramid() -> list:
    base = np.array([[-0.8, -0.8, -0.5], [0.8, -0.8, -0.5], [0.8, 0.8, -0.5], [-0.8, 0.8, -0.5]])
    apex = np.array([0.0, 0.0, 0.8])
    sides = np.stack([np.stack([base[i], base[(i + 1) % 4], apex]) for i in range(4)])
    bottom = np.stack([base[[0, 2, 1]], base[[0, 3, 2]]])
    centre = np.array([0.0, 0.0, -0.2])
    return [
        ("pyramid side", *_triangles(sides, centre)),
        ("pyramid base", *_triangles(bottom, centre)),
    ]


def _capsule() -> list:
    radius, half = 0.4, 0.5
    return [
        ("capsule body", *_cylinder_side(radius, -half, half)),
        ("capsule end", *_sphere_zone(np.array([0, 0, half]), radius, 0.0)),
        ("capsule end", *_sphere_zone(np.array([0, 0, -half]), radius, 0.0, flip=True)),
    ]


def _hemisphere() -> list:
    return [
        ("hemisphere dome", *_sphere_zone(np.array([0, 0, -0.3]), 0.9, 0.0)),
        ("hemisphere base", *_disk(0.9, -0.3, up=False)),
    ]


def _mug() -> list:
    radius, half = 0.5, 0.6
    area, handle = _torus_surface(0.3, 0.07, np.pi / 2)

    def handle_on_side(count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        # The torus stands in the x-z plane (its axis along y) and sticks out of the body at +x.
        points, normals = handle(count, rng)
        swap = [0, 2, 1]
        return points[:, swap] + np.array([radius, 0.0, 0.0]), normals[:, swap]

    return [
        ("mug body", *_cylinder_side(radius, -half, half)),
        ("mug body", *_disk(radius, -half, up=False)),
        ("mug handle", area, handle_on_side),
    ]


def _table() -> list:
    surfaces = [("table top", *_box((-0.9, -0.6, 0.4), (0.9, 0.6, 0.5)))]
    for x in (-0.78, 0.7):
        for y in (-0.48, 0.4):
            surfaces.append(("table leg", *_box((x, y, -0.6), (x + 0.08, y + 0.08, 0.4))))
    return surfaces


_SURFACES = {
    "sphere": _sphere, "cube": _cube, "cylinder": _cylinder, "cone": _cone, "torus": _torus,
    "pyramid": _pyramid, "capsule": _capsule, "hemisphere": _hemisphere, "mug": _mug,
    "table": _table,
}


# ---------------------------------------------------------------------------------------------
# Surfaces: (area, sampler) pairs, each sampler uniform over its surface's area.
# ---------------------------------------------------------------------------------------------


def _sphere_zone(
    centre: np.ndarray, radius: float, z_low: float, flip: bool = False
) -> tuple[float, Sampler]:
    """The part of a sphere above height ``z_low`` (relative to its centre); below if ``flip``.

    By Archimedes' hat-box theorem a zone's area is ``2 pi r h``, and z uniform over the zone's
    height with a uniform angle is uniform over its area.
    """

    def sample(count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        z = rng.uniform(z_low, radius, count)
        angle = rng.uniform(0, 2 * np.pi, count)
        ring = np.sqrt(np.maximum(radius**2 - z**2, 0))
        normals = np.stack([ring * np.cos(angle), ring * np.sin(angle), z], axis=1) / radius
        if flip:
            normals[:, 2] *= -1
        return centre + radius * normals, normals

    return 2 * np.pi * radius * (radius - z_low), sample


def _disk(radius: float, z: float, up: bool) -> tuple[float, Sampler]:
    """A horizontal disk at height ``z``, its normal up or down; ``r = R sqrt(u)`` is uniform."""

    def sample(count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        r = radius * np.sqrt(rng.random(count))
        angle = rng.uniform(0, 2 * np.pi, count)
        points = np.stack([r * np.cos(angle), r * np.sin(angle), np.full(count, z)], axis=1)
        normals = np.zeros((count, 3))
        normals[:, 2] = 1.0 if up else -1.0
        return points, normals

    return np.pi * radius**2, sample


def _cylinder_side(radius: float, z_low: float, z_high: float) -> tuple[float, Sampler]:
    def sample(count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        angle = rng.uniform(0, 2 * np.pi, count)
        normals = np.stack([np.cos(angle), np.sin(angle), np.zeros(count)], axis=1)
        points = radius * normals
        points[:, 2] = rng.uniform(z_low, z_high, count)
        return points, normals

    return 2 * np.pi * radius * (z_high - z_low), sample


def _cone_side(radius: float, z_base: float, z_apex: float) -> tuple[float, Sampler]:
    """The slanted surface of a cone with its apex up; area ``pi R L`` (L the slant height).

    The area within distance t of the apex grows as t², so ``t = sqrt(u)`` (as a fraction of
    the slant) is uniform; the outward normal is ``(h u_r, R) / L`` with u_r the radial unit.
    """
    height = z_apex - z_base
    slant = np.hypot(radius, height)

    def sample(count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        t = np.sqrt(rng.random(count))
        angle = rng.uniform(0, 2 * np.pi, count)
        radial = np.stack([np.cos(angle), np.sin(angle), np.zeros(count)], axis=1)
        points = radius * t[:, None] * radial
        points[:, 2] = z_apex - height * t
        normals = (height * radial + np.array([0.0, 0.0, radius])) / slant
        return points, normals

    return np.pi * radius * slant, sample


def _torus_surface(major: float, minor: float, half_span: float) -> tuple[float, Sampler]:
    """A torus around the z axis, the part with azimuth in ``[-half_span, half_span]``.

    A point is ``((R + r cos t) cos p, (R + r cos t) sin p, r sin t)``; area is uniform when t
    has density proportional to ``R + r cos t``, drawn here by rejection. Area ``2 p_span 2 pi R r``.
    """

    def sample(count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        tube = np.zeros(0)
        while len(tube) < count:
            t = rng.uniform(0, 2 * np.pi, 2 * count + 16)
            keep = rng.uniform(0, major + minor, len(t)) < major + minor * np.cos(t)
            tube = np.concatenate([tube, t[keep]])
        tube = tube[:count]
        azimuth = rng.uniform(-half_span, half_span, count)
        normals = np.stack(
            [np.cos(tube) * np.cos(azimuth), np.cos(tube) * np.sin(azimuth), np.sin(tube)], axis=1
        )
        centres = np.stack([major * np.cos(azimuth), major * np.sin(azimuth), np.zeros(count)], 1)
        return centres + minor * normals, normals

    return 2 * half_span * 2 * np.pi * major * minor, sample


def _triangles(corners: np.ndarray, inside: np.ndarray) -> tuple[float, Sampler]:
    """Triangles ``(T, 3, 3)`` sampled by area, normals turned away from the point ``inside``."""
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    areas = 0.5 * np.linalg.norm(cross, axis=1)
    normals = cross / (2 * areas[:, None])
    outward = ((corners.mean(axis=1) - inside) * normals).sum(axis=1) >= 0
    normals = np.where(outward[:, None], normals, -normals)

    def sample(count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        chosen = rng.choice(len(corners), size=count, p=areas / areas.sum())
        u, v = rng.random(count), rng.random(count)
        flip = u + v > 1
        u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
        a, b, c = corners[chosen, 0], corners[chosen, 1], corners[chosen, 2]
        return a + u[:, None] * (b - a) + v[:, None] * (c - a), normals[chosen]

    return float(areas.sum()), sample


def _box(low: Sequence[float], high: Sequence[float]) -> tuple[float, Sampler]:
    """The six faces of an axis-aligned box, as 12 triangles."""
    lo, hi = np.asarray(low, float), np.asarray(high, float)
    corner = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                       for z in (lo[2], hi[2])])
    # Corner index bits are (x, y, z); each face is the 4 corners sharing one bit value.
    faces = []
    for axis in range(3):
        for side in (0, 1):
            quad = [i for i in range(8) if (i >> (2 - axis)) & 1 == side]
            a, b, c, d = quad  # a and d are opposite corners of the face
            faces += [corner[[a, b, d]], corner[[a, d, c]]]
    return _triangles(np.stack(faces), (lo + hi) / 2)


def _random_pose(rng: np.random.Generator) -> np.ndarray:
    """Any turn about z, then a tilt of up to MAX_TILT_DEGREES about a random horizontal axis."""
    yaw = rng.uniform(0, 2 * np.pi)
    c, s = np.cos(yaw), np.sin(yaw)
    turn = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    axis_angle = rng.uniform(0, 2 * np.pi)
    axis = np.array([np.cos(axis_angle), np.sin(axis_angle), 0.0])
    tilt = np.deg2rad(rng.uniform(0, MAX_TILT_DEGREES))
    # Rodrigues: R = I + sin(a) K + (1 - cos(a)) K², K the cross-product matrix of the axis.
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return (np.eye(3) + np.sin(tilt) * k + (1 - np.cos(tilt)) * k @ k) @ turn
