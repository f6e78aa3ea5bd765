"""Synthetic labelled scenes: rooms and streets built of primitives, scanned by a simulated sensor.

The fixed task behind the scene-segmentation tests and benchmarks. A scene is a list of
labelled primitives; a simulated sensor casts rays into it and keeps, for every ray, the
nearest surface it meets, so anything behind a wall, a car or a tree trunk gets no points
(occlusion), exactly as in a real scan::

    >>> scene = synthetic_scene("room", seed=0, density=0.2)
    >>> scene.classes
    ('floor', 'wall', 'ceiling', 'table', 'chair', 'shelf')
    >>> scene.cloud.fields["label"].dtype
    dtype('int32')

==========  =========================================  ============================================
kind        classes                                    sensor
==========  =========================================  ============================================
``room``    floor, wall, ceiling, table, chair, shelf  a depth camera (90 x 68 degrees, Kinect-like
                                                       noise sigma = 1.5 mm + 2.5 mm / m² · r²)
                                                       from two places, four headings each
``street``  ground, building, tree, car, pole          a spinning 32-beam lidar (-25..+10 degrees,
                                                       sigma = 2 cm) at 1.8 m, from three places
                                                       along the street
==========  =========================================  ============================================

Both sensors sample directions on a regular angular grid, so the density of points falls with
range as 1 / r² on surfaces facing the sensor, and faster on surfaces seen at a grazing angle.
Noise is added along the ray (range noise), and a few returns (2 %) are dropped at random.

The cloud, z up, in metres: ``points`` float32; fields ``colors`` (N, 3) uint8, ``normals``
(N, 3) float32 (the true surface normal, facing the sensor), ``intensity`` (N,) float32 in
[0, 1] (the surface's reflectance times the cosine of the incidence angle), and ``label`` (N,)
int32, an index into ``classes``. Every scene is drawn from ``numpy.random.default_rng(seed)``
alone: the same ``(kind, seed, density)`` gives the same cloud, bit for bit.

Colours and reflectances vary by instance and overlap between classes (a white table before a
white wall, a grey car beside a grey pole), so a model must use shape as well as colour.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pointfield.atomic import atomic_path
from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.formats import write
from pointfield.errors import PointfieldError

ROOM_CLASSES = ("floor", "wall", "ceiling", "table", "chair", "shelf")
STREET_CLASSES = ("ground", "building", "tree", "car", "pole")
SCENE_KINDS = {"room": ROOM_CLASSES, "street": STREET_CLASSES}
LABEL_FIELD = "label"
CLASSES_FILE = "classes.json"  # the class-name table of a folder of labelled clouds
DROPPED_RETURNS = 0.02
_EPSILON = 1e-9


# ---------------------------------------------------------------------------------------------
# Primitives: each finds, for R rays, the distance to its surface and the normal there
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Primitive:
    """A labelled solid: ``label`` (class index), ``colour`` (3,) uint8, ``reflectance`` in [0, 1]."""

    label: int
    colour: tuple[int, int, int]
    reflectance: float

    def intersect(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(t (R,), normals (R, 3))`` for rays ``origin + t · direction`` (unit directions).

        ``t`` is the distance to the first surface point in front of the origin (inf on a miss).
        """
        raise NotImplementedError


@dataclass(frozen=True)
class Box(Primitive):
    """An axis-aligned box between corners ``low`` and ``high``: the slab method.

    Along each axis a ray is inside the slab for t in [(lo - o) / d, (hi - o) / d] (ordered);
    it is inside the box where the three intervals overlap, from t_near = max of the entries to
    t_far = min of the exits. The normal is that of the face the ray enters through.
    """

    low: tuple[float, float, float] = (0.0, 0.0, 0.0)
    high: tuple[float, float, float] = (1.0, 1.0, 1.0)

    def intersect(self, origins, directions):
        safe = np.where(np.abs(directions) < _EPSILON, _EPSILON, directions)
        first = (np.asarray(self.low) - origins) / safe
        second = (np.asarray(self.high) - origins) / safe
        entries, exits = np.minimum(first, second), np.maximum(first, second)
        axis = entries.argmax(axis=1)
        near = entries.max(axis=1)
        far = exits.min(axis=1)
        hit = (near <= far) & (near > _EPSILON)
        t = np.where(hit, near, np.inf)
        normals = np.zeros_like(directions)
        rows = np.arange(len(directions))
        normals[rows, axis] = -np.sign(safe[rows, axis])
        return t, normals


