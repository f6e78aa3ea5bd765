"""The slow, obviously-correct rasterizer that :mod:`pointfield.splats.rasterizer` is tested against.

The same arguments, conventions and outputs as
:func:`pointfield.splats.rasterizer.rasterization`, computed the way the paper describes it
and nothing cleverer: no tiles, no bounding squares, no batching. Each splat is projected on
its own with explicit matrices; the splats are sorted by depth once; then a Python loop over
them updates every pixel of the image, exactly as the per-pixel loop of 3D Gaussian splatting
does (skip ``alpha < 1/255``, clamp at 0.99, stop a pixel before its transmittance would fall
below 1e-4). Use it on scenes of a few dozen splats and a few hundred pixels.
"""

from __future__ import annotations

import torch

from pointfield.fields.encodings.spherical_harmonics import sh_to_rgb
from pointfield.splats.gaussians import quaternion_to_rotation
from pointfield.splats.rasterizer import (
    MAX_ALPHA,
    MIN_ALPHA,
    MIN_TRANSMITTANCE,
    SCREEN_DILATION,
    SIGMA_EXTENT,
)


def rasterization_reference(
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
    antialiased: bool = False,
    screen_dilation: float = SCREEN_DILATION,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Render like :func:`~pointfield.splats.rasterizer.rasterization`: ``(colors, depths, alphas)``."""
    images, depth_images, alpha_images = [], [], []
    for camera in range(viewmats.shape[0]):
        rotation_cam, translation = viewmats[camera, :3, :3], viewmats[camera, :3, 3]
        fx, fy, cx, cy = Ks[camera, 0, 0], Ks[camera, 1, 1], Ks[camera, 0, 2], Ks[camera, 1, 2]
        if sh_degree is not None:
            view_colors = sh_to_rgb(colors, means - (-rotation_cam.T @ translation), sh_degree)
        else:
            view_colors = colors
        v, u = torch.meshgrid(
            torch.arange(height, dtype=means.dtype) + 0.5, torch.arange(width, dtype=means.dtype) + 0.5,
            indexing="ij",
        )
        splats = []
        for i in range(means.shape[0]):
            x, y, z = rotation_cam @ means[i] + translation
            if not near_plane < float(z.detach()) < far_plane:
                continue
            # EWA: Sigma_2d = J W Sigma W^T J^T + s I (s: the screen dilation), J at the
            # (field-of-view clamped) mean.
            limit_x = (-(cx / fx) - 0.3 * 0.5 * width / fx, (width - cx) / fx + 0.3 * 0.5 * width / fx)
            limit_y = (-(cy / fy) - 0.3 * 0.5 * height / fy, (height - cy) / fy + 0.3 * 0.5 * height / fy)
            tx = z * torch.clamp(x / z, min=limit_x[0], max=limit_x[1])
            ty = z * torch.clamp(y / z, min=limit_y[0], max=limit_y[1])
            jacobian = torch.stack([
                torch.stack([fx / z, torch.zeros_like(z), -fx * tx / z**2]),
                torch.stack([torch.zeros_like(z), fy / z, -fy * ty / z**2]),
            ])
            rotation = quaternion_to_rotation(quats[i][None])[0]
            sigma_world = rotation @ torch.diag(scales[i] ** 2) @ rotation.T
            sigma_2d = jacobian @ rotation_cam @ sigma_world @ rotation_cam.T @ jacobian.T
            dilated = sigma_2d + screen_dilation * torch.eye(2, dtype=means.dtype)
            if float(torch.linalg.det(dilated.detach())) <= 0:
                continue
            # Antialiased: the opacity scaled so the dilation spreads the splat's coverage.
            opacity = opacities[i] * torch.sqrt(torch.linalg.det(sigma_2d) / torch.linalg.det(dilated)) \
                if antialiased else opacities[i]
            mean_2d = torch.stack([fx * x / z + cx, fy * y / z + cy])
            splats.append((float(z.detach()), i, z, mean_2d, torch.linalg.inv(dilated), opacity))
        splats.sort(key=lambda splat: splat[0])

        transmittance = torch.ones(height, width, dtype=means.dtype)
        done = torch.zeros(height, width, dtype=torch.bool)
        image = torch.zeros(height, width, view_colors.shape[-1], dtype=means.dtype)
        depth = torch.zeros(height, width, dtype=means.dtype)
        for _, i, z, mean_2d, inverse, opacity in splats:
            d = torch.stack([u - mean_2d[0], v - mean_2d[1]], dim=-1)              # (H, W, 2)
            mahalanobis = torch.einsum("hwi,ij,hwj->hw", d, inverse, d)
            alpha = torch.clamp(opacity * torch.exp(-0.5 * mahalanobis), max=MAX_ALPHA)
            used = (~done) & (mahalanobis <= SIGMA_EXTENT**2) & (alpha >= MIN_ALPHA)
            after = transmittance * (1 - alpha)
            stops = used & (after < MIN_TRANSMITTANCE)
            done = done | stops
            used = used & ~stops
            weight = torch.where(used, alpha * transmittance, torch.zeros_like(alpha))
            image = image + weight[..., None] * view_colors[i]
            depth = depth + weight * z
            transmittance = torch.where(used, after, transmittance)
        if backgrounds is not None:
            background = backgrounds if backgrounds.ndim == 1 else backgrounds[camera]
            image = image + transmittance[..., None] * background
        images.append(image)
        depth_images.append(depth)
        alpha_images.append(1 - transmittance)
    return torch.stack(images), torch.stack(depth_images), torch.stack(alpha_images)
