"""Synthetic scenes: a small analytic ray tracer that writes Blender-format datasets with ground truth.

The built-in default scene, and the data of the lesson's NeRF exercise::

    make_scene("cube", "cube-dataset", views=100, size=100)   # or: pointfield scene make cube ...

Scenes (world z is up; units are arbitrary, the cube's side is 1):

- ``"cube"``: the lesson's cube, side 1, centred at the origin, six coloured faces with opposite
  faces complementary -- +x red, -x cyan, +y green, -y magenta, +z blue, -z yellow -- on a
  transparent background.
- ``"spheres"``: red, green and blue spheres resting on a checkered ground square.
- ``"still-life"``: the cube resting on the checkered ground between two spheres.
- ``"textured"``: the still life with every surface painted in random-colour cells of four
  sizes (:class:`CellTexture`), so that feature detectors find corners everywhere: the scene
  that structure from motion (``scene from-images``) can pose.

Rendering: ``supersampling`` x ``supersampling`` rays per pixel (default 2 x 2) on a regular
grid inside it, each to its nearest analytic hit (slab test for the box, quadratic for spheres,
plane for the ground), Lambertian shading
``c = albedo * (ambient + sum_k I_k max(0, n . l_k) visible_k)`` with hard shadows, clipped to 1.
A pixel is the box-filtered mean of its rays, as a camera's pixel integrates light and as
Blender renders the NeRF-synthetic scenes: ``alpha`` is the share of rays that hit (fractional
on silhouettes) and colour the mean of the hits' colours (straight, not premultiplied). Depth
and mask are those of one more ray, through the pixel's centre, so that every depth lies on a
surface (Blender's depth pass is not antialiased either). One ray per pixel
(``supersampling=1``) gives staircase silhouettes that no model drawing smooth footprints can
match: on the demo's cube (60 views of 100 x 100), splats trained 1000 steps scored 27.8 dB held
out there, and the hash-grid field, whose rays go through the same pixel centres, 39.1 dB after
300; with 2 x 2 rays, 32.1 and 29.7 dB (``pointfield demo`` with those step counts).
Shading does not depend on the viewing direction, so a surface looks the same from every view.
Float64 on the CPU with no randomness: the same arguments give byte-identical files.

Cameras sit at distance ``radius`` from the origin, look at it, and keep world z up in the
image: ``layout="sphere"`` (Fibonacci lattice over the whole sphere), ``"hemisphere"`` (upper
half) or ``"ring"`` (a circle at 30 degrees elevation). The default field of view is the
NeRF-synthetic one (``camera_angle_x`` 0.6911), so 100-pixel views have focal 138.9 like the
classic ``tiny_nerf_data.npz``.

Written dataset (Blender format, readable by :func:`read_scene`, nerfstudio and instant-ngp):
``transforms_{train,val,test}.json``; ``<split>/r_<i>.png`` RGBA (alpha 0 where no surface);
``<split>/r_<i>_depth.npy`` float32 z-depth in world units (distance along the optical axis, 0
where no surface); ``<split>/r_<i>_mask.png`` (255 on surfaces). Every 10th view is "test", every
10th starting at the 5th is "val" (one each for 3 to 19 views, none below 3). The JSON also holds
``near`` / ``far`` (the scene's bounding sphere seen from the camera distance) and ``aabb`` (the
objects' bounds with room around them, :func:`padded_aabb`). Beside them, ``synthetic.json``
(:data:`TRUTH_RECORD`) says which scene it is and how it was rendered, so that its analytic truth
can be rendered from any camera (:func:`synthetic_truth`): a model trained on it can be scored
nearer, farther or from a path, not only at the cameras it was given.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from pointfield.atomic import atomic_path
from pointfield.scenes.cameras import Cameras, look_at, pixel_centers
from pointfield.scenes.formats import write_scene
from pointfield.scenes.scene import Frame, Scene, SceneError

NERF_SYNTHETIC_CAMERA_ANGLE_X = 0.6911112070083618
LAYOUTS = ("sphere", "hemisphere", "ring")
RING_ELEVATION = math.radians(30)
SURFACE_OFFSET = 1e-7
RAYS_PER_BATCH = 1 << 18
SUPERSAMPLING = 2
"""Rays per pixel along each image axis (see the module doc)."""
TRUTH_RECORD = "synthetic.json"
"""The file :func:`make_scene` writes beside a dataset: ``{"scene": name, "supersampling": k}``."""

CUBE_FACE_COLORS = (
    (0.90, 0.10, 0.10),  # +x red
    (0.10, 0.80, 0.80),  # -x cyan
    (0.15, 0.75, 0.15),  # +y green
    (0.80, 0.15, 0.80),  # -y magenta
    (0.15, 0.25, 0.90),  # +z blue
    (0.90, 0.85, 0.10),  # -z yellow
)


@dataclass
class Hit:
    """Nearest intersections of a batch of R rays: ``distance`` (R,) (inf = miss), ``normal``
    (R, 3) facing the ray, ``albedo`` (R, 3)."""

    distance: torch.Tensor
    normal: torch.Tensor
    albedo: torch.Tensor


@dataclass(frozen=True)
class CellTexture:
    """A solid texture: the mean of random colours of cubic cells of several sizes, times a strength.

    For a surface point ``p``: ``albedo * (1 - strength + strength * mean_k c(floor(p / s_k + o)))``
    with ``s_k`` the cell sizes, ``o`` an offset that keeps cell borders off the scene's planes,
    and ``c`` a colour in [0, 1]^3 hashed from the integer cell and k. Defined in 3D, it is the
    same on a surface from every view; nearest-cell colours give the sharp corners SIFT finds.
    """

    cell_sizes: tuple[float, ...] = (0.25, 0.125, 0.0625, 0.03125)
    strength: float = 0.8
    seed: int = 0

    def __call__(self, points: torch.Tensor, albedo: torch.Tensor) -> torch.Tensor:
        colours = torch.zeros_like(points)
        for octave, size in enumerate(self.cell_sizes):
            cells = torch.floor(points.nan_to_num(0, 0, 0) / size + 0.371).long()
            colours += _hash_colours(cells, octave + 16 * self.seed)
        return albedo * (1 - self.strength + self.strength * colours / len(self.cell_sizes))


def _hash_colours(cells: torch.Tensor, salt: int) -> torch.Tensor:
    """``(R, 3)`` integer cells -> ``(R, 3)`` colours in [0, 1): an integer hash, no global RNG."""
    primes = torch.tensor([73856093, 19349663, 83492791], dtype=torch.int64)
    mixed = (cells * primes).sum(-1, keepdim=True) + salt * 2654435761
    channels = mixed + torch.arange(3, dtype=torch.int64) * 1013904223
    for shift in (13, 17, 5):
        # xorshift-multiply rounds; int64 products wrap, the same on every machine.
        channels = (channels ^ (channels >> shift)) * 0x5BD1E995
    return (channels & 0xFFFF).to(torch.float64) / 65536.0


def _painted(hit: Hit, texture: CellTexture | None, origins: torch.Tensor, directions: torch.Tensor) -> Hit:
    """``hit`` with its albedo multiplied by ``texture`` at the hit points (unchanged without one)."""
    if texture is None:
        return hit
    points = origins + hit.distance.nan_to_num(posinf=0)[:, None] * directions
    return Hit(hit.distance, hit.normal, texture(points, hit.albedo).to(hit.albedo.dtype))


@dataclass
class Box:
    """Axis-aligned box with one colour per face, in the order +x, -x, +y, -y, +z, -z."""

    center: tuple[float, float, float]
    half_size: float
    face_colors: tuple[tuple[float, float, float], ...]
    texture: CellTexture | None = None

    def intersect(self, origins: torch.Tensor, directions: torch.Tensor) -> Hit:
        """Slab test: t_enter = max over axes of min(t0, t1), t_exit = min of max; hit if t_enter <= t_exit."""
        center = torch.tensor(self.center, dtype=origins.dtype)
        # A zero direction component would make 0 * inf = NaN; a tiny one gives the right +-inf.
        safe = torch.where(directions.abs() < 1e-30, torch.full_like(directions, 1e-30), directions)
        t0 = (center - self.half_size - origins) / safe
        t1 = (center + self.half_size - origins) / safe
        near_planes, far_planes = torch.minimum(t0, t1), torch.maximum(t0, t1)
        t_enter, axis = near_planes.max(dim=-1)
        t_exit = far_planes.min(dim=-1).values
        hit = (t_enter <= t_exit) & (t_enter > SURFACE_OFFSET)
        distance = torch.where(hit, t_enter, torch.full_like(t_enter, torch.inf))
        sign = -torch.sign(directions.gather(-1, axis[:, None]))[:, 0]
        normal = torch.zeros_like(origins)
        normal.scatter_(-1, axis[:, None], sign[:, None])
        face = 2 * axis + (sign < 0).long()
        albedo = torch.tensor(self.face_colors, dtype=origins.dtype)[face]
        return _painted(Hit(distance, normal, albedo), self.texture, origins, directions)


@dataclass
class Sphere:
    center: tuple[float, float, float]
    radius: float
    color: tuple[float, float, float]
    texture: CellTexture | None = None

    def intersect(self, origins: torch.Tensor, directions: torch.Tensor) -> Hit:
        """Nearest t > 0 of ``|o + t d - c|^2 = r^2`` for unit d: ``t = -b -+ sqrt(b^2 - (|o - c|^2 - r^2))``."""
        offset = origins - torch.tensor(self.center, dtype=origins.dtype)
        b = (offset * directions).sum(-1)
        discriminant = b * b - ((offset * offset).sum(-1) - self.radius**2)
        root = discriminant.clamp_min(0).sqrt()
        entering, leaving = -b - root, -b + root
        distance = torch.where(entering > SURFACE_OFFSET, entering, leaving)
        hit = (discriminant >= 0) & (distance > SURFACE_OFFSET)
        distance = torch.where(hit, distance, torch.full_like(distance, torch.inf))
        normal = torch.nn.functional.normalize(
            offset + distance.nan_to_num(posinf=0)[:, None] * directions, dim=-1
        )
        albedo = torch.tensor(self.color, dtype=origins.dtype).expand_as(origins)
        return _painted(Hit(distance, normal, albedo), self.texture, origins, directions)


@dataclass
class CheckeredGround:
    """The square ``|x|, |y| <= half_size`` at height ``z``, checkered in squares of side ``tile``."""

    z: float
    half_size: float
    tile: float
    colors: tuple[tuple[float, float, float], tuple[float, float, float]] = (
        (0.85, 0.85, 0.85),
        (0.35, 0.35, 0.38),
    )
    texture: CellTexture | None = None

    def intersect(self, origins: torch.Tensor, directions: torch.Tensor) -> Hit:
        dz = directions[:, 2]
        safe = torch.where(dz.abs() < 1e-30, torch.full_like(dz, 1e-30), dz)
        distance = (self.z - origins[:, 2]) / safe
        points = origins + distance[:, None] * directions
        inside = (points[:, 0].abs() <= self.half_size) & (points[:, 1].abs() <= self.half_size)
        hit = inside & (distance > SURFACE_OFFSET)
        distance = torch.where(hit, distance, torch.full_like(distance, torch.inf))
        normal = torch.zeros_like(origins)
        normal[:, 2] = torch.where(dz < 0, 1.0, -1.0)
        parity = (torch.floor(points[:, 0] / self.tile) + torch.floor(points[:, 1] / self.tile)).remainder(2)
        palette = torch.tensor(self.colors, dtype=origins.dtype)
        albedo = palette[parity.nan_to_num(0).long().clamp(0, 1)]
        return _painted(Hit(distance, normal, albedo), self.texture, origins, directions)


@dataclass
class SyntheticScene:
    """Objects, lights ``(direction towards the light, intensity)``, ambient light, bounds."""

    objects: list
    lights: list[tuple[tuple[float, float, float], float]]
    ambient: float
    bounding_radius: float
    aabb: tuple[tuple[float, float, float], tuple[float, float, float]]  # the objects' bounds, unpadded
    layout: str


def _cube() -> SyntheticScene:
    return SyntheticScene(
        objects=[Box((0.0, 0.0, 0.0), 0.5, CUBE_FACE_COLORS)],
        lights=[((0.4, -0.6, 1.0), 0.55), ((-0.5, 0.7, -0.3), 0.25)],
        ambient=0.3,
        bounding_radius=math.sqrt(3) / 2,
        aabb=((-0.5, -0.5, -0.5), (0.5, 0.5, 0.5)),
        layout="sphere",
    )


def _textured_cube() -> SyntheticScene:
    """The cube with a cell texture on its faces: where a plain face looks the same at any depth,
    a textured one pins its depth across views (the geometry benchmark's scene)."""
    cube = _cube()
    return dataclasses.replace(cube, objects=[dataclasses.replace(cube.objects[0], texture=CellTexture(seed=1))])


def _ground() -> CheckeredGround:
    return CheckeredGround(z=-0.5, half_size=2.0, tile=0.5)


def _spheres() -> SyntheticScene:
    return SyntheticScene(
        objects=[
            Sphere((-0.8, -0.3, -0.1), 0.4, (0.85, 0.15, 0.15)),
            Sphere((0.7, -0.4, -0.15), 0.35, (0.15, 0.7, 0.2)),
            Sphere((0.0, 0.7, 0.0), 0.5, (0.2, 0.3, 0.9)),
            _ground(),
        ],
        lights=[((0.4, -0.6, 1.0), 0.6), ((-0.5, 0.7, 0.4), 0.2)],
        ambient=0.25,
        bounding_radius=2.0 * math.sqrt(2),
        aabb=((-2.0, -2.0, -0.5), (2.0, 2.0, 0.5)),
        layout="hemisphere",
    )


def _still_life() -> SyntheticScene:
    return SyntheticScene(
        objects=[
            Box((0.0, 0.0, 0.0), 0.5, CUBE_FACE_COLORS),
            Sphere((-1.1, 0.4, -0.2), 0.3, (0.9, 0.5, 0.1)),
            Sphere((1.0, 0.6, -0.1), 0.4, (0.6, 0.6, 0.65)),
            _ground(),
        ],
        lights=[((0.4, -0.6, 1.0), 0.6), ((-0.5, 0.7, 0.4), 0.2)],
        ambient=0.25,
        bounding_radius=2.0 * math.sqrt(2),
        aabb=((-2.0, -2.0, -0.5), (2.0, 2.0, 0.5)),
        layout="hemisphere",
    )


def _textured() -> SyntheticScene:
    pale_faces = tuple(tuple(0.55 + 0.45 * c for c in face) for face in CUBE_FACE_COLORS)
    return SyntheticScene(
        objects=[
            Box((0.0, 0.0, 0.0), 0.5, pale_faces, CellTexture(seed=1)),
            Sphere((-1.1, 0.4, -0.2), 0.3, (0.95, 0.7, 0.4), CellTexture(seed=2)),
            Sphere((1.0, 0.6, -0.1), 0.4, (0.75, 0.8, 0.95), CellTexture(seed=3)),
            CheckeredGround(z=-0.5, half_size=2.0, tile=0.5, colors=((0.95, 0.95, 0.9), (0.7, 0.7, 0.75)),
                            texture=CellTexture(seed=4)),
        ],
        lights=[((0.4, -0.6, 1.0), 0.6), ((-0.5, 0.7, 0.4), 0.2)],
        ambient=0.3,
        bounding_radius=2.0 * math.sqrt(2),
        aabb=((-2.0, -2.0, -0.5), (2.0, 2.0, 0.5)),
        layout="hemisphere",
    )


SYNTHETIC_SCENES: dict[str, Callable[[], SyntheticScene]] = {
    "cube": _cube,
    "textured-cube": _textured_cube,
    "spheres": _spheres,
    "still-life": _still_life,
    "textured": _textured,
}
"""Name -> builder of each synthetic scene."""


def _scene_named(name: str) -> SyntheticScene:
    if name not in SYNTHETIC_SCENES:
        raise SceneError(f"unknown synthetic scene {name!r}; choose one of {', '.join(SYNTHETIC_SCENES)}")
    return SYNTHETIC_SCENES[name]()


def camera_positions(views: int, radius: float, layout: str) -> np.ndarray:
    """``(views, 3)`` camera centres at distance ``radius`` from the origin (layouts in the module docstring)."""
    index = np.arange(views) + 0.5
    if layout == "ring":
        azimuth = 2 * np.pi * np.arange(views) / max(views, 1)
        elevation = np.full(views, RING_ELEVATION)
        height = np.sin(elevation)
    elif layout in ("sphere", "hemisphere"):
        # Fibonacci lattice: equal-area rings in height, azimuth advancing by the golden angle.
        height = 1 - 2 * index / views if layout == "sphere" else 1 - index / views
        azimuth = np.pi * (3 - np.sqrt(5)) * np.arange(views)
    else:
        raise SceneError(f"unknown camera layout {layout!r}; choose one of {', '.join(LAYOUTS)}")
    ring_radius = np.sqrt(np.clip(1 - height**2, 0, 1))
    return radius * np.stack([ring_radius * np.cos(azimuth), ring_radius * np.sin(azimuth), height], axis=1)


def synthetic_cameras(
    views: int,
    size: int,
    *,
    layout: str = "sphere",
    radius: float = 4.0,
    camera_angle_x: float = NERF_SYNTHETIC_CAMERA_ANGLE_X,
) -> Cameras:
    """``views`` square ``size`` x ``size`` pinhole cameras around the origin, looking at it (float64)."""
    focal = 0.5 * size / math.tan(0.5 * camera_angle_x)
    poses = look_at(camera_positions(views, radius, layout), target=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0))
    return Cameras(poses, focal, focal, size / 2, size / 2, size, size)