@dataclass(frozen=True)
class Cylinder(Primitive):
    """A vertical cylinder of ``radius`` about ``(x, y)`` from z ``bottom`` to ``top``, with a top cap.

    Side: ``|o_xy + t d_xy - c|² = r²``, a quadratic in t whose smaller root in front of the
    origin counts when its z lies between bottom and top.
    """

    centre: tuple[float, float] = (0.0, 0.0)
    radius: float = 0.1
    bottom: float = 0.0
    top: float = 1.0

    def intersect(self, origins, directions):
        offset = origins[:, :2] - np.asarray(self.centre)
        a = (directions[:, :2] ** 2).sum(axis=1)
        b = 2 * (offset * directions[:, :2]).sum(axis=1)
        c = (offset**2).sum(axis=1) - self.radius**2
        discriminant = b * b - 4 * a * c
        root = np.sqrt(np.maximum(discriminant, 0.0))
        t = (-b - root) / np.maximum(2 * a, _EPSILON)
        z = origins[:, 2] + t * directions[:, 2]
        side = (discriminant > 0) & (t > _EPSILON) & (z >= self.bottom) & (z <= self.top)
        t_side = np.where(side, t, np.inf)
        normals = np.zeros_like(directions)
        normals[:, :2] = (offset + t[:, None] * directions[:, :2]) / self.radius
        # The top cap, for rays coming down onto it.
        t_cap = (self.top - origins[:, 2]) / np.where(np.abs(directions[:, 2]) < _EPSILON, _EPSILON,
                                                      directions[:, 2])
        at_cap = origins[:, :2] + t_cap[:, None] * directions[:, :2] - np.asarray(self.centre)
        cap = (t_cap > _EPSILON) & (directions[:, 2] < 0) & ((at_cap**2).sum(axis=1) <= self.radius**2)
        use_cap = cap & (t_cap < t_side)
        normals[use_cap] = (0.0, 0.0, 1.0)
        return np.where(use_cap, t_cap, t_side), normals


@dataclass(frozen=True)
class Ellipsoid(Primitive):
    """An axis-aligned ellipsoid of semi-axes ``radii`` about ``centre`` (a tree's crown).

    Scaled by 1 / radii it is the unit sphere: ``|o' + t d'|² = 1`` with o' = (o - c) / radii,
    d' = d / radii; the normal is the gradient (p - c) / radii².
    """

    centre: tuple[float, float, float] = (0.0, 0.0, 0.0)
    radii: tuple[float, float, float] = (1.0, 1.0, 1.0)

    def intersect(self, origins, directions):
        radii = np.asarray(self.radii)
        o = (origins - np.asarray(self.centre)) / radii
        d = directions / radii
        a = (d * d).sum(axis=1)
        b = 2 * (o * d).sum(axis=1)
        c = (o * o).sum(axis=1) - 1
        discriminant = b * b - 4 * a * c
        t = (-b - np.sqrt(np.maximum(discriminant, 0.0))) / (2 * a)
        hit = (discriminant > 0) & (t > _EPSILON)
        normals = (o + t[:, None] * d) / radii
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), _EPSILON)
        return np.where(hit, t, np.inf), normals


# ---------------------------------------------------------------------------------------------
# Sensors: where rays start and which way they go
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class DepthCamera:
    """A pinhole depth camera at ``position`` with heading ``yaw`` (radians about z, 0 = +x) and
    ``pitch`` (radians, up positive), ``width`` x ``height`` pixels over ``fov`` degrees
    horizontally; range noise ``sigma(r) = 0.0015 + 0.0025 r²`` m, as a structured-light sensor's."""

    position: tuple[float, float, float]
    yaw: float
    pitch: float = 0.0
    width: int = 160
    height: int = 120
    fov: float = 90.0
    max_range: float = 8.0

    def rays(self) -> tuple[np.ndarray, np.ndarray]:
        focal = (self.width / 2) / np.tan(np.deg2rad(self.fov) / 2)
        u, v = np.meshgrid(np.arange(self.width) + 0.5 - self.width / 2,
                           np.arange(self.height) + 0.5 - self.height / 2)
        # Camera frame: forward x, left y, up z.
        local = np.stack([np.full(u.size, focal), -u.ravel(), -v.ravel()], axis=1)
        local /= np.linalg.norm(local, axis=1, keepdims=True)
        cp, sp, cy, sy = np.cos(self.pitch), np.sin(self.pitch), np.cos(self.yaw), np.sin(self.yaw)
        pitch = np.array([[cp, 0, -sp], [0, 1, 0], [sp, 0, cp]])
        yaw = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
        directions = local @ (yaw @ pitch).T
        return np.broadcast_to(np.asarray(self.position, float), directions.shape), directions

    def noise(self, ranges: np.ndarray) -> np.ndarray:
        return 0.0015 + 0.0025 * ranges**2


