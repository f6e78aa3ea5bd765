"""Procedural point clouds and meshes: the built-in data of the demo and the tests.

Every generator is vectorised numpy and seedable: the same arguments give the same cloud, bit for
bit. Points are float32; fields use the dtypes real files use (``colors`` uint8, ``normals`` and
``intensity`` float32, ``ring`` uint8).

====================  =============================================================  ======
generator             what it is                                                     frame
====================  =============================================================  ======
:func:`sphere`        points on a sphere, with normals and colours from the normals  any
:func:`torus`         points on a torus, coloured by the angle around its axis       z up
:func:`cube_surface`  points on the six faces of a cube, one colour per face         any
:func:`lidar_scan`    a spinning 32-beam lidar in a street: intensity and ring       z up
:func:`depth_camera`  an organised (H, W) RGB-D frame with NaN holes                 y down
:func:`icosphere`     a triangle mesh of a sphere, with vertex normals               any
====================  =============================================================  ======
"""

from __future__ import annotations

import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.mesh import Mesh

# Six face colours of cube_surface, in the order +x -x +y -y +z -z.
CUBE_FACE_COLORS = np.array(
    [[230, 57, 70], [29, 53, 87], [69, 123, 157], [241, 196, 15], [42, 157, 143], [244, 162, 97]],
    np.uint8,
)


def _unit_vectors(count: int, rng: np.random.Generator) -> np.ndarray:
    """``(count, 3)`` float64 directions uniform on the unit sphere (normalised Gaussians)."""
    vectors = rng.standard_normal((count, 3))
    norms = np.linalg.norm(vectors, axis=1, keepdims=True)
    # A Gaussian sample of exactly zero has probability 0, but guard the division anyway.
    return vectors / np.maximum(norms, 1e-12)


def _colors_from_normals(normals: np.ndarray) -> np.ndarray:
    """uint8 RGB ``(N, 3)`` with each channel ``round(255 * (n + 1) / 2)``."""
    return np.round(255 * (normals + 1) / 2).clip(0, 255).astype(np.uint8)


def sphere(count: int = 4096, radius: float = 1.0, seed: int = 0) -> PointCloud:
    """``count`` points uniform on a sphere of ``radius`` centred at the origin.

    Fields: ``normals`` (N, 3) float32 (outward, unit) and ``colors`` (N, 3) uint8, the normals
    mapped to RGB by ``255 * (n + 1) / 2``.
    """
    normals = _unit_vectors(count, np.random.default_rng(seed))
    return PointCloud(
        (radius * normals).astype(np.float32),
        {"normals": normals.astype(np.float32), "colors": _colors_from_normals(normals)},
    )


def torus(
    count: int = 4096, major_radius: float = 1.0, minor_radius: float = 0.35, seed: int = 0
) -> PointCloud:
    """``count`` points uniform over the area of a torus around the z axis.

    A point is ``((R + r cos t) cos p, (R + r cos t) sin p, r sin t)`` with p the angle around the
    z axis and t the angle around the tube. Uniform area needs t with density proportional to
    ``R + r cos t`` (the outside of the ring has more area than the inside), drawn here by
    rejection. Fields: ``normals`` float32 and ``colors`` uint8 from the cyclic ``twilight``
    colour map over p.
    """
    from matplotlib import colormaps

    if not 0 < minor_radius < major_radius:
        raise ValueError(
            f"need 0 < minor_radius < major_radius, got {minor_radius}, {major_radius}"
        )
    rng = np.random.default_rng(seed)
    # Acceptance rate is R / (R + r); draw enough candidates for all points in one batch.
    accepted = np.zeros(0)
    while len(accepted) < count:
        batch = int(count * (major_radius + minor_radius) / major_radius * 1.2) + 16
        tube = rng.uniform(0, 2 * np.pi, batch)
        keep = rng.uniform(0, major_radius + minor_radius, batch) < (
            major_radius + minor_radius * np.cos(tube)
        )
        accepted = np.concatenate([accepted, tube[keep]])
    tube = accepted[:count]
    around = rng.uniform(0, 2 * np.pi, count)
    ring = major_radius + minor_radius * np.cos(tube)
    points = np.stack(
        [ring * np.cos(around), ring * np.sin(around), minor_radius * np.sin(tube)], axis=1
    )
    normals = np.stack(
        [np.cos(tube) * np.cos(around), np.cos(tube) * np.sin(around), np.sin(tube)], axis=1
    )
    colors = colormaps["twilight"](around / (2 * np.pi))[:, :3]
    return PointCloud(
        points.astype(np.float32),
        {"normals": normals.astype(np.float32), "colors": np.round(255 * colors).astype(np.uint8)},
    )


