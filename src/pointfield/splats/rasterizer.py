"""The differentiable tile-based Gaussian rasterizer, in plain PyTorch (any device).

One entry point, :func:`rasterization`, in the image of gsplat's: it takes the splats'
parameters and a batch of cameras and returns colour, depth and alpha images whose gradients
flow back to every parameter. It runs on CPU, CUDA and MPS alike, because it is made only of
ordinary tensor operations; :mod:`pointfield.splats.reference` is the slow, per-splat
version it is tested against.

Conventions (the same as gsplat and the original 3D Gaussian splatting):

- ``viewmats`` ``(C, 4, 4)`` are **world-to-camera** matrices in the OpenCV convention (x right,
  y down, the camera looking down +z): ``x_cam = R x_world + t``.
  ``pointfield.scenes.Cameras.world_to_camera()`` gives them.
- ``Ks`` ``(C, 3, 3)`` are pinhole intrinsics ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` in pixels;
  the centre of pixel ``(u, v)`` is at ``(u + 0.5, v + 0.5)``.
- ``quats`` ``(N, 4)`` are **wxyz** quaternions (normalised here), ``scales`` ``(N, 3)``
  standard deviations (not logs), ``opacities`` ``(N,)`` in [0, 1].

The algorithm, step by step:

1. **Project** (EWA splatting, Zwicker et al. 2002): the camera-space covariance
   ``W Sigma W^T`` is mapped to the image by the Jacobian of the perspective projection at the
   mean, ``J = [[fx/z, 0, -fx x/z^2], [0, fy/z, -fy y/z^2]]``, giving
   ``Sigma_2d = J W Sigma W^T J^T + 0.3 I`` (computed as ``M M^T`` with ``M = J W R S``, since
   ``Sigma = R S S^T R^T``). The 0.3 px^2 dilation (``screen_dilation``) keeps every splat at
   least about a pixel wide (no aliasing holes). As in 3DGS, ``x/z`` and ``y/z`` are clamped
   to 1.3x the field of view inside ``J`` so splats far outside the view do not explode. Splats with
   ``z <= near_plane`` are dropped; ``meta["radii"]`` is the 3-sigma half-width
   ``ceil(3 sqrt(lambda_max(Sigma_2d)))``, 0 for splats off screen.
2. **Bound** what each splat can reach. With ``sigma = 0.5 d^T Sigma_2d^-1 d`` at offset ``d``
   from the mean, a pixel takes a splat only inside its 3-sigma ellipse (``sigma <= 4.5``) and
   where ``alpha >= 1/255``, i.e. ``sigma <= ln(255 o)``: together, inside the ellipse
   ``sigma <= t = min(4.5, ln(255 o))`` (:func:`splat_extents`). Splats with ``o < 1/255``
   reach no pixel and are culled.
3. **Bin** splats into ``tile_size`` x ``tile_size`` tiles (4 x 4 by default): one
   (splat, tile) pair per tile whose pixel centres the ellipse of step 2 meets, found exactly
   row of tiles by row of tiles (:func:`tile_intersections`), so that few of the pixels
   evaluated in step 5 are wasted.
4. **Sort** the pairs by tile, and within a tile by camera-space depth z (front first).
5. **Composite** each pixel front to back:
   ``alpha_i = min(0.99, o_i exp(-sigma_i))``, skipped when ``alpha_i < 1/255`` or outside
   3 sigma; ``C = sum_i c_i alpha_i T_i`` with ``T_i = prod_{j<i} (1 - alpha_j)``; a pixel stops
   at the first splat that would bring its transmittance below 1e-4 (that splat is not added).
   Depth is ``sum_i z_i alpha_i T_i`` and alpha ``1 - T_final = sum_i alpha_i T_i``. Median
   depth, when asked for, is the ``z_i`` of the first splat after which the transmittance is
   0.5 or less (``T_i > 0.5 >= T_{i+1}``: the accumulated alpha reaches one half there), and 0
   where it never is -- the depth of a surface, where the expected depth of a semi-transparent
   or doubled one falls between the layers.

Steps 2 to 4 only choose which (pixel, splat) pairs are evaluated; step 5 drops every pair
that does not count, so the image does not depend on the tiling or the batching.

Step 5 is evaluated for whole tiles at once: the splats of a batch of tiles, of similar lengths,
are gathered into a padded block of ``tiles x L x pixels`` (at most ``max_block_elements``)
and the front-to-back product is a ``cumprod`` along L; L is walked in slices of
``splats_per_slice`` so that a tile whose pixels have all stopped is dropped early. It comes in
two implementations, which give the same images to rounding:

- :func:`composite_tiles`, when a gradient is wanted: out-of-place operations that autograd
  differentiates;
- :func:`composite_tiles_no_grad`, whenever no gradient can flow (under ``torch.no_grad()``, or
  when no input requires one), as for rendering a trained model: in place in two reused
  buffers, the block laid out ``tiles x pixels x L`` so that the scan runs along contiguous
  memory, the three tests of step 5 as ``torch.threshold`` passes, and colour, depth and alpha
  summed by one batched matrix product -- several times faster on a CPU.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import torch
import torch.nn.functional as F

from pointfield.compiling import CompiledOrEager
from pointfield.fields.encodings.spherical_harmonics import sh_to_rgb
from pointfield.fields.rendering import MEDIAN_OPACITY
from pointfield.splats.gaussians import quaternion_to_rotation

TILE_SIZE = 4
# The variance (px^2) added to every splat's screen covariance, so that none is thinner than
# a pixel: 3DGS's and gsplat's ``eps2d``. Mip-Splatting's 2D filter uses 0.1 (with the
# antialiased mode's opacity factor), which draws a surface of small splats closer to its
# true outline; the ``screen_dilation`` argument chooses it.
SCREEN_DILATION = 0.3
MIN_ALPHA = 1.0 / 255.0
MAX_ALPHA = 0.99
MIN_TRANSMITTANCE = 1e-4
SIGMA_EXTENT = 3.0
# Relative and absolute widening of the reach t of step 2 when binning: far more than any
# rounding error, far less than a pixel; the per-pixel tests of step 5 stay exact.
BOUND_SLACK = 1e-3
# A sigma past 0.5 * SIGMA_EXTENT^2 (the pixel is dropped anyway) whose exp(-sigma) is far from
# float32 underflow: exp() of denormal results is about a hundred times slower on x86.
SIGMA_CEILING = 20.0
# The compositing's blocks (tiles x L x pixels): with gradients autograd keeps several per
# slice, so their size bounds training memory; without, larger blocks mean fewer iterations.
BLOCK_ELEMENTS = 1 << 18
BLOCK_ELEMENTS_NO_GRAD = 1 << 20
# On a CUDA GPU each slice's dozen operations are kernel launches whose cost does not depend on
# the block, so small blocks leave it idle: at 800 x 800 with 100,000 random splats on an H200
# a training step took 1.11 s with 2^18-element blocks and 0.058 s with 2^24 (peak memory 2.56
# and 3.00 GiB), a render 95 and 36 ms with 2^20 and 2^24 (`make bench-gpu` measures this as
# its "blocks" part). Other GPUs (MPS) keep the CPU's sizes: not measured there.
GPU_BLOCK_ELEMENTS = 1 << 24


def rasterizer_mode(settings: dict[str, Any]) -> dict[str, Any]:
    """How splats are drawn, from a run's config or a splat file's header comment: ``antialiased``
    and ``screen_dilation``, keyword arguments of :func:`rasterization` (and of
    :func:`~pointfield.splats.run.render_views` and :func:`~pointfield.splats.run.render_camera`).

    A missing setting takes its old behaviour (runs made before it existed, and files from the
    original 3D Gaussian splatting code): classic mode, :data:`SCREEN_DILATION`.
    """
    return {"antialiased": bool(settings.get("antialiased", False)),
            "screen_dilation": float(settings.get("screen_dilation", SCREEN_DILATION))}


@dataclass
class Projection:
    """Splats projected into one camera (step 1); N entries, ``visible`` marks the kept ones.

    ``means2d`` ``(N, 2)`` pixel coordinates, ``conics`` ``(N, 3)`` the upper triangle
    ``(a, b, c)`` of ``Sigma_2d^-1``, ``depths`` ``(N,)`` camera z, ``radii`` ``(N,)`` the 3-sigma
    half-width in pixels (0 where not visible), ``visible`` ``(N,)`` bool, ``compensations``
    ``(N,)`` the antialiased mode's opacity factor ``sqrt(det(Sigma_2d - s I) / det(Sigma_2d))``, ``s`` the
    screen dilation.
    """

    means2d: torch.Tensor
    conics: torch.Tensor
    depths: torch.Tensor
    radii: torch.Tensor
    visible: torch.Tensor
    compensations: torch.Tensor


def project_gaussians(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    viewmat: torch.Tensor,
    K: torch.Tensor,
    width: int,
    height: int,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    screen_dilation: float = SCREEN_DILATION,
) -> Projection:
    """Project N Gaussians into one camera (``viewmat`` (4, 4) world-to-camera, ``K`` (3, 3)).

    See the module docstring, steps 1 and 2, for the formulas (``screen_dilation`` is step 1's 0.3).
    """
    rotation, translation = viewmat[:3, :3], viewmat[:3, 3]
    means_cam = means @ rotation.T + translation
    x, y, z = means_cam.unbind(-1)
    in_depth = (z > near_plane) & (z < far_plane)
    # Splats behind the camera still go through the arithmetic (masked afterwards), so give
    # them a harmless depth rather than dividing by zero.
    z_safe = torch.where(in_depth, z, torch.ones_like(z))
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]

    # Sigma_2d = J W R S (J W R S)^T: the splat's scaled axes, rotated into the camera
    # (W R S) then through the Jacobian, whose two rows are few enough to write out.
    axes = torch.einsum("ij,njk->nik", rotation, quaternion_to_rotation(quats) * scales[:, None, :])
    # The 1.3-field-of-view clamp of 3DGS / gsplat, applied to the Jacobian only.
    tan_fov_x, tan_fov_y = 0.5 * width / fx, 0.5 * height / fy
    limit_x_pos = (width - cx) / fx + 0.3 * tan_fov_x
    limit_x_neg = cx / fx + 0.3 * tan_fov_x
    limit_y_pos = (height - cy) / fy + 0.3 * tan_fov_y
    limit_y_neg = cy / fy + 0.3 * tan_fov_y
    tx = z_safe * torch.minimum(torch.maximum(x / z_safe, -limit_x_neg), limit_x_pos)
    ty = z_safe * torch.minimum(torch.maximum(y / z_safe, -limit_y_neg), limit_y_pos)
    # J = [[fx/z, 0, -fx tx/z^2], [0, fy/z, -fy ty/z^2]]
    row_x = (fx / z_safe)[:, None] * axes[:, 0] - (fx * tx / z_safe**2)[:, None] * axes[:, 2]
    row_y = (fy / z_safe)[:, None] * axes[:, 1] - (fy * ty / z_safe**2)[:, None] * axes[:, 2]
    a_undilated, b, c_undilated = (row_x * row_x).sum(-1), (row_x * row_y).sum(-1), (row_y * row_y).sum(-1)
    a, c = a_undilated + screen_dilation, c_undilated + screen_dilation
    determinant = a * c - b * b
    positive = determinant > 0
    determinant_safe = torch.where(positive, determinant, torch.ones_like(determinant))
    conics = torch.stack([c / determinant_safe, -b / determinant_safe, a / determinant_safe], dim=-1)

    means2d = torch.stack([fx * x / z_safe + cx, fy * y / z_safe + cy], dim=-1)
    middle = 0.5 * (a + c)
    largest_eigenvalue = middle + torch.sqrt(torch.clamp_min(middle * middle - determinant, 0.1))
    radii = torch.ceil(SIGMA_EXTENT * torch.sqrt(largest_eigenvalue.detach()))
    u, v = means2d.detach().unbind(-1)
    on_screen = (u + radii > 0) & (u - radii < width) & (v + radii > 0) & (v - radii < height)
    visible = in_depth & positive & on_screen
    # A disc seen edge on has an undilated determinant of about 0, which rounding can make
    # negative: the floor keeps sqrt's gradient finite there (0 through the clamp, not 0 x inf).
    compensations = torch.sqrt(torch.clamp_min((a_undilated * c_undilated - b * b) / determinant_safe, 1e-12))
    return Projection(means2d, conics, z, torch.where(visible, radii, torch.zeros_like(radii)), visible,
                      compensations)


_FUSED_PROJECT = CompiledOrEager(project_gaussians, "the splat projection")


def rasterization(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    viewmats: torch.Tensor,
    Ks: torch.Tensor,
    width: int,
    height: int,
    *,
    sh_degree: int | None = None,
    backgrounds: torch.Tensor | None = None,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    tile_size: int = TILE_SIZE,
    max_block_elements: int | None = None,
    splats_per_slice: int = 64,
    backend: str = "auto",
    median_depth: bool = False,
    antialiased: bool = False,
    screen_dilation: float = SCREEN_DILATION,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, dict[str, torch.Tensor]]:
    """Render N Gaussians into C cameras; differentiable with respect to every tensor input.

    Arguments (conventions in the module docstring):

    - ``means`` ``(N, 3)``, ``quats`` ``(N, 4)`` wxyz, ``scales`` ``(N, 3)``, ``opacities`` ``(N,)``;
    - ``colors``: ``(N, D)`` per-splat values composited as they are (RGB, or any D features),
      or, with ``sh_degree`` given, SH coefficients ``(N, K, 3)`` evaluated per camera in the
      direction from the camera centre to each mean (:func:`pointfield.fields.encodings.spherical_harmonics.sh_to_rgb`);
    - ``viewmats`` ``(C, 4, 4)`` world-to-camera, ``Ks`` ``(C, 3, 3)``, image ``width`` x ``height``;
    - ``backgrounds`` ``(C, D)`` or ``(D,)``: added where the splats leave light through,
      ``colour + T_final * background`` (default: none, i.e. black);
    - ``tile_size``, ``max_block_elements``, ``splats_per_slice``: the tiles' width in pixels
      and the memory and early-termination granularity of the compositing (they change speed,
      never the result; ``max_block_elements`` defaults to :data:`GPU_BLOCK_ELEMENTS` on CUDA,
      elsewhere to :data:`BLOCK_ELEMENTS` with gradients and :data:`BLOCK_ELEMENTS_NO_GRAD` without);
    - ``backend``: whether rendering compiles its kernels (:mod:`pointfield.compiling`);
    - ``median_depth``: also render the median depth (step 5), into ``meta["median_depths"]``
      (no gradient; off by default, so that training does not pay for it);
    - ``antialiased``: gsplat's "antialiased" mode (Mip-Splatting's 2D filter): each opacity is
      scaled by ``sqrt(det(Sigma_2d - s I) / det(Sigma_2d))``, so that the dilation of step 1
      spreads a splat's coverage instead of adding to it. Without it a splat much smaller than
      a pixel still covers one, and a surface of such splats renders fatter than it is by about
      a pixel at its outline;
    - ``screen_dilation``: ``s``, the variance in px^2 that step 1 adds to every ``Sigma_2d``
      (default :data:`SCREEN_DILATION`, 0.3 as 3DGS; Mip-Splatting's 2D filter uses 0.1).

    Where no gradient can flow (under ``torch.no_grad()``, or when no input requires one), the
    compositing takes its in-place path, :func:`composite_tiles_no_grad`: the same images, to
    rounding, several times faster; and the projection and the tile binning's per-splat
    arithmetic run compiled where ``backend`` (:mod:`pointfield.compiling`) allows.

    Returns ``(colors (C, H, W, D), depths (C, H, W), alphas (C, H, W), meta)``. ``depths`` is
    the alpha-weighted sum of camera z (divide by ``alphas`` for the expected depth). ``meta``
    holds ``means2d`` ``(C, N, 2)`` (call ``retain_grad()`` on it before ``backward`` to get the
    screen-space gradients densification uses), ``radii`` ``(C, N)`` (0: not visible),
    ``depths`` ``(C, N)``, and with ``median_depth`` ``median_depths`` ``(C, H, W)``: camera z of
    each pixel's first splat after which its transmittance is 0.5 or less, 0 where none is.

    Example::

        >>> means = torch.tensor([[0.0, 0.0, 3.0]])
        >>> quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]])
        >>> scales = torch.full((1, 3), 0.2)
        >>> K = torch.tensor([[[50.0, 0, 16], [0, 50.0, 16], [0, 0, 1]]])
        >>> rgb, depth, alpha, meta = rasterization(means, quats, scales, torch.tensor([0.9]),
        ...     torch.tensor([[1.0, 0.5, 0.0]]), torch.eye(4)[None], K, 32, 32)
        >>> rgb.shape, round(float(alpha[0, 16, 16]), 3)
        (torch.Size([1, 32, 32, 3]), 0.88)
    """
    inputs = (means, quats, scales, opacities, colors, viewmats, Ks, backgrounds)
    differentiable = torch.is_grad_enabled() and any(t is not None and t.requires_grad for t in inputs)
    camera_count = viewmats.shape[0]
    # Compiled only for rendering: with gradients it would need compiled autograd as well.
    fused = backend if not differentiable else "eager"
    if max_block_elements is None:
        max_block_elements = (GPU_BLOCK_ELEMENTS if means.device.type == "cuda"
                              else BLOCK_ELEMENTS if differentiable else BLOCK_ELEMENTS_NO_GRAD)
    if not differentiable:
        # Plain tensors, not the model's nn.Parameters: dynamo keeps a parameter's shape static,
        # so every change of the splat count (densification) would compile the projection again,
        # and past RECOMPILE_LIMIT of them it would run eagerly for good.
        means, quats, scales = means.detach(), quats.detach(), scales.detach()
    projections = [
        _FUSED_PROJECT(fused, means.device, means, quats, scales, viewmats[i], Ks[i], width, height,
                       near_plane, far_plane, screen_dilation)
        for i in range(camera_count)
    ]
    # One (C, N, 2) tensor that the compositing reads from, so its .grad is the screen-space
    # gradient of every camera.
    means2d = torch.stack([p.means2d for p in projections])
    images, depth_images, alpha_images, median_images = [], [], [], []
    for i, projection in enumerate(projections):
        if sh_degree is not None:
            rotation, translation = viewmats[i, :3, :3], viewmats[i, :3, 3]
            camera_centre = -rotation.T @ translation
            view_colors = sh_to_rgb(colors, means - camera_centre, sh_degree)
        else:
            view_colors = colors
        background = None
        if backgrounds is not None:
            background = backgrounds if backgrounds.ndim == 1 else backgrounds[i]
        composite = composite_tiles if differentiable else composite_tiles_no_grad
        view_opacities = opacities * projection.compensations if antialiased else opacities
        image, depth, alpha, median = composite(
            means2d[i], projection.conics, view_opacities, view_colors, projection.depths,
            projection.visible, width, height, background, tile_size, max_block_elements,
            splats_per_slice, backend, median_depth,
        )
        images.append(image)
        depth_images.append(depth)
        alpha_images.append(alpha)
        median_images.append(median)
    meta = {
        "means2d": means2d,
        "radii": torch.stack([p.radii for p in projections]),
        "depths": torch.stack([p.depths for p in projections]),
    }
    if median_depth:
        meta["median_depths"] = torch.stack(median_images)
    return torch.stack(images), torch.stack(depth_images), torch.stack(alpha_images), meta


def splat_reach(opacities: torch.Tensor) -> torch.Tensor:
    """How far each splat reaches, as the largest ``sigma``: ``(N,)``, negative for none.

    A pixel at offset ``d`` from the mean gets ``sigma = 0.5 d^T Sigma_2d^-1 d`` and takes the
    splat only when ``sigma <= 4.5`` (3 sigma) and ``o exp(-sigma) >= 1/255``, i.e. when
    ``sigma <= t = min(4.5, ln(255 o))``. Returns ``t``, made a little larger (``BOUND_SLACK``)
    where it is not negative, so that rounding in the per-pixel tests never reaches past it.
    """
    opacities = opacities.detach().to(_precise(opacities.device))
    limit = torch.clamp_max(torch.log(opacities / MIN_ALPHA), 0.5 * SIGMA_EXTENT**2)
    return torch.where(limit >= 0, limit * (1 + BOUND_SLACK) + BOUND_SLACK, limit)


def tile_intersections(
    means2d: torch.Tensor, conics: torch.Tensor, opacities: torch.Tensor, depths: torch.Tensor,
    visible: torch.Tensor, width: int, height: int, tile_size: int = TILE_SIZE, backend: str = "auto",
) -> tuple[torch.Tensor, torch.Tensor]:
    """Steps 2 to 4: the (splat, tile) pairs where the splat reaches a pixel, sorted by tile then depth.

    A splat reaches the ellipse ``0.5 d^T Sigma_2d^-1 d <= t`` (``t`` from :func:`splat_reach`).
    Writing the conic as ``(A, B, C)``, the ellipse's row at height ``dy`` spans
    ``dx = -(B / A) dy +- sqrt(2t / A - (AC - B^2) / A^2 dy^2)``; its right end is concave in
    ``dy`` and largest at ``dy_r = Sigma_xy sqrt(2t / Sigma_xx)`` (the left end: smallest at
    ``-dy_r``). So for each row of tiles the splat spans, the x-range of the ellipse within that
    band of pixel-centre rows is the right end at ``dy_r`` clamped into the band, and the left
    end likewise: a pair is made exactly when the ellipse meets a tile's pixel centres' box.

    Returns ``(splat_ids (P,), tile_ids (P,))`` int64, ``tile_id = ty * tiles_x + tx``. The
    per-splat and per-band arithmetic (:func:`_bands`, :func:`_tile_spans`) is compiled where
    ``backend`` (:mod:`pointfield.compiling`) allows.
    """
    device = means2d.device
    tiles_x = math.ceil(width / tile_size)
    reach = splat_reach(opacities)
    ids = torch.nonzero(visible & (reach >= 0)).squeeze(1)
    # Depth order first; the stable sort by tile below keeps it within each tile.
    ids = ids.index_select(0, torch.argsort(depths.detach().index_select(0, ids), stable=True))
    # float64: for long thin splats AC - B^2 cancels badly in float32.
    mean_x, mean_y, a, b, c = _gather([*means2d.detach().T, *conics.detach().T], ids, _precise(device))
    with torch.no_grad():  # integer bounds: nothing to differentiate, one compiled kernel per dtype
        row_first, row_last, band_first, bands, *ellipse = _FUSED_BANDS(
            backend, device, mean_y, a, b, c, reach.index_select(0, ids), height, tile_size)
        band_owner, band_row = _ranges(band_first, bands)
        tile_first, tiles = _FUSED_TILE_SPANS(
            backend, device, *_gather([mean_x, mean_y, *ellipse, row_first, row_last], band_owner), band_row,
            width, tile_size)
    pair_band, tile_ids = _ranges(band_row * tiles_x + tile_first, tiles)
    # Narrow keys sort faster on a CPU: int16 several times, int32 twice as fast as int64.
    key = torch.int16 if tiles_x * math.ceil(height / tile_size) <= torch.iinfo(torch.int16).max else torch.int32
    tile_ids, order = torch.sort(tile_ids.to(key), stable=True)
    return ids.index_select(0, band_owner).index_select(0, pair_band.index_select(0, order)), tile_ids.long()


def _bands(mean_y, a, b, c, reach, height: int, tile_size: int):
    """Per splat (conic ``(a, b, c)``, reach t): its pixel rows, its rows of tiles, and the ellipse's shape.

    Returns ``row_first, row_last`` (pixel rows whose centres lie within the ellipse's y-extent),
    ``band_first, bands`` (the first row of tiles and how many), then ``slope = b / a``,
    ``width_at_centre = 2t / a``, ``narrowing = (ac - b^2) / a^2`` and ``right_dy`` (the ``dy_r``
    of :func:`tile_intersections`).
    """
    determinant = a * c - b * b
    reach_y = torch.sqrt(2 * reach * a / determinant)  # sqrt(2t Sigma_yy)
    right_dy = -b * torch.sqrt(2 * reach / (c * determinant))  # Sigma_xy sqrt(2t / Sigma_xx)
    row_first = torch.clamp(torch.ceil(mean_y - reach_y - 0.5), 0, height).long()
    row_last = torch.clamp(torch.floor(mean_y + reach_y - 0.5), -1, height - 1).long()
    band_first = torch.div(row_first, tile_size, rounding_mode="floor")
    bands = torch.where(row_first <= row_last, torch.div(row_last, tile_size, rounding_mode="floor") - band_first + 1, 0)
    return row_first, row_last, band_first, bands, b / a, 2 * reach / a, determinant / (a * a), right_dy


def _tile_spans(mean_x, mean_y, slope, width_at_centre, narrowing, right_dy, row_first, row_last, band_row,
                width: int, tile_size: int):
    """Per (splat, row of tiles) band: the first tile column the ellipse meets there, and how many."""
    # The band's pixel-centre rows, as offsets dy from the mean.
    dy_low = torch.maximum(row_first, band_row * tile_size) + (0.5 - mean_y)
    dy_high = torch.minimum(row_last, band_row * tile_size + (tile_size - 1)) + (0.5 - mean_y)
    dy_right = torch.minimum(torch.maximum(right_dy, dy_low), dy_high)
    dy_left = torch.minimum(torch.maximum(-right_dy, dy_low), dy_high)
    x_high = mean_x - slope * dy_right + torch.sqrt(torch.clamp_min(width_at_centre - narrowing * dy_right**2, 0))
    x_low = mean_x - slope * dy_left - torch.sqrt(torch.clamp_min(width_at_centre - narrowing * dy_left**2, 0))
    column_first = torch.clamp(torch.ceil(x_low - 0.5), 0, width).long()
    column_last = torch.clamp(torch.floor(x_high - 0.5), -1, width - 1).long()
    tile_first = torch.div(column_first, tile_size, rounding_mode="floor")
    tiles = torch.where(column_first <= column_last,
                        torch.div(column_last, tile_size, rounding_mode="floor") - tile_first + 1, 0)
    return tile_first, tiles


_FUSED_BANDS = CompiledOrEager(_bands, "the splat binning")
_FUSED_TILE_SPANS = CompiledOrEager(_tile_spans, "the splat binning")


def _precise(device: torch.device) -> torch.dtype:
    """float64 for the bounds of step 2, except on MPS, which has no float64."""
    return torch.float32 if device.type == "mps" else torch.float64


def _gather(fields: list[torch.Tensor], index: torch.Tensor, dtype: torch.dtype | None = None) -> list[torch.Tensor]:
    """``[field[index] for field in fields]``, each contiguous (a gather of a (N, F) table is not)."""
    return [field.to(dtype or field.dtype).index_select(0, index) for field in fields]


def _ranges(first: torch.Tensor, counts: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The ranges ``first[i], first[i] + 1, .., first[i] + counts[i] - 1``, concatenated.

    Returns ``(owner, value)``, both ``(counts.sum(),)``: ``i`` and the integer, per element.
    """
    owner = torch.repeat_interleave(counts)
    start = torch.cumsum(counts, 0) - counts
    return owner, torch.arange(len(owner), device=counts.device) + (first - start).index_select(0, owner)


def composite_tiles(
    means2d: torch.Tensor,
    conics: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    depths: torch.Tensor,
    visible: torch.Tensor,
    width: int,
    height: int,
    background: torch.Tensor | None = None,
    tile_size: int = TILE_SIZE,
    max_block_elements: int = BLOCK_ELEMENTS,
    splats_per_slice: int = 64,
    backend: str = "auto",
    median_depth: bool = False,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """Steps 2 to 5 for one camera, differentiably: ``(colors (H, W, D), depths, alphas, median depths)``.

    Inputs per splat: ``means2d`` ``(N, 2)``, ``conics`` ``(N, 3)``, ``opacities`` ``(N,)``,
    ``colors`` ``(N, D)``, ``depths`` ``(N,)``, ``visible`` ``(N,)`` bool. Each batch of tiles
    walks its depth-sorted splats ``splats_per_slice`` at a time in ``(tiles, L, pixels)``
    blocks, carrying the transmittance from slice to slice, and drops a tile once every pixel
    of it has stopped (T < 1e-4) -- the early termination of the CUDA rasterizers, per tile.
    Each image is ``(H, W)`` but colour; the median depths are None unless ``median_depth``,
    and carry no gradient.
    """
    device, dtype = means2d.device, means2d.dtype
    channels = colors.shape[-1]
    pixels_per_tile = tile_size * tile_size
    tiles_x, tiles_y = math.ceil(width / tile_size), math.ceil(height / tile_size)
    splat_ids, tile_ids = tile_intersections(means2d, conics, opacities, depths, visible, width, height, tile_size,
                                             backend)
    per_tile = torch.bincount(tile_ids, minlength=tiles_x * tiles_y)
    tile_start = torch.cumsum(per_tile, 0) - per_tile
    offsets = torch.arange(tile_size, device=device, dtype=dtype) + 0.5  # pixel centres in a tile

    batch_tiles, color_blocks, depth_blocks, alpha_blocks, median_blocks = [], [], [], [], []
    for tiles, longest in _tile_batches(per_tile, splats_per_slice, pixels_per_tile, max_block_elements):
        count = len(tiles)
        color_sum = torch.zeros(count, pixels_per_tile, channels, device=device, dtype=colors.dtype)
        depth_sum = torch.zeros(count, pixels_per_tile, device=device, dtype=dtype)
        alpha_sum = torch.zeros(count, pixels_per_tile, device=device, dtype=dtype)
        median_sum = torch.zeros(count, pixels_per_tile, device=device, dtype=dtype) if median_depth else None
        # The front-to-back product so far, per pixel (not stopped at 1e-4: "counted" below
        # compares it with the threshold, which is the same test).
        transmittance = torch.ones(count, pixels_per_tile, device=device, dtype=dtype)
        live = torch.arange(count, device=device)  # tiles with splats left and light left
        for first in range(0, longest, splats_per_slice):
            live_tiles = tiles[live]
            slot = torch.arange(first, min(first + splats_per_slice, longest), device=device)
            present = slot[None, :] < per_tile[live_tiles][:, None]                  # (B, L)
            pair = (tile_start[live_tiles][:, None] + slot[None, :]).clamp_max(len(splat_ids) - 1)
            ids = splat_ids[pair]                                                    # (B, L)
            corner = torch.stack([live_tiles % tiles_x, live_tiles // tiles_x], dim=-1).to(dtype) * tile_size
            splat_means = means2d[ids]                                               # (B, L, 2)
            # A tile's pixels are a grid, so dx depends on the column only and dy on the row
            # only: (B, L, S) each, broadcast to (B, L, S, S) at the end.
            dx = (corner[:, None, 0:1] + offsets) - splat_means[..., 0:1]
            dy = (corner[:, None, 1:2] + offsets) - splat_means[..., 1:2]
            a, b, c = conics[ids][..., None].unbind(-2)                              # (B, L, 1) each
            # sigma = 0.5 d^T Sigma_2d^-1 d = 0.5 a dx^2 + b dx dy + 0.5 c dy^2
            sigma = (
                (0.5 * a * dx * dx)[..., None, :]
                + (0.5 * c * dy * dy)[..., :, None]
                + (b * dy)[..., :, None] * dx[..., None, :]
            ).flatten(-2)                                                            # (B, L, S * S)
            # Padding slots get opacity 0, hence alpha 0: they change nothing.
            splat_opacities = torch.where(present, opacities[ids], torch.zeros_like(opacities[ids]))
            alpha = torch.clamp_max(splat_opacities[..., None] * torch.exp(-sigma.clamp_max(SIGMA_CEILING)), MAX_ALPHA)
            inside = (sigma <= 0.5 * SIGMA_EXTENT**2) & (alpha >= MIN_ALPHA)
            alpha = torch.where(inside, alpha, torch.zeros_like(alpha))
            transmittance_after = torch.cumprod(1 - alpha, dim=1) * transmittance[live][:, None, :]
            # A pixel stops at the first splat that would bring T below 1e-4; T only falls,
            # so "not stopped yet" is "T after this splat still >= 1e-4".
            counted = transmittance_after >= MIN_TRANSMITTANCE
            # T before splat i is T after it divided by (1 - alpha_i) >= 0.01: no shifted copy.
            weights = alpha / (1 - alpha) * transmittance_after * counted          # (B, L, S * S)
            color_sum = color_sum.index_add(0, live, torch.einsum("blp,bld->bpd", weights, colors[ids]))
            depth_sum = depth_sum.index_add(0, live, torch.einsum("blp,bl->bp", weights, depths[ids]))
            alpha_sum = alpha_sum.index_add(0, live, weights.sum(1))
            if median_sum is not None:
                after = transmittance_after.detach()
                before = torch.cat([transmittance[live][:, None, :].detach(), after[:, :-1]], dim=1)
                crossing = (before > 1 - MEDIAN_OPACITY) & (after <= 1 - MEDIAN_OPACITY)    # (B, L, S * S)
                median_sum = median_sum.index_add(
                    0, live, torch.einsum("blp,bl->bp", crossing.to(dtype), depths[ids].detach()))
            transmittance = transmittance.index_copy(0, live, transmittance_after[:, -1])
            # Early termination: a tile is finished when its splats are, or its light is.
            more = (per_tile[live_tiles] > first + splats_per_slice) & (
                transmittance_after[:, -1] >= MIN_TRANSMITTANCE).any(1)
            live = live[more]
            if len(live) == 0:
                break
        batch_tiles.append(tiles)
        color_blocks.append(color_sum)
        depth_blocks.append(depth_sum)
        alpha_blocks.append(alpha_sum)
        median_blocks.append(median_sum)

    tile_count = tiles_x * tiles_y
    color_tiles = colors.new_zeros(tile_count, pixels_per_tile, channels)
    depth_tiles = means2d.new_zeros(tile_count, pixels_per_tile)
    alpha_tiles = means2d.new_zeros(tile_count, pixels_per_tile)
    median_tiles = means2d.new_zeros(tile_count, pixels_per_tile) if median_depth else None
    if batch_tiles:  # empty tiles stay 0
        filled = torch.cat(batch_tiles)
        color_tiles = color_tiles.index_copy(0, filled, torch.cat(color_blocks))
        depth_tiles = depth_tiles.index_copy(0, filled, torch.cat(depth_blocks))
        alpha_tiles = alpha_tiles.index_copy(0, filled, torch.cat(alpha_blocks))
        if median_tiles is not None:
            median_tiles = median_tiles.index_copy(0, filled, torch.cat(median_blocks))
    return _images(color_tiles, depth_tiles[..., None], alpha_tiles[..., None], background, tiles_x, width, height,
                   None if median_tiles is None else median_tiles[..., None])


def composite_tiles_no_grad(
    means2d: torch.Tensor,
    conics: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    depths: torch.Tensor,
    visible: torch.Tensor,
    width: int,
    height: int,
    background: torch.Tensor | None = None,
    tile_size: int = TILE_SIZE,
    max_block_elements: int = BLOCK_ELEMENTS_NO_GRAD,
    splats_per_slice: int = 64,
    backend: str = "auto",
    median_depth: bool = False,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """:func:`composite_tiles` where no gradient is wanted: the same images, computed in place.

    The same arguments, steps and batches; the differences are all for speed. Each slice is a
    ``(tiles, pixels, L)`` block, so that the scan along L runs over contiguous memory, and
    every pass over it writes into one of two buffers allocated per batch (fresh large tensors
    cost more than the arithmetic: allocation, page faults). The tests of step 5 are
    ``torch.threshold`` passes, exact (``x >= t`` is ``x > nextafter(t, -inf)``), in place of
    comparisons and masks, which PyTorch runs several times slower on a CPU. Colour, depth and
    alpha are summed by one batched matrix product of the weights with a per-splat table.
    """
    device, dtype = means2d.device, torch.promote_types(means2d.dtype, colors.dtype)
    channels = colors.shape[-1]
    pixels_per_tile = tile_size * tile_size
    tiles_x, tiles_y = math.ceil(width / tile_size), math.ceil(height / tile_size)
    splat_ids, tile_ids = tile_intersections(means2d, conics, opacities, depths, visible, width, height, tile_size,
                                             backend)
    per_tile = torch.bincount(tile_ids, minlength=tiles_x * tiles_y)
    tile_start = torch.cumsum(per_tile, 0) - per_tile
    # One row per splat: mean (2), -conic / 2 with b doubled (3), opacity, then the values
    # summed over a pixel's splats: colour (D), depth, 1 (for alpha). Then a padding row, of
    # opacity 0, that the slots past the end of a tile's list point to.
    splats = torch.cat([
        means2d, conics * torch.tensor([-0.5, -1.0, -0.5], device=device), opacities[:, None], colors,
        depths[:, None], torch.ones_like(depths)[:, None],
    ], dim=1).to(dtype)
    splats = torch.cat([splats, torch.zeros_like(splats[:1])])
    splat_ids = torch.cat([splat_ids, torch.tensor([len(opacities)], device=device)])
    padding_pair = len(splat_ids) - 1
    inside, visible_alpha, light_left = (
        float(torch.nextafter(torch.tensor(limit, dtype=dtype), torch.tensor(-math.inf, dtype=dtype)))
        for limit in (-0.5 * SIGMA_EXTENT**2, MIN_ALPHA, MIN_TRANSMITTANCE)
    )
    one = torch.ones((), device=device, dtype=dtype)
    offsets = torch.arange(tile_size, device=device, dtype=dtype)[:, None] + 0.5     # (S, 1)

    sums = torch.zeros(tiles_x * tiles_y, pixels_per_tile, channels + 2, device=device, dtype=dtype)
    medians = torch.zeros(tiles_x * tiles_y, pixels_per_tile, 1, device=device, dtype=dtype) if median_depth else None
    for tiles, longest in _tile_batches(per_tile, splats_per_slice, pixels_per_tile, max_block_elements):
        slots = min(splats_per_slice, longest)
        pixel_x = (tiles % tiles_x * tile_size).to(dtype)[:, None, None] + offsets      # (B, S, 1)
        pixel_y = (tiles // tiles_x * tile_size).to(dtype)[:, None, None] + offsets
        alpha_buffer = torch.empty(len(tiles), tile_size, tile_size, slots, device=device, dtype=dtype)
        scan_buffer = torch.empty(len(tiles), pixels_per_tile, slots + 1, device=device, dtype=dtype)
        transmittance = torch.ones(len(tiles), pixels_per_tile, 1, device=device, dtype=dtype)
        live = torch.arange(len(tiles), device=device)
        for first in range(0, longest, slots):
            count, live_tiles = len(live), tiles[live]
            slot = torch.arange(first, first + slots, device=device)
            pair = torch.where(slot < per_tile[live_tiles, None], tile_start[live_tiles, None] + slot, padding_pair)
            rows = splats.index_select(0, splat_ids.index_select(0, pair.flatten())).view(count, slots, -1)
            fields = rows.transpose(1, 2).contiguous()                               # (B, F, L)
            dx = pixel_x[live] - fields[:, 0:1]                                      # (B, S, L)
            dy = pixel_y[live] - fields[:, 1:2]
            # -sigma = -(0.5 a dx^2 + b dx dy + 0.5 c dy^2), as (B, S_y, S_x, L).
            alpha = alpha_buffer[:count]
            torch.add((fields[:, 4:5] * dy * dy)[:, :, None], (fields[:, 2:3] * dx * dx)[:, None], out=alpha)
            alpha.addcmul_((fields[:, 3:4] * dy)[:, :, None], dx[:, None])
            alpha = alpha.view(count, pixels_per_tile, slots)
            # Outside 3 sigma: -sigma -> -20, whose alpha the 1/255 test drops (and exp() then
            # never meets the slow denormals of arguments far below zero).
            F.threshold_(alpha, inside, -SIGMA_CEILING)
            alpha.exp_().mul_(fields[:, None, 5]).clamp_max_(MAX_ALPHA)
            F.threshold_(alpha, visible_alpha, 0.0)
            # scan[..., k + 1] = T after splat k = T_0 prod_{j <= k} (1 - alpha_j), set to 0 once
            # below 1e-4; the weight alpha_k T_k is alpha_k / (1 - alpha_k) times it.
            scan = scan_buffer[:count]
            scan[..., :1] = transmittance[live]
            torch.sub(one.expand_as(alpha), alpha, out=scan[..., 1:])
            weights = alpha.div_(scan[..., 1:])
            F.threshold_(scan.cumprod_(2), light_left, 0.0)
            weights.mul_(scan[..., 1:])
            sums.index_add_(0, live_tiles, torch.bmm(weights, rows[..., 6:]))
            if medians is not None:
                # T never rises: in a slice that takes it from above 0.5 to 0.5 or below, the splats
                # after which it is still above come first, and the one after them crosses. (Zeroing
                # T below 1e-4 moves no crossing: alpha <= 0.99 takes T from above 0.5 to >= 0.005.)
                half = 1 - MEDIAN_OPACITY
                still_above = (scan[..., 1:] > half).sum(dim=2)                              # (B, S * S)
                crosses = (scan[..., 0] > half) & (scan[..., -1] <= half)
                crossing_z = rows[..., -2].gather(1, still_above.clamp_max_(slots - 1))
                medians.index_add_(0, live_tiles, torch.where(crosses, crossing_z, 0.0)[..., None])
            transmittance[live] = scan[..., -1:]
            # Early termination: a tile is finished when its splats are, or its light is.
            more = (per_tile[live_tiles] > first + slots) & (scan[:, :, -1] > 0).any(1)
            live = live[more]
            if len(live) == 0:
                break

    return _images(*sums.split([channels, 1, 1], dim=-1), background, tiles_x, width, height, medians)


def _tile_batches(
    per_tile: torch.Tensor, splats_per_slice: int, pixels_per_tile: int, max_block_elements: int,
) -> Iterator[tuple[torch.Tensor, int]]:
    """The tiles that have splats, in batches of similar length: ``(tile ids (B,), longest)`` each.

    Tiles sorted by their number of splats are cut where a slice of the batch, padded to its
    longest tile (``tiles x min(length, splats_per_slice) x pixels``), would pass
    ``max_block_elements``; at least one tile per batch.
    """
    tile_order = torch.argsort(per_tile, stable=True)
    lengths = per_tile[tile_order].tolist()
    start = next((i for i, length in enumerate(lengths) if length > 0), len(lengths))
    while start < len(lengths):
        end = start + 1
        while end < len(lengths):
            # The batch's slices if tile `end` joined: padded to its length, the longest so far.
            if (end + 1 - start) * min(lengths[end], splats_per_slice) * pixels_per_tile > max_block_elements:
                break
            end += 1
        yield tile_order[start:end], lengths[end - 1]
        start = end


def _images(
    color_tiles: torch.Tensor, depth_tiles: torch.Tensor, alpha_tiles: torch.Tensor, background: torch.Tensor | None,
    tiles_x: int, width: int, height: int, median_tiles: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """Per-tile sums ``(tiles, S * S, D)``, ``(tiles, S * S, 1)`` x 2 (and median depths, or None)
    -> colour over the background, depth, alpha and median depth images ``(H, W, D)``, ``(H, W)`` x 3."""
    tile_size = math.isqrt(color_tiles.shape[1])
    tiles_y = color_tiles.shape[0] // tiles_x
    if background is not None:
        color_tiles = color_tiles + (1 - alpha_tiles) * background
    image = _untile(color_tiles, tiles_x, tiles_y, tile_size, color_tiles.shape[-1])[:height, :width]
    depth = _untile(depth_tiles, tiles_x, tiles_y, tile_size, 1)[:height, :width, 0]
    alpha = _untile(alpha_tiles, tiles_x, tiles_y, tile_size, 1)[:height, :width, 0]
    median = None if median_tiles is None else _untile(median_tiles, tiles_x, tiles_y, tile_size, 1)[:height, :width, 0]
    return image, depth, alpha, median


def _untile(values: torch.Tensor, tiles_x: int, tiles_y: int, tile_size: int, channels: int) -> torch.Tensor:
    """``(tiles, S * S, D)`` in row-major tile order -> ``(tiles_y * S, tiles_x * S, D)``."""
    blocks = values.reshape(tiles_y, tiles_x, tile_size, tile_size, channels)
    return blocks.permute(0, 2, 1, 3, 4).reshape(tiles_y * tile_size, tiles_x * tile_size, channels)
