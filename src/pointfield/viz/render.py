"""Pictures of point clouds: a small, deterministic, pure-numpy point renderer.

:func:`render_cloud` turns a cloud into an ``(H, W, 3)`` uint8 image in four steps:

1. **Viewpoint.** A perspective camera looks at the centre of the cloud's robust box (its bounds
   without stray outliers, see :func:`_robust_box`) from azimuth 45 degrees and elevation 28
   degrees about the up axis — or from near the sensor, azimuth 20 and elevation 12, for camera
   frames (up ``-y``), whose far side is empty — and the focal length is chosen so that the
   robust box of the projected points fills the frame with a 4 % margin.
2. **Colour.** The ``colors`` field when there is one, else ``intensity``, else the height along
   the up axis; or whatever ``color_by`` names (see :func:`colour_source`).
3. **Visibility.** Each point covers a disc of ``point_size`` pixels. The nearest point wins each
   pixel, ties going to the lower index: each point gets an integer key ordered as (depth,
   index), each pixel keeps the smallest key landing on it (``np.minimum.at``), and a minimum
   filter over the disc grows single pixels into discs. This is "sort by (pixel, depth), keep
   the first" without the sort — no last-write-wins, the image is the same on every run. A
   second pass with wider discs fills the gaps between random points (:func:`_nearest_per_pixel`).
4. **Shading.** Eye-dome lighting (Boucheny 2009, as in CloudCompare and Potree) darkens a pixel
   by ``exp(-EDL_STRENGTH * mean_k max(0, log z - log z_k))`` over its 8 neighbours k, which
   outlines silhouettes and creases from the depth image alone, plus a mild fog with depth.

The up axis, when not given, is guessed by :func:`guess_up_axis`. Unless ``point_size`` is given,
discs are sized from the spacing of the projected points (:func:`_automatic_point_size`). Meshes
are drawn as their surface: 3 area-weighted samples per image pixel (:meth:`Mesh.sample_surface`,
seed 0) coloured by height or by the samples' face normals; a mesh coloured by a per-vertex field
(its ``colors``, ``intensity``, ...) is drawn as its vertices, which carry that field. Clouds above
2,000,000 finite points are drawn from a fixed-seed random subset of that many.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pointfield.atomic import atomic_path
from pointfield.clouds.cloud import PointCloud, Records
from pointfield.clouds.formats import read
from pointfield.clouds.mesh import Mesh
from pointfield.errors import PointfieldError

MAX_POINTS = 2_000_000
MESH_SAMPLES_PER_PIXEL = 3  # enough that the side facing the camera is closed at 3x3 discs
# (azimuth, elevation) in degrees of the viewpoint; camera frames are seen from near the camera.
VIEW_ANGLES_DEG = (45.0, 28.0)
CAMERA_FRAME_VIEW_ANGLES_DEG = (20.0, 12.0)
FIELD_OF_VIEW_DEG = 40.0  # only places the camera; the focal length is then fitted to the frame
FRAME_MARGIN = 0.04
ROBUST_PERCENTILES = (1.0, 99.0)
OUTLIER_REACH = 0.25  # points this fraction of the percentile span beyond it still count
# Discs grow up to 1/25 of the image's smaller side (24 px at 800x600), so that a sparse cloud
# still looks like a surface, and never below 9 px.
MAX_POINT_SIZE_FRACTION = 1 / 25
SPACING_TO_POINT_SIZE = 3.0
HOLE_DEPTH_RATIO = 0.05  # a pixel 5 % deeper than the surface around it is a hole in it
EDL_STRENGTH = 120.0
FOG = 0.3  # the farthest visible point is darkened by this fraction
HEIGHT_COLORMAP = "turbo"
FIELD_COLORMAP = "viridis"
CATEGORY_COLORMAP = "tab20"
MAX_CATEGORIES = 20  # integer fields with at most this many values are coloured as categories

# z is "clearly smallest" when its extent is below this fraction of the smaller of x and y.
FLAT_RATIO = 0.5
# Formats whose convention is z up: LAS and E57 (geodetic elevation), OFF (ModelNet's objects).
Z_UP_FORMATS = frozenset({"las", "e57", "off"})

UP_AXES = ("x", "y", "z", "-x", "-y", "-z")
# For each up axis, the side of the cloud a viewer at azimuth 0 stands on: +z for y up (OpenGL,
# models face the viewer), -y for z up, and -z for -y up (a camera frame: the sensor's side).
_FRONT = {
    "x": (0, 0, 1),
    "y": (0, 0, 1),
    "z": (0, -1, 0),
    "-x": (0, 0, 1),
    "-y": (0, 0, -1),
    "-z": (0, 1, 0),
}


def axis_vector(axis: str) -> np.ndarray:
    """The unit vector ``(3,)`` of ``"x" | "y" | "z"`` with an optional leading ``-``."""
    if axis not in UP_AXES:
        raise PointfieldError(f"unknown axis {axis!r}; expected one of {', '.join(UP_AXES)}")
    vector = np.zeros(3)
    vector["xyz".index(axis[-1])] = -1.0 if axis.startswith("-") else 1.0
    return vector


def guess_up_axis(cloud: PointCloud) -> str:
    """The axis that points up in ``cloud``, guessed from what the file is and how it is shaped.

    In order:

    - organised clouds (an (H, W) grid, both above 1) are depth-camera frames: x right,
      **y down**, z forward, so up is ``"-y"``;
    - LAS / E57 files (elevation is z) and OFF files (ModelNet objects stand on z): ``"z"``;
    - a cloud whose robust z extent is below ``FLAT_RATIO`` (0.5) of the smaller of its x and y
      extents is a lidar sweep or a terrain tile: ``"z"``;
    - a cloud wholly in front of the origin along z and farther from it than its own depth
      (``z_min > z_max - z_min``) is a camera frame too, as PCL's Kinect captures are: ``"-y"``;
    - anything else follows the graphics convention of PLY / PCD models: ``"y"``.
    """
    if cloud.shape is not None and min(cloud.shape) > 1:
        return "-y"
    if cloud.metadata.get("format") in Z_UP_FORMATS:
        return "z"
    finite = _finite_points(cloud)
    if len(finite) == 0:
        return "y"
    low, high = _robust_box(finite)
    extent = high - low
    if extent[2] < FLAT_RATIO * min(extent[0], extent[1]):
        return "z"
    if low[2] > 0 and low[2] > extent[2]:
        return "-y"
    return "y"


def colour_source(cloud: PointCloud, color_by: str | None = None) -> str:
    """What the points are coloured by: ``"colors"``, ``"normals"``, ``"height"`` or a field name.

    ``None`` picks ``colors`` when the cloud has them, else ``intensity``, else ``height``.
    Scalar fields are mapped through a colour map over their 2nd..98th percentiles (integer
    fields with at most 20 distinct values, such as labels, get one colour per value); normals
    are shown as RGB ``(n + 1) / 2``.
    """
    if color_by is None:
        if _is_rgb(cloud.fields.get("colors")):
            return "colors"
        if _is_scalar(cloud.fields.get("intensity")):
            return "intensity"
        return "height"
    if color_by == "height":
        return color_by
    if color_by not in cloud.fields:
        offered = ", ".join(["height", *cloud.fields])
        raise PointfieldError(f"no field {color_by!r} to colour by; this cloud offers: {offered}")
    values = cloud.fields[color_by]
    if (color_by in ("colors", "normals") and _is_rgb(values)) or _is_scalar(values):
        return color_by
    raise PointfieldError(
        f"field {color_by!r} has shape {values.shape[1:]} and dtype {values.dtype} per point; "
        f"colour by a numeric scalar field, colors, normals or height"
    )


def _is_rgb(values: np.ndarray | None) -> bool:
    """An ``(N, 3)`` or ``(N, 4)`` numeric field."""
    return (
        values is not None
        and values.ndim == 2
        and values.shape[1] in (3, 4)
        and values.dtype.kind in "biuf"
    )


def _is_scalar(values: np.ndarray | None) -> bool:
    """A numeric field with one value per point, ``(N,)`` or ``(N, 1)``."""
    return (
        values is not None and values.dtype.kind in "biuf" and int(np.prod(values.shape[1:])) == 1
    )


def render_cloud(
    cloud: PointCloud,
    width: int = 800,
    height: int = 600,
    up: str | None = None,
    color_by: str | None = None,
    point_size: float | None = None,
    background: tuple[int, int, int] = (255, 255, 255),
) -> np.ndarray:
    """Draw ``cloud`` from a sensible viewpoint; returns an ``(height, width, 3)`` uint8 image.

    ``up`` is ``"x" | "y" | "z"`` (optionally ``-``-prefixed), guessed by :func:`guess_up_axis`
    when None. ``color_by`` is passed to :func:`colour_source`. ``point_size`` is the diameter of
    each point's disc in pixels; None sizes the discs from the spacing of the projected points so
    that surfaces look closed. Points with a NaN or infinite coordinate are skipped; a cloud with
    no finite point gives a blank image.

    Example::

        >>> image = render_cloud(pointfield.read("scan.pcd"), width=400, height=300)
        >>> image.shape, image.dtype
        ((300, 400, 3), dtype('uint8'))
    """
    if isinstance(cloud, Records):
        raise PointfieldError(f"{len(cloud)} records without x/y/z coordinates: nothing to draw")
    if width < 1 or height < 1:
        raise PointfieldError(f"image size must be positive, got {width}x{height}")
    up = up or guess_up_axis(cloud)
    up_vector = axis_vector(up)  # validates ``up`` before any work
    source = colour_source(cloud, color_by)
    if isinstance(cloud, Mesh) and len(cloud.faces) and source in ("height", "normals"):
        try:
            cloud = cloud.sample_surface(MESH_SAMPLES_PER_PIXEL * width * height, seed=0)
        except ValueError:
            pass  # no area to sample, or faces out of range: the vertices are all there is
    image = np.empty((height, width, 3), np.uint8)
    image[:] = background

    keep = np.flatnonzero(np.isfinite(cloud.points).all(axis=1))
    if len(keep) > MAX_POINTS:
        keep = np.sort(np.random.default_rng(0).choice(keep, MAX_POINTS, replace=False))
    if len(keep) == 0:
        return image
    points = cloud.points[keep].astype(np.float64)
    colours = point_colours(
        source, points, {k: v[keep] for k, v in cloud.fields.items()}, up_vector
    )

    rotation, eye = _look_at(points, up)
    camera = (points - eye) @ rotation.T  # x right, y up, z depth
    in_front = camera[:, 2] > 1e-6 * np.abs(camera[:, 2]).max()
    camera, colours = camera[in_front], colours[in_front]
    if len(camera) == 0:
        return image
    column, row = _project(camera, width, height)
    depth = camera[:, 2]

    nearest = _nearest_per_pixel(column, row, depth, width, height, point_size)
    covered = nearest >= 0
    depth_image = np.full((height, width), np.inf)
    depth_image[covered] = depth[nearest[covered]]
    shade = (_eye_dome_shade(depth_image) * _fog(depth_image))[covered]
    image[covered] = np.round(255 * colours[nearest[covered]] * shade[:, None]).clip(0, 255)
    return image


def point_colours(
    source: str, points: np.ndarray, fields: dict[str, np.ndarray], up_vector: np.ndarray
) -> np.ndarray:
    """``(N, 3)`` float32 RGB in [0, 1] per point, from ``source`` (see :func:`colour_source`)."""
    if source == "colors":
        return normalised_colours(fields["colors"])
    if source == "normals":
        normals = np.nan_to_num(fields["normals"][:, :3].astype(np.float64))
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
        return ((normals + 1) / 2).astype(np.float32)
    if source == "height":
        return _colour_map(points @ up_vector, HEIGHT_COLORMAP)
    values = fields[source].reshape(len(points))
    if values.dtype.kind in "biu":
        categories, category_of = np.unique(values, return_inverse=True)
        if len(categories) <= MAX_CATEGORIES:
            return _lookup_table(CATEGORY_COLORMAP, MAX_CATEGORIES)[category_of]
    return _colour_map(values.astype(np.float64), FIELD_COLORMAP)


def normalised_colours(colors: np.ndarray) -> np.ndarray:
    """RGB(A) colours of any dtype as ``(N, 3)`` float32 in [0, 1]; alpha is dropped.

    uint8 is divided by 255. Other integers are divided by 255 when no value exceeds 255 (LAS
    files often store 8-bit colours in uint16), else by 65535 when none exceeds that, else by the
    largest value. Floats are taken as [0, 1] when none exceeds 1, as [0, 255] when none exceeds
    255, else divided by the largest value. NaN becomes 0.
    """
    rgb = colors[:, :3]
    if rgb.dtype == np.uint8:
        return rgb.astype(np.float32) / 255
    values = np.nan_to_num(rgb.astype(np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    largest = values.max() if values.size else 0.0
    if rgb.dtype.kind == "f" and largest <= 1.0:
        scale = 1.0
    elif largest <= 255:
        scale = 255.0
    elif largest <= 65535 and rgb.dtype.kind in "iu":
        scale = 65535.0
    else:
        scale = largest
    return (values / scale).clip(0, 1).astype(np.float32)


def _colour_map(values: np.ndarray, colormap: str) -> np.ndarray:
    """Scalars to RGB through ``colormap``, stretched over their 2nd..98th percentiles."""
    finite = values[np.isfinite(values)]
    if len(finite) == 0:
        return np.full((len(values), 3), 0.5, np.float32)
    low, high = np.percentile(finite, [2, 98])
    if high <= low:
        low, high = finite.min(), finite.max()
    scaled = (values - low) / (high - low) if high > low else np.full(len(values), 0.5)
    index = np.round(np.nan_to_num(scaled, nan=0.0).clip(0, 1) * 255).astype(np.intp)
    return _lookup_table(colormap, 256)[index]


def _lookup_table(colormap: str, size: int) -> np.ndarray:
    """``(size, 3)`` float32 RGB samples of a matplotlib colour map."""
    from matplotlib import colormaps

    cmap = colormaps[colormap].resampled(size)
    return cmap(np.arange(size))[:, :3].astype(np.float32)


def _finite_points(cloud: PointCloud) -> np.ndarray:
    return cloud.points[np.isfinite(cloud.points).all(axis=1)]


def _robust_box(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-column ``(low, high)`` bounds that leave out stray outliers but no part of the shape.

    From at most 100,000 evenly strided rows: the 1st and 99th percentiles p1, p99, widened by
    a quarter of their span on each side and clipped to the real extremes, so points within
    ``0.25 (p99 - p1)`` of the bulk (a tail, an ear) stay in and lone far points do not.
    """
    stride = max(1, len(points) // 100_000)
    sample = points[::stride].astype(np.float64)
    low, high = np.percentile(sample, ROBUST_PERCENTILES, axis=0)
    reach = (high - low) * OUTLIER_REACH
    return np.maximum(sample.min(axis=0), low - reach), np.minimum(sample.max(axis=0), high + reach)


def _look_at(points: np.ndarray, up: str) -> tuple[np.ndarray, np.ndarray]:
    """Camera rotation (rows: right, up, forward) and eye position for the standard viewpoint.

    The eye is on the ray from the box centre towards
    ``cos(el) (cos(az) front + sin(az) side) + sin(el) up`` with ``side = up x front``, at the
    distance where a sphere around the box fits a ``FIELD_OF_VIEW_DEG`` cone, so that every
    point of the box is in front of it.
    """
    low, high = _robust_box(points)
    centre = (low + high) / 2
    radius = max(
        float(np.linalg.norm(high - low)) / 2, 1e-9 * max(1.0, float(np.abs(centre).max()))
    )
    up_vector = axis_vector(up)
    front = np.asarray(_FRONT[up], float)
    side = np.cross(up_vector, front)
    az, el = np.radians(CAMERA_FRAME_VIEW_ANGLES_DEG if up == "-y" else VIEW_ANGLES_DEG)
    towards_eye = np.cos(el) * (np.cos(az) * front + np.sin(az) * side) + np.sin(el) * up_vector
    eye = centre + towards_eye * radius / np.sin(np.radians(FIELD_OF_VIEW_DEG) / 2)
    forward = -towards_eye
    right = np.cross(forward, up_vector)
    right /= np.linalg.norm(right)
    return np.stack([right, np.cross(right, forward), forward]), eye


def _project(camera: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Continuous pixel coordinates ``(column, row)`` with the focal length fitted to the frame.

    The pinhole projection ``(x / z, y / z)`` is scaled by the largest focal length that keeps
    the robust box of the projected points inside the image less a margin, and centred.
    """
    ratios = camera[:, :2] / camera[:, 2:]
    low, high = _robust_box(ratios)
    span = high - low
    usable = np.array([width, height]) * (1 - 2 * FRAME_MARGIN)
    with np.errstate(divide="ignore"):
        focal = float(np.min(np.where(span > 0, usable / span, np.inf)))
    if not np.isfinite(focal):  # a single point, or all on one line of sight
        focal = min(width, height) / 2
    middle = (low + high) / 2
    column = width / 2 + focal * (ratios[:, 0] - middle[0])
    row = height / 2 - focal * (ratios[:, 1] - middle[1])
    return column, row


def _disc_offsets(point_size: float) -> np.ndarray:
    """``(K, 2)`` integer (row, column) offsets of the pixels within a disc of that diameter."""
    reach = int(np.ceil(point_size / 2))
    dy, dx = np.mgrid[-reach : reach + 1, -reach : reach + 1]
    inside = dy**2 + dx**2 <= (point_size / 2) ** 2
    inside[reach, reach] = True
    return np.column_stack([dy[inside], dx[inside]])


def _depth_index_keys(depth: np.ndarray) -> np.ndarray:
    """int64 keys ordered as the pairs (depth, index): the smaller key is the nearer point.

    The low bits hold the point's index; the high bits hold its depth quantised to the
    remaining 2^(62 - index bits) levels between the nearest and farthest point (about 10^12
    levels for 2 million points), so two points only tie when their depths agree to that
    precision, and then the lower index wins. Comparing keys replaces sorting by depth.
    """
    index_bits = max(1, int(len(depth) - 1).bit_length())
    levels = 2 ** (62 - index_bits) - 1
    near, far = float(depth.min()), float(depth.max())
    scaled = (depth - near) / (far - near) if far > near else np.zeros_like(depth)
    quantised = np.floor(scaled * levels).astype(np.int64)
    return (quantised << index_bits) | np.arange(len(depth), dtype=np.int64)


def _nearest_per_pixel(
    column: np.ndarray,
    row: np.ndarray,
    depth: np.ndarray,
    width: int,
    height: int,
    point_size: float | None,
) -> np.ndarray:
    """``(height, width)`` index of the nearest point covering each pixel, -1 where none does.

    A point at pixel p covers the pixels of a disc around p. The winner of a pixel is the point
    with the smallest (depth, index) key among those whose disc covers it: that is the minimum
    of the single-pixel key image (``np.minimum.at``, exact whatever the order of the points)
    over the disc's footprint, a minimum filter.

    Randomly spread points leave small gaps between their discs, through which the far side
    of a surface shows. A second pass with discs twice as wide fills them: where its winner is
    more than ``HOLE_DEPTH_RATIO`` nearer than the first pass's, the pixel was a hole in a nearer
    surface and takes the second pass's point; so does an empty pixel enclosed by covered ones
    (:func:`_enclosed`). Other empty pixels stay empty, so outlines stay sharp.
    """
    largest = max(9.0, min(width, height) * MAX_POINT_SIZE_FRACTION)
    reach = int(np.ceil(largest))  # room for the hole-filling discs, twice the largest
    padded_h, padded_w = height + 2 * reach, width + 2 * reach
    col = np.floor(column).astype(np.int64) + reach
    rw = np.floor(row).astype(np.int64) + reach
    on_canvas = (col >= 0) & (col < padded_w) & (rw >= 0) & (rw < padded_h)
    keys = _depth_index_keys(depth)
    empty = np.iinfo(np.int64).max
    key_image = np.full(padded_h * padded_w, empty, np.int64)
    np.minimum.at(key_image, rw[on_canvas] * padded_w + col[on_canvas], keys[on_canvas])
    key_image = key_image.reshape(padded_h, padded_w)

    if point_size is None:
        point_size = _automatic_point_size(key_image < empty)
    point_size = float(np.clip(point_size, 1.0, largest))
    index_mask = (1 << max(1, int(len(depth) - 1).bit_length())) - 1

    def splat(size: float) -> np.ndarray:
        nearest = np.full((height, width), empty, np.int64)
        for dy, dx in _disc_offsets(size):
            window = key_image[reach + dy : reach + dy + height, reach + dx : reach + dx + width]
            np.minimum(nearest, window, out=nearest)
        return np.where(nearest < empty, nearest & index_mask, -1)

    nearest = splat(point_size)
    wide = splat(2 * point_size)
    covered = nearest >= 0
    hole = np.zeros_like(covered)
    hole[covered] = depth[nearest[covered]] > depth[wide[covered]] * (1 + HOLE_DEPTH_RATIO)
    hole |= ~covered & _enclosed(covered, int(np.ceil(point_size)))
    nearest[hole] = wide[hole]
    return nearest


def _enclosed(covered: np.ndarray, distance: int) -> np.ndarray:
    """Pixels with a covered pixel ``distance`` away in each of the four axis directions."""
    padded = np.pad(covered, distance)
    height, width = covered.shape
    enclosed = np.ones_like(covered)
    for dy, dx in ((-distance, 0), (distance, 0), (0, -distance), (0, distance)):
        enclosed &= padded[
            distance + dy : distance + dy + height, distance + dx : distance + dx + width
        ]
    return enclosed


def _automatic_point_size(hit: np.ndarray) -> float:
    """Disc diameter from the typical spacing s of the projected points: ``3 s``.

    The image is cut into b x b pixel blocks; a block holding c pixels with a point has a local
    spacing of ``b / sqrt(c)``, and s is the median of that over the points (each block weighted
    by c), so that the dense parts of a cloud set the size and a few sparse far points do not.
    b is the smallest of 4, 8, 16, 32 that is at least twice s: smaller blocks would miss the
    gaps between sparse points. Random points need discs well over s across to close a surface,
    and the hidden back of a surface lands in the counts too, halving the apparent spacing;
    3 s leaves few holes (a dense cloud, s = 1, gets 3x3 squares).
    """
    if not hit.any():
        return 1.0
    for block in (4, 8, 16, 32):
        h, w = hit.shape[0] // block * block, hit.shape[1] // block * block
        counts = hit[:h, :w].reshape(h // block, block, w // block, block).sum(axis=(1, 3))
        counts = np.sort(counts[counts > 0])
        if len(counts) == 0:
            continue
        # The block holding the median point: where the cumulative count passes half the total.
        cumulative = np.cumsum(counts)
        median_count = counts[np.searchsorted(cumulative, cumulative[-1] / 2)]
        spacing = block / np.sqrt(median_count)
        if spacing <= block / 2:
            break
    return SPACING_TO_POINT_SIZE * spacing


def _eye_dome_shade(depth_image: np.ndarray) -> np.ndarray:
    """Eye-dome lighting factor in (0, 1] per pixel from an ``(H, W)`` depth image (inf = empty).

    ``exp(-EDL_STRENGTH * mean_k max(0, log z - log z_k))`` over the 8 neighbours k at a 1-pixel
    distance; an empty neighbour counts as infinitely far, so it never darkens.
    """
    finite = np.isfinite(depth_image)
    log_depth = np.log(np.where(finite, depth_image, 1.0))
    # An empty pixel is -inf as the centre (it is not shaded) and +inf as a neighbour, so that
    # every difference below is finite or -inf and max(0, .) drops what does not count.
    centre = np.where(finite, log_depth, -np.inf)
    padded = np.pad(np.where(finite, log_depth, np.inf), 1, constant_values=np.inf)
    height, width = depth_image.shape
    response = np.zeros_like(log_depth)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dy or dx:
                neighbour = padded[1 + dy : 1 + dy + height, 1 + dx : 1 + dx + width]
                response += np.maximum(0, centre - neighbour)
    return np.exp(-EDL_STRENGTH * response / 8)


def _fog(depth_image: np.ndarray) -> np.ndarray:
    """``1 - FOG * t`` with t the depth's position between the nearest and farthest pixel."""
    finite = np.isfinite(depth_image)
    if not finite.any():
        return np.ones_like(depth_image)
    near, far = depth_image[finite].min(), depth_image[finite].max()
    t = (depth_image - near) / (far - near) if far > near else np.zeros_like(depth_image)
    return 1 - FOG * np.where(finite, t, 0)


def image_grid(
    images: Sequence[np.ndarray],
    labels: Sequence[str] | None = None,
    columns: int | None = None,
    background: tuple[int, int, int] = (255, 255, 255),
) -> np.ndarray:
    """Tile ``(H_i, W_i, 3)`` uint8 images into one contact sheet, a label under each.

    Cells are as large as the largest image; ``columns`` defaults to ``ceil(sqrt(count))``.
    """
    from PIL import Image, ImageDraw

    if not images:
        raise ValueError("image_grid needs at least one image")
    columns = columns or int(np.ceil(np.sqrt(len(images))))
    rows = -(-len(images) // columns)
    cell_h = max(image.shape[0] for image in images)
    cell_w = max(image.shape[1] for image in images)
    label_h = 22 if labels else 0
    sheet = Image.new("RGB", (columns * cell_w, rows * (cell_h + label_h)), background)
    draw = ImageDraw.Draw(sheet)
    for i, image in enumerate(images):
        top, left = (i // columns) * (cell_h + label_h), (i % columns) * cell_w
        sheet.paste(Image.fromarray(image), (left, top))
        if labels:
            draw.text((left + 8, top + cell_h + 4), labels[i], fill=(40, 40, 40))
    return np.asarray(sheet)


def save_image(path: str | os.PathLike[str], image: np.ndarray) -> Path:
    """Write an ``(H, W, 3)`` uint8 image as PNG, atomically; returns the path."""
    from PIL import Image

    path = Path(path)
    with atomic_path(path) as tmp:
        Image.fromarray(np.ascontiguousarray(image)).save(tmp, format="PNG")
    return path


def render_file(
    path: str | os.PathLike[str],
    out: str | os.PathLike[str],
    width: int = 800,
    height: int = 600,
    up: str | None = None,
    color_by: str | None = None,
    point_size: float | None = None,
    **read_options: Any,
) -> Path:
    """Read a cloud file, draw it with :func:`render_cloud` and save the PNG at ``out``.

    The Python form of ``pointfield cloud render FILE --out OUT``.
    """
    cloud = read(path, **read_options)
    try:
        image = render_cloud(cloud, width, height, up, color_by, point_size)
    except PointfieldError as error:
        raise PointfieldError(f"{path}: {error}") from None
    return save_image(out, image)