def ray_offsets(per_axis: int) -> torch.Tensor:
    """``(K, 2)`` float64 ``(u, v)`` offsets from a pixel's corner of the rays :func:`render_scene`
    traces through it: the ``per_axis`` x ``per_axis`` grid at ``(i + 0.5) / per_axis``, row by
    row, and -- when ``per_axis > 1`` -- last, the centre ``(0.5, 0.5)`` (the depth and mask ray).
    With ``per_axis == 1`` the one ray is the centre."""
    inside = (torch.arange(per_axis, dtype=torch.float64) + 0.5) / per_axis
    down, across = torch.meshgrid(inside, inside, indexing="ij")
    offsets = torch.stack([across.flatten(), down.flatten()], dim=-1)
    if per_axis > 1:
        offsets = torch.cat([offsets, torch.tensor([[0.5, 0.5]], dtype=torch.float64)])
    return offsets


def render_scene(
    name: str, cameras: Cameras, supersampling: int = SUPERSAMPLING
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Render synthetic scene ``name`` through ``cameras`` (one image size): RGBA, depth, mask.

    Returns ``rgba`` float32 ``(N, H, W, 4)`` (straight colour, the mean of the hits among the
    pixel's ``supersampling**2`` rays; alpha the share of them that hit), ``depth`` float32
    ``(N, H, W)`` z-depth and ``mask`` bool ``(N, H, W)`` of the ray through the pixel's centre
    (0 and False where it misses).
    """
    if int(supersampling) != supersampling or not 1 <= supersampling <= 16:
        raise SceneError(f"supersampling must be an integer from 1 to 16, got {supersampling}")
    scene = _scene_named(name)
    cameras = cameras.to("cpu", torch.float64)
    if len({(int(w), int(h)) for w, h in zip(cameras.width, cameras.height)}) > 1:
        raise SceneError("render_scene needs cameras of one image size")
    width, height = int(cameras.width[0]), int(cameras.height[0])
    offsets = ray_offsets(int(supersampling))
    samples = int(supersampling) ** 2
    grid = pixel_centers(width, height, dtype=torch.float64)[:, :, None, :] - 0.5 + offsets   # (H, W, K, 2)
    views_per_batch = max(1, RAYS_PER_BATCH // grid[..., 0].numel())
    rgbas, depths, masks = [], [], []
    for first in range(0, len(cameras), views_per_batch):
        batch = cameras[first : first + views_per_batch]
        rays = batch.rays_through(torch.arange(len(batch))[:, None, None, None], grid)   # (V, H, W, K)
        color, distance = _trace(scene, rays.origins.reshape(-1, 3), rays.directions.reshape(-1, 3))
        shape = rays.axis_cosine.shape
        color, distance = color.reshape(*shape, 3)[..., :samples, :], distance.reshape(shape)
        hit = torch.isfinite(distance)
        hits = hit[..., :samples].sum(-1)
        # Missed rays are black (see _trace), so the sum over the pixel's rays is the hits' sum.
        rgb = color.sum(-2) / hits.clamp_min(1)[..., None]
        rgbas.append(torch.cat([rgb, (hits / samples)[..., None]], dim=-1))
        masks.append(hit[..., -1])
        depths.append(torch.where(hit[..., -1], distance[..., -1] * rays.axis_cosine[..., -1], 0.0))
    return torch.cat(rgbas).float().numpy(), torch.cat(depths).float().numpy(), torch.cat(masks).numpy()


def _nearest(objects, origins: torch.Tensor, directions: torch.Tensor) -> Hit:
    best = Hit(
        torch.full(origins.shape[:1], torch.inf, dtype=origins.dtype),
        torch.zeros_like(origins),
        torch.zeros_like(origins),
    )
    for shape in objects:
        hit = shape.intersect(origins, directions)
        closer = hit.distance < best.distance
        best = Hit(
            torch.where(closer, hit.distance, best.distance),
            torch.where(closer[:, None], hit.normal, best.normal),
            torch.where(closer[:, None], hit.albedo, best.albedo),
        )
    return best


def _trace(
    scene: SyntheticScene, origins: torch.Tensor, directions: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Colour ``(R, 3)`` (black where missed) and hit distance ``(R,)`` (inf where missed) of R rays."""
    hit = _nearest(scene.objects, origins, directions)
    surface = torch.isfinite(hit.distance)
    points = origins + hit.distance.nan_to_num(posinf=0)[:, None] * directions
    light = torch.full_like(hit.distance, scene.ambient)
    for direction, intensity in scene.lights:
        towards_light = torch.nn.functional.normalize(torch.tensor(direction, dtype=origins.dtype), dim=0)
        facing = (hit.normal @ towards_light).clamp_min(0)
        shadow_origins = points + 1e-6 * hit.normal
        blocked = torch.isfinite(
            _nearest(scene.objects, shadow_origins, towards_light.expand_as(points)).distance
        )
        light = light + intensity * facing * (~blocked)
    color = (hit.albedo * light[:, None]).clamp(0, 1)
    return torch.where(surface[:, None], color, torch.zeros_like(color)), hit.distance


def split_indices(views: int) -> dict[str, np.ndarray]:
    """Every k-th view "test" (0, k, 2k, ...), every k-th from k/2 "val", the rest "train" (k = 10 for >= 20 views)."""
    everything = np.arange(views)
    if views < 3:
        return {"train": everything}
    held = max(1, views // 10)
    stride = views // held
    test = np.arange(0, views, stride)[:held]
    val = np.arange(stride // 2, views, stride)[:held]
    train = np.setdiff1d(everything, np.concatenate([test, val]))
    return {"train": train, "val": val, "test": test}


def synthetic_scene(
    name: str = "cube",
    views: int = 100,
    size: int = 100,
    *,
    layout: str | None = None,
    radius: float = 4.0,
    camera_angle_x: float = NERF_SYNTHETIC_CAMERA_ANGLE_X,
    supersampling: int = SUPERSAMPLING,
) -> Scene:
    """Render synthetic scene ``name`` into an in-memory :class:`Scene` (images, depth, masks, splits).

    ``layout`` defaults to the scene's own ("sphere" for the cube, "hemisphere" over the ground).
    """
    if int(views) != views or views < 1:
        raise SceneError(f"views must be a positive integer, got {views}")
    if int(size) != size or not 1 <= size <= 4096:
        raise SceneError(f"size must be an integer from 1 to 4096, got {size}")
    if not radius > 0 or not 0 < camera_angle_x < math.pi:
        raise SceneError("radius must be positive and camera_angle_x in (0, pi)")
    builder = _scene_named(name)
    layout = layout or builder.layout
    cameras = synthetic_cameras(
        int(views), int(size), layout=layout, radius=radius, camera_angle_x=camera_angle_x
    )
    rgba, depth, mask = render_scene(name, cameras, supersampling)
    rgba8 = np.round(rgba * 255).astype(np.uint8)
    frames = [Frame(f"r_{i}", image=rgba8[i], depth=depth[i], mask=mask[i]) for i in range(len(cameras))]
    near = max(radius - builder.bounding_radius, 0.05 * radius)
    near_far = np.tile([near, radius + builder.bounding_radius], (len(cameras), 1))
    metadata = {"path": f"synthetic:{name}", "root": ".", "frames_listed": len(cameras), "layout": layout,
                "synthetic": {"scene": name, "supersampling": int(supersampling)}}
    return Scene(
        cameras, frames, split_indices(int(views)), None, near_far, padded_aabb(builder.aabb), metadata=metadata
    )


AABB_MARGIN = 0.1
"""Room around the objects in a synthetic scene's ``aabb``, as a fraction of their extent on each side."""


def padded_aabb(bounds) -> np.ndarray:
    """``(2, 3)``: the objects' ``bounds`` grown by :data:`AABB_MARGIN` of their extent on each side.

    The ``aabb`` is the region of interest a model reconstructs (the fast field's box). Exactly
    the objects' bounds would tell it where their surfaces are -- a cube's box *is* the cube --
    which no real capture's box does; the geometry benchmark scores against those surfaces.
    """
    low, high = np.array(bounds, dtype=np.float64)
    margin = AABB_MARGIN * (high - low)
    return np.stack([low - margin, high + margin])


def make_scene(
    name: str,
    out: str | os.PathLike[str],
    views: int = 100,
    size: int = 100,
    *,
    layout: str | None = None,
    radius: float = 4.0,
    camera_angle_x: float = NERF_SYNTHETIC_CAMERA_ANGLE_X,
    supersampling: int = SUPERSAMPLING,
    overwrite: bool = False,
) -> Path:
    """Render synthetic scene ``name`` and write it to ``out`` as a Blender-format dataset.

    ``pointfield scene make NAME --views V --size S --out DIR`` runs this. Returns ``out``.
    100 views of 100 x 100 take about a second.
    """
    scene = synthetic_scene(name, views, size, layout=layout, radius=radius, camera_angle_x=camera_angle_x,
                            supersampling=supersampling)
    written = write_scene(scene, out, "blender", overwrite=overwrite)
    with atomic_path(Path(written) / TRUTH_RECORD) as record:
        record.write_text(json.dumps(scene.metadata["synthetic"]) + "\n", encoding="utf-8")
    return written


def synthetic_source(scene: Scene) -> dict:
    """``{"scene": name, "supersampling": k}`` of a synthetic scene, in memory or as ``make_scene`` wrote it.

    Raises :class:`SceneError` for any other scene: only these have an analytic truth.
    """
    if "synthetic" in scene.metadata:
        return dict(scene.metadata["synthetic"])
    record = Path(scene.metadata.get("root", ".")) / TRUTH_RECORD
    where = scene.metadata.get("path", "scene")
    if not record.is_file():
        raise SceneError(f"{where}: not a synthetic scene (no {TRUTH_RECORD} beside it, as `scene make` writes)")
    try:
        source = json.loads(record.read_text(encoding="utf-8"))
        name, supersampling = str(source["scene"]), int(source.get("supersampling", SUPERSAMPLING))
    except (ValueError, KeyError, TypeError) as error:
        raise SceneError(f"{record}: expected {{\"scene\": name, \"supersampling\": k}} ({error})") from None
    _scene_named(name)  # an unknown name is refused here, naming the choices
    return {"scene": name, "supersampling": supersampling}


def synthetic_truth(scene: Scene, cameras: Cameras) -> np.ndarray:
    """What a synthetic ``scene`` looks like through any ``cameras``: float32 ``(N, H, W, 3)`` in [0, 1].

    Rendered by the same tracer, with the same supersampling, as the scene's own images, and
    composited onto the scene's background as :meth:`Scene.image` composites them: the truth a
    model's render from those cameras is scored against. The cameras must share one image size.

    Example::

        scene = read_scene("cube-dataset")                       # written by `scene make cube`
        near = synthetic_cameras(8, 100, radius=0.65 * 4.0)      # nearer than its cameras
        truth = synthetic_truth(scene, near)                     # (8, 100, 100, 3)
    """
    source = synthetic_source(scene)
    rgba, _, _ = render_scene(source["scene"], cameras, source["supersampling"])
    alpha = rgba[..., 3:]
    return (rgba[..., :3] * alpha + scene.background * (1 - alpha)).astype(np.float32)
