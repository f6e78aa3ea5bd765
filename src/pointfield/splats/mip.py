"""Mip-Splatting's filters (Yu et al., CVPR 2024): splats that hold up closer than they were trained.

A splat sized for the training pixels' footprint shows its edges when the camera comes closer
(thin splats, gaps between them), and one smaller than a pixel aliases from farther away.
Mip-Splatting bounds both with two filters, which ``splat train --mip`` turns on together:

- the **3D smoothing filter** (:func:`smoothing_variance`, :func:`smoothed`): no splat may be
  finer than the finest sampling any training camera gave it. A splat at camera depth ``z``
  seen by a camera of focal length ``f`` pixels is sampled every ``z / f`` world units; its
  highest sampling rate is ``nu = max over the training cameras that see it of f / z``, and
  its covariance gets the 3D Gaussian low-pass ``Sigma + (s / nu^2) I`` (``s`` =
  :data:`SMOOTHING`, 0.2 as the paper) with its opacity scaled by
  ``sqrt(det Sigma / det(Sigma + (s / nu^2) I))``, so that the splat's integral is unchanged;
- the **2D mip filter**: the rasterizer's antialiased mode with a 0.1 px^2 dilation
  (:data:`MIP_DILATION`), a Gaussian approximation of the one-pixel box filter with the same
  opacity compensation in screen space, in place of 3DGS's fixed 0.3 px^2 dilation
  (:func:`~pointfield.splats.rasterizer.rasterization`, ``antialiased``).

The filter is a function of the splats' means and the training cameras, so it is not stored:
training recomputes it every :data:`REFRESH_EVERY` steps and whenever the splat count changes
(Mip-Splatting does so at each densification and every 100 steps), and a loaded run recomputes
it from its scene's training cameras. An exported ``.ply`` has it baked into the scales and
opacities (:func:`baked`), as Mip-Splatting's exporter does, so any viewer draws it.
"""

from __future__ import annotations

import torch

from pointfield.splats.gaussians import Gaussians

SMOOTHING = 0.2
"""Mip-Splatting's ``s``: the 3D filter's variance in units of the squared sampling interval (what
a mip run made before ``mip_smoothing`` was recorded was trained with; new runs default to
:data:`pointfield.splats.train.DEFAULT_MIP_SMOOTHING`)."""
MIP_DILATION = 0.1
"""The 2D mip filter's variance in px^2 (Mip-Splatting's ``kernel_size``)."""
REFRESH_EVERY = 100
SCREEN_MARGIN = 0.15
"""A splat counts as seen by a camera within this fraction of the image beyond its edges (Mip-Splatting's)."""


@torch.no_grad()
def smoothing_variance(means: torch.Tensor, viewmats: torch.Tensor, Ks: torch.Tensor, widths, heights,
                       near_plane: float = 0.01, smoothing: float = SMOOTHING) -> torch.Tensor:
    """Each splat's 3D filter variance ``s / nu^2`` ``(N,)`` from the training cameras that see it
    (``s`` = ``smoothing``).

    ``viewmats`` ``(C, 4, 4)`` world-to-camera and ``Ks`` ``(C, 3, 3)`` as the rasterizer's,
    ``widths`` and ``heights`` ``(C,)``. A camera sees a splat when its mean is in front of the
    near plane and projects within :data:`SCREEN_MARGIN` of the image; ``1 / nu`` is the smallest
    ``z / f`` (``f`` the larger of ``fx``, ``fy``) among those cameras. A splat no camera sees
    gets the largest interval of the others (Mip-Splatting's choice).
    """
    interval = torch.full((len(means),), torch.inf, dtype=means.dtype, device=means.device)
    for camera in range(len(viewmats)):
        points = means @ viewmats[camera, :3, :3].T + viewmats[camera, :3, 3]
        z = points[:, 2]
        K, width, height = Ks[camera], float(widths[camera]), float(heights[camera])
        safe = z.clamp_min(near_plane)
        u = K[0, 0] * points[:, 0] / safe + K[0, 2]
        v = K[1, 1] * points[:, 1] / safe + K[1, 2]
        seen = ((z > near_plane) & (u >= -SCREEN_MARGIN * width) & (u <= (1 + SCREEN_MARGIN) * width)
                & (v >= -SCREEN_MARGIN * height) & (v <= (1 + SCREEN_MARGIN) * height))
        focal = torch.maximum(K[0, 0], K[1, 1])
        interval = torch.where(seen, torch.minimum(interval, safe / focal), interval)
    seen_any = torch.isfinite(interval)
    if not bool(seen_any.any()):
        return torch.zeros_like(interval)
    interval = torch.where(seen_any, interval, interval[seen_any].max())
    return smoothing * interval**2


def smoothed(scales: torch.Tensor, opacities: torch.Tensor,
             variance: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:
    """Scales ``(N, 3)`` and opacities ``(N,)`` with the 3D filter of ``variance`` ``(N,)`` applied
    (unchanged when None): ``sqrt(s^2 + var)`` and ``o sqrt(prod s^2 / prod(s^2 + var))``."""
    if variance is None:
        return scales, opacities
    squared = scales * scales
    filtered = squared + variance[:, None].to(squared.dtype)
    compensation = torch.sqrt((squared / filtered).prod(dim=1))
    return torch.sqrt(filtered), opacities * compensation


def drawn(gaussians: Gaussians) -> tuple[torch.Tensor, torch.Tensor]:
    """The scales and opacities the rasterizer draws: with the 3D filter where ``gaussians.smoothing`` is set."""
    variance = getattr(gaussians, "smoothing", None)
    if variance is not None and len(variance) != len(gaussians):
        raise ValueError(f"the 3D filter has {len(variance)} entries for {len(gaussians)} splats: recompute it")
    return smoothed(gaussians.scales, gaussians.opacities, variance)


@torch.no_grad()
def baked(gaussians: Gaussians) -> Gaussians:
    """A copy of ``gaussians`` whose scales and opacities include the 3D filter (for export)."""
    scales, opacities = drawn(gaussians)
    opacities = opacities.clamp(1e-7, 1 - 1e-7)
    return Gaussians(gaussians.means, gaussians.quats, torch.log(scales), torch.logit(opacities),
                     gaussians.sh_dc, gaussians.sh_rest, gaussians.active_sh_degree)


def training_smoothing(gaussians: Gaussians, cameras, smoothing: float = SMOOTHING) -> torch.Tensor:
    """:func:`smoothing_variance` of ``gaussians`` from ``cameras`` (:class:`~pointfield.scenes.cameras.Cameras`,
    the training views) with strength ``smoothing``, on the splats' device."""
    device, dtype = gaussians.means.device, gaussians.means.dtype
    viewmats = cameras.world_to_camera().to(device, dtype)
    Ks = cameras.intrinsic_matrices().to(device, dtype)
    return smoothing_variance(gaussians.means.detach(), viewmats, Ks, cameras.width, cameras.height,
                              smoothing=smoothing)
