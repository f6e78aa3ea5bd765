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
   ``Sigma_2d = J W Sigma W^T J^T + 0.3 I``. The 0.3 px^2 dilation keeps every splat at least
   about a pixel wide (no aliasing holes). As in 3DGS, ``x/z`` and ``y/z`` are clamped to 1.3x
   the field of view inside ``J`` so splats far outside the view do not explode. Splats with
   ``z <= near_plane`` are dropped.
2. **Bound** each splat by a square of half-width ``r = ceil(3 sqrt(lambda_max(Sigma_2d)))``
   (3 sigma) and keep those overlapping the image. A splat contributes only inside its 3-sigma
   ellipse (``d^T Sigma_2d^-1 d <= 9``), so the image does not depend on the tiling.
3. **Bin** splats into 16 x 16-pixel tiles: one (splat, tile) pair per tile the square touches.
4. **Sort** the pairs by tile, and within a tile by camera-space depth z (front first).
5. **Composite** each pixel front to back:
   ``alpha_i = min(0.99, o_i exp(-0.5 d^T Sigma_2d^-1 d))``, skipped when ``alpha_i < 1/255``;
   ``C = sum_i c_i alpha_i T_i`` with ``T_i = prod_{j<i} (1 - alpha_j)``; a pixel stops at the
   first splat that would bring its transmittance below 1e-4 (that splat is not added).
   Depth is ``sum_i z_i alpha_i T_i`` and alpha ``1 - T_final = sum_i alpha_i T_i``.

Step 5 is evaluated for whole tiles at once: the splats of a batch of tiles are gathered into
a padded ``(tiles, L, 256)`` block and the front-to-back product is a ``cumprod`` along L,
which autograd differentiates. Tiles are processed in batches of similar length so the
padding, and the memory, stay bounded (``max_block_elements``), and L is walked in slices of
``splats_per_slice`` so a tile whose pixels have all stopped is dropped early.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from pointfield.splats.gaussians import covariances
from pointfield.splats.sh import sh_to_rgb

TILE_SIZE = 16
SCREEN_DILATION = 0.3
MIN_ALPHA = 1.0 / 255.0
MAX_ALPHA = 0.99
MIN_TRANSMITTANCE = 1e-4
SIGMA_EXTENT = 3.0