@dataclass(frozen=True)
class SpinningLidar:
    """A spinning lidar at ``position``: ``beams`` elevations evenly from ``low`` to ``high``
    degrees, ``steps`` azimuths per turn; range noise 2 cm at any range."""

    position: tuple[float, float, float]
    beams: int = 32
    steps: int = 720
    low: float = -25.0
    high: float = 10.0
    max_range: float = 60.0

    def rays(self) -> tuple[np.ndarray, np.ndarray]:
        elevation, azimuth = np.meshgrid(np.deg2rad(np.linspace(self.low, self.high, self.beams)),
                                         np.linspace(0, 2 * np.pi, self.steps, endpoint=False))
        elevation, azimuth = elevation.ravel(), azimuth.ravel()
        directions = np.stack([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth),
                               np.sin(elevation)], axis=1)
        return np.broadcast_to(np.asarray(self.position, float), directions.shape), directions

    def noise(self, ranges: np.ndarray) -> np.ndarray:
        return np.full_like(ranges, 0.02)


# ---------------------------------------------------------------------------------------------
# Scanning
# ---------------------------------------------------------------------------------------------


@dataclass
class LabelledScene:
    """A scanned scene: ``cloud`` (see the module doc for its fields) and ``classes`` (label -> name)."""

    cloud: PointCloud
    classes: tuple[str, ...]