def cube_surface(count: int = 4096, size: float = 1.0, seed: int = 0) -> PointCloud:
    """``count`` points uniform on the surface of an axis-aligned cube of edge ``size``.

    The faces have equal area, so each point picks a face uniformly, then a uniform position on
    it. Fields: ``normals`` float32 (the face's outward axis) and ``colors`` uint8, one colour per
    face (:data:`CUBE_FACE_COLORS`).
    """
    rng = np.random.default_rng(seed)
    face = rng.integers(0, 6, count)  # 0..5 = +x -x +y -y +z -z
    axis, sign = face // 2, np.where(face % 2 == 0, 1.0, -1.0)
    points = rng.uniform(-size / 2, size / 2, (count, 3))
    rows = np.arange(count)
    points[rows, axis] = sign * size / 2
    normals = np.zeros((count, 3))
    normals[rows, axis] = sign
    return PointCloud(
        points.astype(np.float32),
        {"normals": normals.astype(np.float32), "colors": CUBE_FACE_COLORS[face]},
    )


# ---------------------------------------------------------------------------------------------
# Ray casting for the sensor-like generators. Rays are ``origin + t * direction`` with the origin
# at 0; each primitive returns the ray parameter t of its first hit (inf for a miss) and the unit
# surface normal there, so the nearest surface over all primitives is an elementwise minimum.


def _hit_plane(directions: np.ndarray, axis: int, offset: float) -> tuple[np.ndarray, np.ndarray]:
    """First hit of rays from the origin with the plane ``p[axis] == offset``."""
    component = directions[:, axis]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = offset / component
    t = np.where(np.isfinite(t) & (t > 0), t, np.inf)
    normal = np.zeros(3)
    normal[axis] = -np.sign(offset)  # faces the origin
    return t, np.broadcast_to(normal, directions.shape)


def _hit_box(
    directions: np.ndarray, centre: np.ndarray, half_size: np.ndarray, yaw: float
) -> tuple[np.ndarray, np.ndarray]:
    """First hit with a box of ``half_size`` at ``centre`` rotated by ``yaw`` about z (slab test).

    In the box's frame the ray enters slab i at ``(-h_i - o_i) / d_i`` or ``(h_i - o_i) / d_i``;
    it hits the box when the latest entry comes before the earliest exit. The normal is the axis
    of the latest entry, pointing against the ray.
    """
    cos, sin = np.cos(yaw), np.sin(yaw)
    to_box = np.array([[cos, sin, 0.0], [-sin, cos, 0.0], [0.0, 0.0, 1.0]])  # rotation by -yaw
    d = directions @ to_box.T
    o = to_box @ -centre
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (-half_size - o) / d
        t2 = (half_size - o) / d
    near, far = np.fmin(t1, t2), np.fmax(t1, t2)
    entry_axis = np.argmax(near, axis=1)
    t_entry, t_exit = near.max(axis=1), far.min(axis=1)
    hit = (t_entry <= t_exit) & (t_entry > 0)
    t = np.where(hit, t_entry, np.inf)
    normal_in_box = np.zeros_like(d)
    rows = np.arange(len(d))
    normal_in_box[rows, entry_axis] = -np.sign(d[rows, entry_axis])
    return t, normal_in_box @ to_box  # back to the world frame (inverse rotation)


def _hit_vertical_cylinder(
    directions: np.ndarray,
    centre_xy: tuple[float, float],
    radius: float,
    z_range: tuple[float, float],
) -> tuple[np.ndarray, np.ndarray]:
    """First hit with the side of a vertical cylinder (no caps): solve |o + t d - c|_xy = r."""
    c = np.asarray(centre_xy)
    dxy = directions[:, :2]
    a = (dxy**2).sum(axis=1)
    b = -2 * dxy @ c
    discriminant = b**2 - 4 * a * (c @ c - radius**2)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (-b - np.sqrt(discriminant)) / (2 * a)
    z = t * directions[:, 2]
    hit = (discriminant >= 0) & (t > 0) & (z >= z_range[0]) & (z <= z_range[1])
    t = np.where(hit, t, np.inf)
    normal = np.zeros_like(directions)
    normal[:, :2] = (np.where(hit, t, 0)[:, None] * dxy - c) / radius
    return t, normal