@dataclass
class Projection:
    """Splats projected into one camera (step 1 and 2); N entries, ``visible`` marks the kept ones.

    ``means2d`` ``(N, 2)`` pixel coordinates, ``conics`` ``(N, 3)`` the upper triangle
    ``(a, b, c)`` of ``Sigma_2d^-1``, ``depths`` ``(N,)`` camera z, ``radii`` ``(N,)`` the 3-sigma
    half-width in pixels (0 where not visible), ``visible`` ``(N,)`` bool.
    """

    means2d: torch.Tensor
    conics: torch.Tensor
    depths: torch.Tensor
    radii: torch.Tensor
    visible: torch.Tensor


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
) -> Projection:
    """Project N Gaussians into one camera (``viewmat`` (4, 4) world-to-camera, ``K`` (3, 3)).

    See the module docstring, steps 1 and 2, for the formulas.
    """
    rotation, translation = viewmat[:3, :3], viewmat[:3, 3]
    means_cam = means @ rotation.T + translation
    x, y, z = means_cam.unbind(-1)
    in_depth = (z > near_plane) & (z < far_plane)
    # Splats behind the camera still go through the arithmetic (masked afterwards), so give
    # them a harmless depth rather than dividing by zero.
    z_safe = torch.where(in_depth, z, torch.ones_like(z))
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]

    covariance_cam = rotation @ covariances(quats, scales) @ rotation.T
    # The 1.3-field-of-view clamp of 3DGS / gsplat, applied to the Jacobian only.
    tan_fov_x, tan_fov_y = 0.5 * width / fx, 0.5 * height / fy
    limit_x_pos = (width - cx) / fx + 0.3 * tan_fov_x
    limit_x_neg = cx / fx + 0.3 * tan_fov_x
    limit_y_pos = (height - cy) / fy + 0.3 * tan_fov_y
    limit_y_neg = cy / fy + 0.3 * tan_fov_y
    tx = z_safe * torch.minimum(torch.maximum(x / z_safe, -limit_x_neg), limit_x_pos)
    ty = z_safe * torch.minimum(torch.maximum(y / z_safe, -limit_y_neg), limit_y_pos)
    zeros = torch.zeros_like(z_safe)
    jacobian = torch.stack(
        [fx / z_safe, zeros, -fx * tx / z_safe**2,
         zeros, fy / z_safe, -fy * ty / z_safe**2],
        dim=-1,
    ).reshape(-1, 2, 3)
    covariance_2d = jacobian @ covariance_cam @ jacobian.transpose(1, 2)
    a = covariance_2d[:, 0, 0] + SCREEN_DILATION
    b = covariance_2d[:, 0, 1]
    c = covariance_2d[:, 1, 1] + SCREEN_DILATION
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
    return Projection(means2d, conics, z, torch.where(visible, radii, torch.zeros_like(radii)), visible)


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
    max_block_elements: int = 1 << 22,
    splats_per_slice: int = 64,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, dict[str, torch.Tensor]]:
    """Render N Gaussians into C cameras; differentiable with respect to every tensor input.

    Arguments (conventions in the module docstring):

    - ``means`` ``(N, 3)``, ``quats`` ``(N, 4)`` wxyz, ``scales`` ``(N, 3)``, ``opacities`` ``(N,)``;
    - ``colors``: ``(N, D)`` per-splat values composited as they are (RGB, or any D features),
      or, with ``sh_degree`` given, SH coefficients ``(N, K, 3)`` evaluated per camera in the
      direction from the camera centre to each mean (:func:`pointfield.splats.sh.sh_to_rgb`);
    - ``viewmats`` ``(C, 4, 4)`` world-to-camera, ``Ks`` ``(C, 3, 3)``, image ``width`` x ``height``;
    - ``backgrounds`` ``(C, D)`` or ``(D,)``: added where the splats leave light through,
      ``colour + T_final * background`` (default: none, i.e. black);
    - ``max_block_elements``, ``splats_per_slice``: memory and early-termination granularity
      of the compositing (they change speed, never the result).

    Returns ``(colors (C, H, W, D), depths (C, H, W), alphas (C, H, W), meta)``. ``depths`` is
    the alpha-weighted sum of camera z (divide by ``alphas`` for the expected depth). ``meta``
    holds ``means2d`` ``(C, N, 2)`` (call ``retain_grad()`` on it before ``backward`` to get the
    screen-space gradients densification uses), ``radii`` ``(C, N)`` (0: not visible) and
    ``depths`` ``(C, N)``.

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
    camera_count = viewmats.shape[0]
    projections = [
        project_gaussians(means, quats, scales, viewmats[i], Ks[i], width, height, near_plane, far_plane)
        for i in range(camera_count)
    ]
    # One (C, N, 2) tensor that the compositing reads from, so its .grad is the screen-space
    # gradient of every camera.
    means2d = torch.stack([p.means2d for p in projections])
    images, depth_images, alpha_images = [], [], []
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
        image, depth, alpha = composite_tiles(
            means2d[i], projection.conics, opacities, view_colors, projection.depths,
            projection.radii, projection.visible, width, height, background, max_block_elements,
            splats_per_slice,
        )
        images.append(image)
        depth_images.append(depth)
        alpha_images.append(alpha)
    meta = {
        "means2d": means2d,
        "radii": torch.stack([p.radii for p in projections]),
        "depths": torch.stack([p.depths for p in projections]),
    }
    return torch.stack(images), torch.stack(depth_images), torch.stack(alpha_images), meta


def tile_intersections(
    means2d: torch.Tensor, radii: torch.Tensor, depths: torch.Tensor, visible: torch.Tensor,
    tiles_x: int, tiles_y: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Steps 3 and 4: the (splat, tile) pairs, sorted by tile then depth.

    Returns ``(splat_ids (P,), tile_ids (P,))`` int64 with P pairs; ``tile_id = ty * tiles_x + tx``.
    """
    device = means2d.device
    ids = torch.nonzero(visible).squeeze(1)
    # Depth order first; the stable sort by tile below keeps it within each tile.
    ids = ids[torch.argsort(depths.detach()[ids], stable=True)]
    u, v = means2d.detach()[ids].unbind(-1)
    r = radii[ids]
    x0 = torch.clamp(torch.floor((u - r) / TILE_SIZE), 0, tiles_x).long()
    x1 = torch.clamp(torch.floor((u + r) / TILE_SIZE) + 1, 0, tiles_x).long()
    y0 = torch.clamp(torch.floor((v - r) / TILE_SIZE), 0, tiles_y).long()
    y1 = torch.clamp(torch.floor((v + r) / TILE_SIZE) + 1, 0, tiles_y).long()
    span_x = (x1 - x0).clamp_min(0)
    counts = span_x * (y1 - y0).clamp_min(0)
    total = int(counts.sum())
    owner = torch.repeat_interleave(torch.arange(len(ids), device=device), counts)
    first = torch.cumsum(counts, 0) - counts
    offset = torch.arange(total, device=device) - first[owner]
    tile_x = x0[owner] + offset % span_x[owner]
    tile_y = y0[owner] + offset // span_x[owner]
    tile_ids = tile_y * tiles_x + tile_x
    order = torch.argsort(tile_ids, stable=True)
    return ids[owner[order]], tile_ids[order]