def cast(
    primitives: Sequence[Primitive], origins: np.ndarray, directions: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The nearest surface along each ray: ``(t (R,), index of the primitive hit (R,), normals (R, 3))``.

    ``t`` is inf and the index -1 where a ray meets nothing. One pass per primitive keeps the
    memory at O(R).
    """
    nearest = np.full(len(directions), np.inf)
    which = np.full(len(directions), -1)
    normals = np.zeros_like(directions)
    for index, primitive in enumerate(primitives):
        t, n = primitive.intersect(origins, directions)
        closer = t < nearest
        nearest[closer], which[closer], normals[closer] = t[closer], index, n[closer]
    return nearest, which, normals


def scan(
    primitives: Sequence[Primitive],
    sensors: Sequence[DepthCamera | SpinningLidar],
    classes: Sequence[str],
    rng: np.random.Generator,
) -> LabelledScene:
    """Scan ``primitives`` from every sensor and join the returns into one labelled cloud.

    A return within the sensor's ``max_range`` becomes the point ``o + (t + e) d`` with range
    noise ``e ~ N(0, sigma(t)²)``; :data:`DROPPED_RETURNS` of them are dropped at random.
    """
    parts = []
    for sensor in sensors:
        origins, directions = sensor.rays()
        t, which, normals = cast(primitives, origins, directions)
        kept = (which >= 0) & (t <= sensor.max_range) & (rng.random(len(t)) >= DROPPED_RETURNS)
        t, which, normals = t[kept], which[kept], normals[kept]
        origins, directions = origins[kept], directions[kept]
        noisy = t + rng.normal(0.0, 1.0, len(t)) * sensor.noise(t)
        normals = np.where(((normals * directions).sum(axis=1) > 0)[:, None], -normals, normals)
        cosine = np.clip(-(normals * directions).sum(axis=1), 0.0, 1.0)
        parts.append((origins + noisy[:, None] * directions, which, normals, cosine))
    points = np.concatenate([p[0] for p in parts]).astype(np.float32)
    which = np.concatenate([p[1] for p in parts])
    labels = np.array([p.label for p in primitives], np.int32)[which]
    colours = np.array([p.colour for p in primitives], np.float64)[which]
    colours = np.clip(colours + rng.normal(0.0, 6.0, colours.shape), 0, 255).astype(np.uint8)
    reflectance = np.array([p.reflectance for p in primitives])[which]
    intensity = (reflectance * np.concatenate([p[3] for p in parts])).astype(np.float32)
    fields = {
        "colors": colours,
        "normals": np.concatenate([p[2] for p in parts]).astype(np.float32),
        "intensity": intensity,
        LABEL_FIELD: labels,
    }
    return LabelledScene(PointCloud(points, fields), tuple(classes))


# ---------------------------------------------------------------------------------------------
# Rooms
# ---------------------------------------------------------------------------------------------


def _shade(rng: np.random.Generator, base: Sequence[int], spread: float = 25.0) -> tuple[int, int, int]:
    colour = np.clip(np.asarray(base, float) + rng.normal(0.0, spread, 3), 0, 255)
    return tuple(int(c) for c in colour)


def _table(rng, label, centre, size, height, colour) -> list[Primitive]:
    (x, y), (w, d), leg = centre, size, 0.05
    parts: list[Primitive] = [Box(label, colour, 0.5, (x - w / 2, y - d / 2, height - 0.04),
                                  (x + w / 2, y + d / 2, height))]
    for sx in (-1, 1):
        for sy in (-1, 1):
            lx, ly = x + sx * (w / 2 - leg), y + sy * (d / 2 - leg)
            parts.append(Box(label, colour, 0.5, (lx - leg / 2, ly - leg / 2, 0.0), (lx + leg / 2, ly + leg / 2,
                                                                                      height - 0.04)))
    return parts


def _chair(rng, label, centre, facing, colour) -> list[Primitive]:
    """A seat at 0.45 m on four legs, its back on the side away from ``facing`` (unit xy)."""
    (x, y), half, seat = centre, 0.22, 0.45
    parts = _table(rng, label, centre, (2 * half, 2 * half), seat, colour)
    fx, fy = facing
    bx, by = x - fx * half, y - fy * half
    thin_x, thin_y = (0.03, half) if abs(fx) > abs(fy) else (half, 0.03)
    parts.append(Box(label, colour, 0.5, (bx - thin_x, by - thin_y, seat), (bx + thin_x, by + thin_y, seat + 0.45)))
    return parts


def _shelf(rng, label, x_range, wall_y, inward, height, colour) -> list[Primitive]:
    """A bookshelf against the wall at ``y = wall_y``, 0.35 m deep: two sides, a back, boards."""
    depth = 0.35
    y0, y1 = sorted((wall_y, wall_y + inward * depth))
    (x0, x1), board = x_range, 0.025
    parts: list[Primitive] = [
        Box(label, colour, 0.5, (x0, y0, 0.0), (x0 + board, y1, height)),
        Box(label, colour, 0.5, (x1 - board, y0, 0.0), (x1, y1, height)),
        Box(label, colour, 0.5, (x0, y0, 0.0), (x1, y0 + board, height) if inward > 0 else (x1, y1, height)),
    ]
    if inward < 0:  # the back against the wall on the far side
        parts[-1] = Box(label, colour, 0.5, (x0, y1 - board, 0.0), (x1, y1, height))
    for z in np.linspace(0.05, height - board, int(height / 0.4) + 1):
        parts.append(Box(label, colour, 0.5, (x0, y0, z), (x1, y1, z + board)))
    # Books: coloured blocks on each board, part of the shelf as S3DIS labels them.
    for z in np.linspace(0.05, height - board, int(height / 0.4) + 1)[:-1]:
        start = x0 + board
        while start < x1 - board - 0.1:
            width = rng.uniform(0.05, 0.25)
            end = min(start + width, x1 - board)
            parts.append(Box(label, _shade(rng, (120, 90, 60), 60), 0.4,
                             (start, y0 + 0.03, z + board), (end, y1 - 0.03, z + board + rng.uniform(0.18, 0.3))))
            start = end + rng.uniform(0.0, 0.15)
    return parts


def room_primitives(rng: np.random.Generator) -> tuple[list[Primitive], tuple[float, float, float]]:
    """A furnished room: ``(primitives, (width, depth, height))``; the floor spans [0, w] x [0, d]."""
    width, depth, height = rng.uniform(4.5, 7.5), rng.uniform(4.0, 6.0), rng.uniform(2.6, 3.2)
    floor, wall, ceiling, table, chair, shelf = range(6)
    wall_colour = _shade(rng, (225, 225, 215), 15)
    t = 0.1
    primitives: list[Primitive] = [
        Box(floor, _shade(rng, (150, 120, 90), 30), 0.3, (-t, -t, -t), (width + t, depth + t, 0.0)),
        Box(ceiling, _shade(rng, (235, 235, 230), 10), 0.8, (-t, -t, height), (width + t, depth + t, height + t)),
        Box(wall, wall_colour, 0.7, (-t, -t, 0.0), (0.0, depth + t, height)),
        Box(wall, wall_colour, 0.7, (width, -t, 0.0), (width + t, depth + t, height)),
        Box(wall, wall_colour, 0.7, (-t, -t, 0.0), (width + t, 0.0, height)),
        Box(wall, wall_colour, 0.7, (-t, depth, 0.0), (width + t, depth + t, height)),
    ]
    # Shelves against the two long walls, tables with chairs in the middle of the room.
    for wall_y, inward in ((0.0, 1.0), (depth, -1.0))[: rng.integers(1, 3)]:
        length = rng.uniform(1.0, 2.0)
        x0 = rng.uniform(0.3, width - length - 0.3)
        primitives += _shelf(rng, shelf, (x0, x0 + length), wall_y, inward, rng.uniform(1.6, 2.2),
                             _shade(rng, (140, 110, 80), 50))
    tables = rng.integers(1, 3)
    for k in range(tables):
        w, d = rng.uniform(1.0, 1.8), rng.uniform(0.7, 1.0)
        x = width * (k + 1) / (tables + 1) + rng.uniform(-0.3, 0.3)
        y = depth / 2 + rng.uniform(-0.3, 0.3)
        table_colour = _shade(rng, (200, 180, 150) if rng.random() < 0.7 else (225, 225, 215), 30)
        primitives += _table(rng, table, (x, y), (w, d), rng.uniform(0.7, 0.78), table_colour)
        chair_colour = _shade(rng, rng.choice([(60, 60, 70), (170, 40, 40), (40, 80, 160), (200, 180, 150)]), 20)
        for side in (-1, 1):
            for offset in rng.choice([-0.3, 0.3, 0.0], size=rng.integers(1, 3), replace=False):
                centre = (x + offset * w, y + side * (d / 2 + 0.3))
                primitives += _chair(rng, chair, centre, (0.0, -side), chair_colour)
    return primitives, (width, depth, height)


def room_scene(seed: int = 0, density: float = 1.0) -> LabelledScene:
    """A room scanned by a depth camera from two places, turning through four headings at each."""
    rng = np.random.default_rng(seed)
    primitives, (width, depth, _) = room_primitives(rng)
    size = max(1, round(160 * np.sqrt(density))), max(1, round(120 * np.sqrt(density)))
    sensors = []
    for fx, fy in ((0.25, 0.3), (0.75, 0.7)):
        position = (width * fx + rng.uniform(-0.2, 0.2), depth * fy + rng.uniform(-0.2, 0.2), rng.uniform(1.3, 1.7))
        start = rng.uniform(0, np.pi / 2)
        for k in range(4):
            sensors.append(DepthCamera(position, start + k * np.pi / 2, pitch=rng.uniform(-0.35, -0.15),
                                       width=size[0], height=size[1], fov=90.0))
    return scan(primitives, sensors, ROOM_CLASSES, rng)


# ---------------------------------------------------------------------------------------------
# Streets
# ---------------------------------------------------------------------------------------------


def street_primitives(rng: np.random.Generator) -> tuple[list[Primitive], float]:
    """A straight street along x: ``(primitives, length)``; the road is ``|y| < 5`` m, pavements to 8 m."""
    length = rng.uniform(50.0, 70.0)
    ground, building, tree, car, pole = range(5)
    primitives: list[Primitive] = [Box(ground, _shade(rng, (90, 90, 95), 10), 0.2, (-20, -40, -0.2),
                                       (length + 20, 40, 0.0))]
    for side in (-1, 1):
        x = rng.uniform(-10, 0)
        while x < length + 10:  # a row of buildings behind the pavement, with gaps
            w = rng.uniform(8, 18)
            setback = rng.uniform(9.0, 12.0)
            y0, y1 = sorted((side * setback, side * (setback + rng.uniform(8, 14))))
            primitives.append(Box(building, _shade(rng, rng.choice([(180, 160, 140), (140, 60, 50), (200, 200, 195)])),
                                  rng.uniform(0.4, 0.8), (x, y0, 0.0), (x + w, y1, rng.uniform(6, 18))))
            x += w + rng.uniform(2, 6)
        for x in np.arange(rng.uniform(3, 10), length, rng.uniform(12, 18)):  # trees on the pavement
            y = side * rng.uniform(6.5, 7.5)
            trunk_top = rng.uniform(2.0, 3.0)
            primitives.append(Cylinder(tree, _shade(rng, (90, 70, 50), 15), 0.3, (x, y), rng.uniform(0.12, 0.2),
                                       0.0, trunk_top + 0.3))
            r = rng.uniform(1.5, 2.5)
            primitives.append(Ellipsoid(tree, _shade(rng, (60, 120, 50), 20), 0.6, (x, y, trunk_top + r * 0.8),
                                        (r, r, r * 1.2)))
        for x in np.arange(rng.uniform(0, 8), length, rng.uniform(15, 22)):  # poles at the kerb
            primitives.append(Cylinder(pole, _shade(rng, (120, 120, 125), 20), 0.7,
                                       (x + rng.uniform(-1, 1), side * 5.4), 0.08, 0.0, rng.uniform(5, 8)))
        for x in np.arange(rng.uniform(0, 6), length, rng.uniform(7, 12)):  # parked cars
            if rng.random() < 0.3:
                continue
            colour = _shade(rng, rng.choice([(120, 120, 125), (30, 30, 35), (200, 30, 30), (230, 230, 230),
                                             (30, 60, 140)]), 15)
            y = side * rng.uniform(3.2, 3.8)
            car_length = rng.uniform(3.8, 4.8)
            primitives.append(Box(car, colour, 0.9, (x, y - 0.9, 0.25), (x + car_length, y + 0.9, 0.95)))
            primitives.append(Box(car, _shade(rng, (60, 70, 80), 10), 0.3,
                                  (x + 0.25 * car_length, y - 0.8, 0.95), (x + 0.75 * car_length, y + 0.8, 1.45)))
    return primitives, length


def street_scene(seed: int = 0, density: float = 1.0) -> LabelledScene:
    """A street scanned by a 32-beam lidar at 1.8 m, from three places along the road."""
    rng = np.random.default_rng(seed)
    primitives, length = street_primitives(rng)
    steps = max(8, round(720 * density))
    sensors = [SpinningLidar((length * f + rng.uniform(-2, 2), rng.uniform(-1.5, 1.5), 1.8), steps=steps)
               for f in (0.2, 0.5, 0.8)]
    return scan(primitives, sensors, STREET_CLASSES, rng)


def synthetic_scene(kind: str = "room", seed: int = 0, density: float = 1.0) -> LabelledScene:
    """A labelled scan of a synthetic ``room`` or ``street`` (see the module doc), drawn from ``seed``.

    ``density`` scales the number of rays (1.0: about 150,000 for a room, 70,000 for a street).
    """
    if kind not in SCENE_KINDS:
        raise PointfieldError(f"unknown scene kind {kind!r}: expected one of {', '.join(SCENE_KINDS)}")
    if not density > 0:
        raise PointfieldError(f"density must be positive, got {density}")
    return (room_scene if kind == "room" else street_scene)(seed, density)


def make_scenes(
    out: str | os.PathLike[str],
    kind: str = "room",
    count: int = 10,
    *,
    seed: int = 0,
    density: float = 1.0,
    test: int | None = None,
    suffix: str = ".ply",
) -> list[Path]:
    """Write ``count`` scanned scenes to ``out/train/`` and ``out/test/`` with their class table.

    Scene i is drawn from seed ``seed + i``; the last ``test`` of them (default a fifth, at least
    one when ``count >= 2``) go to ``test/``. Each is a labelled cloud (``suffix``: any format
    that keeps the ``label``, ``colors``, ``normals`` and ``intensity`` fields, PLY by default),
    and ``out/classes.json`` is the class-name table, given once for the folder. Returns the
    files written.
    """
    if count < 1:
        raise PointfieldError(f"count must be at least 1, got {count}")
    held = test if test is not None else (max(1, count // 5) if count >= 2 else 0)
    root = Path(out)
    written = []
    for i in range(count):
        scene = synthetic_scene(kind, seed + i, density)
        folder = root / ("test" if i >= count - held else "train")
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / f"{kind}_{seed + i:04d}{suffix}"
        write(path, scene.cloud)
        written.append(path)
    with atomic_path(root / CLASSES_FILE) as tmp:
        tmp.write_text(json.dumps(list(SCENE_KINDS[kind])) + "\n")
    return written