def _nearest(
    hits: list[tuple[np.ndarray, np.ndarray]], properties: list[float]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per ray: t of the nearest hit, its normal and the property of the primitive hit."""
    ts = np.stack([t for t, _ in hits])
    first = np.argmin(ts, axis=0)
    rows = np.arange(ts.shape[1])
    normals = np.stack([n for _, n in hits])[first, rows]
    return ts[first, rows], normals, np.asarray(properties)[first]


SENSOR_HEIGHT = 1.73  # metres above the ground, as the KITTI Velodyne


def lidar_scan(rings: int = 32, columns: int = 1024, seed: int = 0) -> PointCloud:
    """One sweep of a spinning lidar in a street, in the sensor frame (x forward, y left, z up).

    ``rings`` beams between -24.9 and +2 degrees of elevation, each fired at ``columns`` azimuths
    over 360 degrees. The scene: the ground at ``z = -SENSOR_HEIGHT``, a building front along one
    side, parked cars (boxes with a random yaw) and poles (cylinders), placed from ``seed``.
    Rays that hit nothing within 80 m return no point, so N <= rings * columns.

    Fields: ``intensity`` float32 in [0, 1], the surface's reflectance times
    ``0.35 + 0.65 |cos(incidence)|`` plus noise; ``ring`` uint8, the beam index (0 = lowest).
    Ranges carry Gaussian noise of 1 cm.
    """
    rng = np.random.default_rng(seed)
    elevation = np.radians(np.linspace(-24.9, 2.0, rings))
    azimuth = np.linspace(-np.pi, np.pi, columns, endpoint=False)
    el, az = np.meshgrid(elevation, azimuth, indexing="ij")  # (rings, columns)
    directions = np.stack(
        [np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1
    ).reshape(-1, 3)
    ring = np.repeat(np.arange(rings, dtype=np.uint8), columns)

    ground = -SENSOR_HEIGHT
    hits = [_hit_plane(directions, 2, ground)]
    reflectance = [0.25]
    building = np.array([0.0, 11.0, ground + 4.0]), np.array([30.0, 1.0, 4.0])
    hits.append(_hit_box(directions, *building, 0.0))
    reflectance.append(0.45)
    for _ in range(6):  # parked cars on both sides of the road
        side = rng.choice([-3.5, 3.5])
        centre = np.array([rng.uniform(-25, 25), side + rng.normal(0, 0.2), ground + 0.75])
        hits.append(_hit_box(directions, centre, np.array([2.1, 0.9, 0.75]), rng.normal(0, 0.1)))
        reflectance.append(0.7)
    for x in np.arange(-24.0, 25.0, 8.0):  # street lights along the far kerb
        centre_xy = (x + rng.uniform(-1, 1), -7.0 + rng.uniform(-0.3, 0.3))
        hits.append(_hit_vertical_cylinder(directions, centre_xy, 0.15, (ground, ground + 5.0)))
        reflectance.append(0.55)

    t, normals, albedo = _nearest(hits, reflectance)
    returned = t < 80.0
    t = t[returned] + rng.normal(0, 0.01, returned.sum())
    directions, normals, albedo = directions[returned], normals[returned], albedo[returned]
    incidence = np.abs((normals * directions).sum(axis=1))
    intensity = albedo * (0.35 + 0.65 * incidence) + rng.normal(0, 0.02, len(t))
    return PointCloud(
        (directions * t[:, None]).astype(np.float32),
        {"intensity": intensity.clip(0, 1).astype(np.float32), "ring": ring[returned]},
    )


def depth_camera(height: int = 120, width: int = 160, seed: int = 0) -> PointCloud:
    """An organised RGB-D frame: a ball and a box on a checkered floor in front of a wall.

    Camera frame as OpenCV and PCL: x right, y down, z forward; the camera is 0.8 m above the
    floor with focal ``0.8 * width`` pixels. Pixel (row v, column u) is point ``v * width + u``,
    so ``shape == (height, width)``. As a real sensor, pixels return NaN where nothing is within
    4 m (beside the wall), where the surface is seen at a grazing angle (``|cos| < 0.2``), and at 1 %
    random dropouts. Depth noise grows with the square of the depth (1.5 mm at 1 m).

    Fields: ``colors`` (N, 3) uint8 (0 at NaN points).
    """
    rng = np.random.default_rng(seed)
    focal = 0.8 * width
    u, v = np.meshgrid(np.arange(width), np.arange(height))
    # Directions with z = 1, so the ray parameter t of a hit is its depth.
    directions = np.stack(
        [(u - (width - 1) / 2) / focal, (v - (height - 1) / 2) / focal, np.ones_like(u, float)],
        axis=-1,
    ).reshape(-1, 3)

    floor_y, wall_z = 0.8, 3.5
    ball_centre, ball_radius = np.array([0.3, floor_y - 0.45, 2.3]), 0.45
    box_centre, box_half = np.array([-0.55, floor_y - 0.25, 2.6]), np.array([0.25, 0.25, 0.25])
    wall_t, wall_normal = _hit_plane(directions, 2, wall_z)
    wall_t = np.where(np.abs(directions[:, 0] * wall_t) < 1.6, wall_t, np.inf)  # 3.2 m wide
    a = (directions**2).sum(axis=1)
    b = -2 * directions @ ball_centre
    discriminant = b**2 - 4 * a * (ball_centre @ ball_centre - ball_radius**2)
    with np.errstate(invalid="ignore"):
        ball_t = np.where(discriminant >= 0, (-b - np.sqrt(discriminant)) / (2 * a), np.inf)
    ball_normal = (
        directions * np.where(np.isfinite(ball_t), ball_t, 0)[:, None] - ball_centre
    ) / ball_radius
    t, normals, surface = _nearest(
        [
            _hit_plane(directions, 1, floor_y),
            (wall_t, wall_normal),
            (ball_t, ball_normal),
            _hit_box(directions, box_centre, box_half, 0.3),
        ],
        [0, 1, 2, 3],
    )
    missed = t > 4.0
    points = directions * np.where(missed, 1.0, t)[:, None]  # finite placeholders, NaN below
    incidence = np.abs((normals * directions).sum(axis=1)) / np.sqrt(a)

    checker = (np.floor(points[:, 0] / 0.4) + np.floor(points[:, 2] / 0.4)) % 2
    palette = {
        0: np.where(checker[:, None] == 0, [[196, 164, 132]], [[120, 94, 70]]),  # floor
        1: np.broadcast_to([[205, 222, 235]], points.shape),  # wall
        2: np.broadcast_to([[220, 70, 50]], points.shape),  # ball
        3: np.broadcast_to([[60, 130, 200]], points.shape),  # box
    }
    albedo = np.zeros(points.shape)
    for index, colours in palette.items():
        albedo[surface == index] = colours[surface == index]
    colors = albedo * (0.45 + 0.55 * incidence[:, None])

    points[:, 2] += rng.normal(0, 0.0015, len(points)) * points[:, 2] ** 2
    points[:, :2] = directions[:, :2] * points[:, 2:]
    invalid = missed | (incidence < 0.2) | (rng.random(len(points)) < 0.01)
    points[invalid] = np.nan
    colors[invalid] = 0
    return PointCloud(
        points.astype(np.float32),
        {"colors": np.round(colors).clip(0, 255).astype(np.uint8)},
        shape=(height, width),
    )


def icosphere(subdivisions: int = 2, radius: float = 1.0) -> Mesh:
    """A triangle mesh of a sphere: an icosahedron whose faces are split ``subdivisions`` times.

    Each split replaces a triangle (a, b, c) by four, through the midpoints of its edges pushed
    out to the sphere; shared edges share their midpoint, so the mesh stays closed. That gives
    ``10 * 4**s + 2`` vertices and ``20 * 4**s`` faces (162 and 320 for s = 2), faces
    counter-clockwise seen from outside. Fields: ``normals`` float32 (the unit vertex positions).
    """
    if subdivisions < 0:
        raise ValueError(f"subdivisions must be >= 0, got {subdivisions}")
    phi = (1 + np.sqrt(5)) / 2
    vertices = np.array(
        [
            [-1, phi, 0], [1, phi, 0], [-1, -phi, 0], [1, -phi, 0],
            [0, -1, phi], [0, 1, phi], [0, -1, -phi], [0, 1, -phi],
            [phi, 0, -1], [phi, 0, 1], [-phi, 0, -1], [-phi, 0, 1],
        ],
        float,
    )  # fmt: skip
    faces = np.array(
        [
            [0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11],
            [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6], [7, 1, 8],
            [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9],
            [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1],
        ]
    )  # fmt: skip
    vertices /= np.linalg.norm(vertices, axis=1, keepdims=True)
    for _ in range(subdivisions):
        edges = np.sort(
            np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1
        )
        unique_edges, edge_of = np.unique(edges, axis=0, return_inverse=True)
        midpoints = vertices[unique_edges].sum(axis=1)
        midpoints /= np.linalg.norm(midpoints, axis=1, keepdims=True)
        m01, m12, m20 = edge_of.reshape(3, -1) + len(vertices)
        a, b, c = faces.T
        faces = np.concatenate(
            [
                np.stack(f, axis=1)
                for f in ((a, m01, m20), (b, m12, m01), (c, m20, m12), (m01, m12, m20))
            ]
        )
        vertices = np.concatenate([vertices, midpoints])
    return Mesh(
        (radius * vertices).astype(np.float32),
        {"normals": vertices.astype(np.float32)},
        faces=faces.astype(np.int32),
    )