def composite_tiles(
    means2d: torch.Tensor,
    conics: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    depths: torch.Tensor,
    radii: torch.Tensor,
    visible: torch.Tensor,
    width: int,
    height: int,
    background: torch.Tensor | None = None,
    max_block_elements: int = 1 << 22,
    splats_per_slice: int = 64,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Steps 3 to 5 for one camera: ``(colors (H, W, D), depths (H, W), alphas (H, W))``.

    Each batch of tiles walks its depth-sorted splats ``splats_per_slice`` at a time, carrying
    the transmittance from slice to slice, and drops a tile once every pixel of it has stopped
    (T < 1e-4) -- the early termination of the CUDA rasterizers, per tile.
    """
    device, dtype = means2d.device, means2d.dtype
    tiles_x, tiles_y = math.ceil(width / TILE_SIZE), math.ceil(height / TILE_SIZE)
    tile_count = tiles_x * tiles_y
    splat_ids, tile_ids = tile_intersections(means2d, radii, depths, visible, tiles_x, tiles_y)
    per_tile = torch.bincount(tile_ids, minlength=tile_count)
    tile_start = torch.cumsum(per_tile, 0) - per_tile
    channels = colors.shape[-1]

    # Pixel-centre offsets within a tile (the 256 pixels are row-major: v then u).
    tile_offsets = torch.arange(TILE_SIZE, device=device, dtype=dtype) + 0.5
    pixels_per_tile = TILE_SIZE * TILE_SIZE

    # Batches of tiles with similar lengths: sort tiles by length, cut where the padded block
    # (tiles x splats per slice x 256) would pass max_block_elements.
    tile_order = torch.argsort(per_tile, stable=True)
    lengths = per_tile[tile_order].tolist()
    batches, start = [], 0
    while start < tile_count:
        end = start + 1
        while end < tile_count and (end + 1 - start) * min(max(lengths[end], 1), splats_per_slice) * pixels_per_tile <= max_block_elements:
            end += 1
        batches.append((start, end, max(lengths[end - 1], 1)))
        start = end

    color_blocks, depth_blocks, alpha_blocks = [], [], []
    for start, end, longest in batches:
        tiles = tile_order[start:end]
        count = end - start
        color_sum = torch.zeros(count, pixels_per_tile, channels, device=device, dtype=colors.dtype)
        depth_sum = torch.zeros(count, pixels_per_tile, device=device, dtype=dtype)
        alpha_sum = torch.zeros(count, pixels_per_tile, device=device, dtype=dtype)
        # The front-to-back product so far, per pixel (not stopped at 1e-4: "counted" below
        # compares it with the threshold, which is the same test).
        transmittance = torch.ones(count, pixels_per_tile, device=device, dtype=dtype)
        live = torch.arange(count, device=device)  # tiles with splats left and light left
        for first in range(0, longest, splats_per_slice):
            live_tiles = tiles[live]
            slot = torch.arange(first, min(first + splats_per_slice, longest), device=device)
            present = slot[None, :] < per_tile[live_tiles][:, None]                  # (B, L)
            pair = (tile_start[live_tiles][:, None] + slot[None, :]).clamp_max(max(len(splat_ids) - 1, 0))
            ids = splat_ids[pair] if len(splat_ids) else torch.zeros_like(pair)        # (B, L)
            corner = torch.stack([live_tiles % tiles_x, live_tiles // tiles_x], dim=-1).to(dtype) * TILE_SIZE
            splat_means = means2d[ids]                                               # (B, L, 2)
            # A tile's pixels are a 16 x 16 grid, so dx depends on the column only and dy on
            # the row only: (B, L, 16) each, broadcast to (B, L, 16, 16) at the end.
            dx = (corner[:, None, 0:1] + tile_offsets) - splat_means[..., 0:1]
            dy = (corner[:, None, 1:2] + tile_offsets) - splat_means[..., 1:2]
            a, b, c = conics[ids][..., None].unbind(-2)                              # (B, L, 1) each
            # sigma = 0.5 d^T Sigma_2d^-1 d = 0.5 a dx^2 + b dx dy + 0.5 c dy^2
            sigma = (
                (0.5 * a * dx * dx)[..., None, :]
                + (0.5 * c * dy * dy)[..., :, None]
                + (b * dy)[..., :, None] * dx[..., None, :]
            ).flatten(-2)                                                            # (B, L, 256)
            # Padding slots get opacity 0, hence alpha 0: they change nothing.
            splat_opacities = torch.where(present, opacities[ids], torch.zeros_like(opacities[ids]))
            alpha = torch.clamp_max(splat_opacities[..., None] * torch.exp(-sigma), MAX_ALPHA)
            inside = (sigma <= 0.5 * SIGMA_EXTENT**2) & (alpha >= MIN_ALPHA)
            alpha = torch.where(inside, alpha, torch.zeros_like(alpha))
            transmittance_after = torch.cumprod(1 - alpha, dim=1) * transmittance[live][:, None, :]
            # A pixel stops at the first splat that would bring T below 1e-4; T only falls,
            # so "not stopped yet" is "T after this splat still >= 1e-4".
            counted = transmittance_after >= MIN_TRANSMITTANCE
            # T before splat i is T after it divided by (1 - alpha_i) >= 0.01: no shifted copy.
            weights = alpha / (1 - alpha) * transmittance_after * counted          # (B, L, 256)
            color_sum = color_sum.index_add(0, live, torch.einsum("blp,bld->bpd", weights, colors[ids]))
            depth_sum = depth_sum.index_add(0, live, torch.einsum("blp,bl->bp", weights, depths[ids]))
            alpha_sum = alpha_sum.index_add(0, live, weights.sum(1))
            transmittance = transmittance.index_copy(0, live, transmittance_after[:, -1])
            # Early termination: a tile is finished when its splats are, or its light is.
            more = (per_tile[live_tiles] > first + splats_per_slice) & (transmittance_after[:, -1] >= MIN_TRANSMITTANCE).any(1)
            live = live[more]
            if len(live) == 0:
                break
        color_blocks.append(color_sum)
        depth_blocks.append(depth_sum)
        alpha_blocks.append(alpha_sum)

    inverse = torch.argsort(tile_order)
    color_tiles = torch.cat(color_blocks)[inverse]                                   # (T, 256, D)
    depth_tiles = torch.cat(depth_blocks)[inverse]
    alpha_tiles = torch.cat(alpha_blocks)[inverse]
    if background is not None:
        color_tiles = color_tiles + (1 - alpha_tiles)[..., None] * background
    image = _untile(color_tiles, tiles_x, tiles_y, channels)[:height, :width]
    depth = _untile(depth_tiles[..., None], tiles_x, tiles_y, 1)[:height, :width, 0]
    alpha = _untile(alpha_tiles[..., None], tiles_x, tiles_y, 1)[:height, :width, 0]
    return image, depth, alpha


def _untile(values: torch.Tensor, tiles_x: int, tiles_y: int, channels: int) -> torch.Tensor:
    """``(tiles, 256, D)`` in row-major tile order -> ``(tiles_y * 16, tiles_x * 16, D)``."""
    blocks = values.reshape(tiles_y, tiles_x, TILE_SIZE, TILE_SIZE, channels)
    return blocks.permute(0, 2, 1, 3, 4).reshape(tiles_y * TILE_SIZE, tiles_x * TILE_SIZE, channels)
