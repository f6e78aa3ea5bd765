"""Meshes straight from a radiance field's density: marching cubes on sigma (``--method density``).

::

    mesh = mesh_from_density(load_run("runs/lego-ngp"), resolution=256)   # or: nerf export RUN --mesh --method density

For a bounded field run -- the hash-grid field (``ngp``) of an object in a box, or TinyNeRF /
NeRF trained on a scene with one -- the density is known at every point, so the surface needs
no fused depth (the TSDF route of :mod:`pointfield.geometry.meshes` builds it from rendered
depth instead); the training views are rendered only coarsely, to learn what they saw:

1. Sample the density sigma(x) at the voxel centres ``low + (i + 0.5) voxel`` of a grid over
   the box (``resolution`` voxels along its longest side; by default the field's own box),
   without gradients, on the run's device, a slab of voxels at a time. It is the density the
   renders see (:func:`density_field`); the grid is padded with one voxel of zero density on
   every side (nothing is rendered outside the box), so a surface cut by the box is closed.
2. Fill what no training view sees (:func:`fill_unseen`): the inside of a solid object is
   whatever density the field was left with, pinned by no loss, and meshes as foam. The
   training views' median depth, rendered at most ``VISIBILITY_PIXELS`` across, says what each
   view saw; a voxel far enough behind the surface in every view that holds it is filled.
   (Filling only what the matter encloses is not enough: one gap in the shell joins the foam
   to the outside. The textured-cube field of the 77f39f1 geometry record had one, a patch of
   a face left transparent over matter 0.1 to 0.2 deeper, and 69 % of its density mesh lay
   inside the cube.)
3. Marching cubes (scikit-image) at the level sigma = ``threshold``; faces wound to face out,
   where the density falls.
4. Colour each vertex with what a camera looking at it along its inward normal sees: the model
   renders the ray from ``COLOUR_RAY_VOXELS`` voxels outside the vertex to as many inside, and
   its colour over a black background is divided by its opacity (the mean colour of the matter
   the ray meets).

The default threshold is instant-ngp's (its mesh export's 2.5), made independent of the scene's
scale: instant-ngp measures density per unit of its normalised coordinates, in which a bounded
object's box is the unit cube, so 2.5 there is ``2.5 / L`` per world unit for a box of longest
side ``L`` -- the density at which matter as thick as the whole box would be 92 % opaque
(``1 - e^-2.5``). A trained field is far denser than that within a voxel or two of its
surfaces and far thinner in empty space, so the surface moves little with the level; lower
levels keep more of a half-trained field's surface, higher ones drop its haze. The level is
set by the field's own box, not by ``--crop``, so cropping only crops. (A level tied to the
grid, such as ``ln 2 / voxel`` -- a voxel of matter half opaque -- would move the surface of a
soft field when the resolution changes, and at 64^3 punches holes in a field trained for a
few hundred steps.)
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch

from pointfield.clouds.mesh import Mesh
from pointfield.errors import PointfieldError
from pointfield.fields.field import render_in_chunks
from pointfield.fields.nerf import NeRF, TinyNeRF
from pointfield.fields.ngp import InstantNGP
from pointfield.fields.rays import RayBundle
from pointfield.fields.run import RENDER_CHUNK, FieldRun
from pointfield.fields.scene_box import scene_bounds
from pointfield.geometry.clouds import cameras_of, rendered_depth_maps
from pointfield.geometry.tsdf import grid_shape, pixels_under
from pointfield.scenes.cameras import Cameras

BYTES_PER_VOXEL = 4 + 8
"""The padded float32 density grid that marching cubes reads, and :func:`fill_unseen`'s int64
index of each voxel under the level (marching cubes' output grows with the surface only)."""
DENSITY_CHUNK = 1 << 17
"""Points per density query: bounds the field's working memory."""
COLOUR_RAY_VOXELS = 2.0
"""A vertex's colour ray starts this many voxels outside it and ends as many inside."""
INSTANT_NGP_THRESHOLD = 2.5
"""instant-ngp's marching-cubes level, in density per unit of its normalised coordinates (box side 1)."""
UNSEEN_MARGIN_VOXELS = 1.5
"""A voxel is unseen only this many voxels or more behind every view's surface: the band at the
surface is the level's to place. (On the 77f39f1 record's textured-cube field, margins of 1.5
and 3 voxels gave the same Chamfer distance, 0.43 % of the diagonal; a wall thinner than the
margin keeps its inner side.)"""
VISIBILITY_PIXELS = 128
"""The training views are rendered for :func:`fill_unseen` at most this many pixels across."""
VISIBILITY_CHUNK = 1 << 22
"""Voxels tested against every view at once: bounds :func:`fill_unseen`'s working memory."""
SEES_NOTHING = 1e-3
"""A colour ray less opaque than this met no matter: its vertex is grey."""

Density = Callable[[torch.Tensor], torch.Tensor]
"""World positions ``(N, 3)`` -> density ``(N,)``, in inverse world units."""


def density_field(scene_run: Any) -> tuple[Density, np.ndarray]:
    """The run's density at world points, as its renders see it, and the ``(2, 3)`` box it lives in.

    - ``ngp`` (bounded): the field's density inside occupied cells of its occupancy grid, 0
      elsewhere (the ray marcher never samples there) and outside its box; the box is the
      model's own.
    - ``tiny``: its field; ``nerf``: its fine field (the one that renders). Their density does
      not depend on the view direction. The box is the scene's
      (:func:`~pointfield.fields.scene_box.scene_bounds`), which must be bounded.

    Raises :class:`PointfieldError` for a splat run and for a field of an unbounded scene
    (contracted space has no box to grid): their meshes come from ``--method tsdf``.
    """
    if not isinstance(scene_run, FieldRun):
        raise _no_density(scene_run, f"this is a {scene_run.model_name} run, which has no density field")
    model = scene_run.module
    if isinstance(model, InstantNGP):
        if model.unbounded:
            raise _no_density(scene_run, "this ngp run is of an unbounded scene (contracted space)")
        return _occupied_density(model), model.box.detach().cpu().double().numpy()
    if isinstance(model, NeRF):
        field = model.fine
    elif isinstance(model, TinyNeRF):
        field = model.field
    else:
        raise _no_density(scene_run, f"its model {type(model).__name__} has no known density field")
    box, unbounded = scene_bounds(scene_run.scene)
    if unbounded:
        raise _no_density(scene_run, "its scene is unbounded (photos without alpha)")

    def density(positions: torch.Tensor) -> torch.Tensor:
        any_direction = torch.zeros_like(positions)
        any_direction[:, 2] = 1.0
        return field(positions, any_direction)[0]

    return density, np.asarray(box, np.float64)


def _no_density(scene_run: Any, reason: str) -> PointfieldError:
    return PointfieldError(
        f"{scene_run.path}: density meshing needs a field run of a bounded scene (tiny, nerf or ngp on an "
        f"object in a box); {reason}; use --method tsdf, which fuses rendered depth"
    )


def _occupied_density(model: InstantNGP) -> Density:
    def density(positions: torch.Tensor) -> torch.Tensor:
        sigma = torch.zeros(len(positions), device=positions.device)
        occupied = model.grid.occupied_at(positions)
        sigma[occupied] = model.density_at(positions[occupied]).float()
        return sigma

    return density


def training_cameras(scene_run: Any, frames: int | None = None) -> Cameras:
    """The run's training cameras (``frames`` of them, evenly spaced, if given) on its device,
    downscaled to at most ``VISIBILITY_PIXELS`` across."""
    cameras = cameras_of(scene_run, "dataset", frames)
    longest = int(torch.maximum(cameras.width, cameras.height).max())
    return cameras.scaled(max(1, math.ceil(longest / VISIBILITY_PIXELS)))


def default_threshold(box: np.ndarray) -> float:
    """Instant-ngp's level, ``2.5 / L`` for a field whose ``(2, 3)`` box has longest side ``L`` (module docstring).

    Example::

        >>> default_threshold(np.array([[-1.5, -1.5, -1.5], [1.5, 1.5, 1.5]]))
        0.8333333333333334
    """
    return INSTANT_NGP_THRESHOLD / float(np.max(np.asarray(box[1]) - np.asarray(box[0])))


@torch.no_grad()
def sample_density(
    density: Density,
    low: Sequence[float],
    voxel: float,
    shape: tuple[int, int, int],
    device: torch.device | str = "cpu",
    chunk: int = DENSITY_CHUNK,
    progress: bool = False,
) -> np.ndarray:
    """``density`` at the centres ``low + (i + 0.5) voxel`` of a ``shape`` grid, padded by one voxel of 0.

    Returns float32 ``(X + 2, Y + 2, Z + 2)``: voxel ``(i, j, k)`` of the grid is entry
    ``(i + 1, j + 1, k + 1)``. Evaluated an x-slab at a time, ``chunk`` points per call.
    """
    from tqdm.auto import tqdm

    size_x, size_y, size_z = shape
    padded = np.zeros((size_x + 2, size_y + 2, size_z + 2), np.float32)
    low = torch.as_tensor(np.asarray(low, np.float64), dtype=torch.float32, device=device)
    j, k = torch.meshgrid(torch.arange(size_y, device=device), torch.arange(size_z, device=device), indexing="ij")
    slab = torch.stack([torch.zeros_like(j), j, k], dim=-1).reshape(-1, 3).float()
    for i in tqdm(range(size_x), desc="density", unit="slab", disable=not progress):
        slab[:, 0] = i
        points = low + (slab + 0.5) * voxel
        values = torch.cat([density(part) for part in points.split(chunk)])
        padded[i + 1, 1:-1, 1:-1] = values.reshape(size_y, size_z).float().cpu().numpy()
    return padded


def mesh_from_density(
    scene_run: Any,
    low: Sequence[float] | None = None,
    high: Sequence[float] | None = None,
    resolution: int = 256,
    threshold: float | None = None,
    *,
    frames: int | None = None,
    chunk: int = DENSITY_CHUNK,
    memory_limit: int | None = None,
    progress: bool = False,
) -> Mesh:
    """The level ``sigma = threshold`` of a field run's density over a box, as a coloured mesh (module docstring).

    ``low``, ``high``: the box's ``(3,)`` corners (default: the field's own box,
    :func:`density_field`); ``resolution`` voxels along its longest side; ``threshold``
    (inverse world units) defaults to :func:`default_threshold` of the field's box. Vertices are
    float64 world points with uint8 ``colors``; faces face out. ``frames``: how many training
    views (evenly spaced; default all) judge what was seen (:func:`fill_unseen`): each is one
    coarse render, so fewer are faster, and a hollow no kept view looks into is filled. Floating pieces are kept (the
    exporter drops them). Raises :class:`PointfieldError` for a run without a bounded density
    field, a grid larger than ``memory_limit`` bytes and a density that never crosses the level.
    ``chunk``: points per density query.
    """
    from skimage.measure import marching_cubes

    density, box = density_field(scene_run)
    low = box[0] if low is None else np.asarray(low, np.float64)
    high = box[1] if high is None else np.asarray(high, np.float64)
    shape, voxel = grid_shape(low, high, resolution)
    needed = int(np.prod([size + 2 for size in shape])) * BYTES_PER_VOXEL
    if memory_limit is not None and needed > memory_limit:
        fits = int(resolution * (memory_limit / needed) ** (1 / 3))
        raise PointfieldError(
            f"a {resolution}^3 density grid ({shape[0]}x{shape[1]}x{shape[2]} voxels) needs "
            f"{needed / 2**30:.1f} GiB, more than the {memory_limit / 2**30:.1f} GiB allowed; "
            f"pass --resolution {fits} or less, or a smaller --crop box"
        )
    threshold = default_threshold(box) if threshold is None else float(threshold)
    if not threshold > 0:
        raise PointfieldError(f"the density threshold must be positive, got {threshold}")
    grid = sample_density(density, low, voxel, shape, scene_run.device, chunk, progress)
    if grid.max() <= threshold:
        raise PointfieldError(
            f"{scene_run.path}: the density never reaches the threshold {threshold:.4g} inside the box "
            f"(its largest value is {grid.max():.4g}); nothing to mesh (lower --threshold)"
        )
    cameras = training_cameras(scene_run, frames)
    depth_maps = [depth for depth, _ in rendered_depth_maps(scene_run, cameras, progress=progress, depth="median")]
    fill_unseen(grid, threshold, low, voxel, cameras, depth_maps, progress=progress)
    # Density rises inwards; "ascent" winds the faces (right-hand rule) and points the normals outwards.
    vertices, faces, normals, _ = marching_cubes(grid, level=threshold, gradient_direction="ascent",
                                                 allow_degenerate=False)
    world = low + (vertices.astype(np.float64) - 1 + 0.5) * voxel  # - 1: the padding
    colours = surface_colours(scene_run.module, world, normals.astype(np.float64), COLOUR_RAY_VOXELS * voxel,
                              scene_run.device)
    return Mesh(world, {"colors": colours}, faces=faces.astype(np.int64))


@torch.no_grad()
def fill_unseen(
    grid: np.ndarray,
    threshold: float,
    low: Sequence[float],
    voxel: float,
    cameras: Cameras,
    depth_maps: Sequence[torch.Tensor],
    margin: float = UNSEEN_MARGIN_VOXELS,
    progress: bool = False,
) -> np.ndarray:
    """Raise to ``2 threshold``, in place, every voxel of ``grid`` under the level that no view sees.

    ``grid`` is :func:`sample_density`'s padded ``(X + 2, Y + 2, Z + 2)`` array over voxels of
    side ``voxel`` from ``low``; ``depth_maps`` holds each camera's z-depth ``(H, W)`` of what it
    rendered at least half opaque, 0 where it rendered nothing (the transmittance never fell
    below 1/2). A view sees a voxel centre that projects into its image in front of the surface
    there, or through a pixel that shows nothing. Unseen: inside at least one view's image, and
    more than ``margin`` voxels behind the surface in every view whose image holds it. So that
    an edge is never filled on the strength of one pixel, each pixel's surface is the farthest
    of its 3 x 3 neighbourhood. Voxels no image holds, and the padding, are left as they are.
    Returns ``grid``.
    """
    from tqdm.auto import tqdm

    inner = grid[1:-1, 1:-1, 1:-1]
    device = cameras.device
    cameras = cameras.to(dtype=torch.float32)
    farthest = []
    for depth in depth_maps:
        surface = torch.where(depth > 0, depth, torch.inf).to(device, torch.float32)
        farthest.append(torch.nn.functional.max_pool2d(surface[None, None], 3, stride=1, padding=1)[0, 0].reshape(-1))
    low = torch.as_tensor(np.asarray(low, np.float64), dtype=torch.float32, device=device)
    candidates = torch.from_numpy(np.flatnonzero(inner <= threshold)).to(device)
    unseen = []
    for flat in tqdm(candidates.split(VISIBILITY_CHUNK), desc="visibility", unit="chunk", disable=not progress):
        centres = low + (torch.stack(torch.unravel_index(flat, inner.shape), dim=1).float() + 0.5) * voxel
        in_an_image = torch.zeros(len(flat), dtype=torch.bool, device=device)
        for camera, surface in enumerate(farthest):
            pixel, inside, z_depth = pixels_under(cameras[[camera]], centres)
            seen = inside & (z_depth < surface[pixel] + margin * voxel)
            in_an_image |= inside
            flat, centres, in_an_image = flat[~seen], centres[~seen], in_an_image[~seen]
        unseen.append(flat[in_an_image])
    unseen = torch.cat(unseen).cpu().numpy()
    inner[np.unravel_index(unseen, inner.shape)] = 2 * threshold
    return grid


@torch.no_grad()
def surface_colours(
    model: torch.nn.Module,
    points: np.ndarray,
    normals: np.ndarray,
    reach: float,
    device: torch.device | str = "cpu",
    chunk: int = RENDER_CHUNK,
) -> np.ndarray:
    """uint8 ``(V, 3)``: what a camera looking at each surface point along its inward normal sees.

    ``points``, ``normals``: ``(V, 3)`` world points and their outward unit normals. The ray
    ``x + reach n - t n``, ``t`` in ``[0, 2 reach]``, is rendered over black, and its colour
    ``C = sum_i w_i c_i`` divided by its opacity ``sum_i w_i`` (grey where it meets nothing),
    ``chunk`` rays at a time.
    """
    inward = -torch.nn.functional.normalize(torch.as_tensor(normals, dtype=torch.float32), dim=-1)
    origins = torch.as_tensor(points, dtype=torch.float32) - reach * inward
    near, far = torch.zeros(len(points)), torch.full((len(points),), 2 * reach)
    rays = RayBundle(origins, inward, near, far).to(device)
    rendered = render_in_chunks(model, rays, None, chunk=chunk)
    opacity = rendered["opacity"][:, None]
    colours = torch.where(opacity > SEES_NOTHING, rendered["rgb"] / opacity.clamp_min(SEES_NOTHING),
                          torch.full_like(rendered["rgb"], 0.5))
    return (colours.clamp(0, 1) * 255).round().to(torch.uint8).cpu().numpy()
