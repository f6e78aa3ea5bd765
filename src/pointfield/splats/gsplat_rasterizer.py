"""The optional gsplat rasterizer: rendering through gsplat's CUDA kernels where they exist.

pointfield's own rasterizer (:mod:`pointfield.splats.rasterizer`) runs everywhere. Where the
``gsplat`` package is installed (``pip install gsplat``; it builds its CUDA kernels on first
use) and the splats live on a CUDA device, :func:`rasterization_gsplat` renders the same images
with gsplat's kernels, through the same signature and return values: pointfield's rasterizer
was written in the image of ``gsplat.rasterization`` (world-to-camera OpenCV ``viewmats``,
pinhole ``Ks``, wxyz quaternions, scales, opacities in [0, 1], SH or plain colours, the 0.3 px^2
screen dilation, the same near plane), so no conversion is needed but the output layout.

``rasterizer`` choices (``pointfield splat render --rasterizer``): "pointfield", "gsplat", or
"auto" (default): gsplat where it can run, pointfield otherwise.
"""

from __future__ import annotations

import importlib.util

import torch

from pointfield.errors import PointfieldError
from pointfield.splats.rasterizer import SCREEN_DILATION

RASTERIZERS = ("auto", "pointfield", "gsplat")


def gsplat_usable(device: torch.device) -> bool:
    """Whether gsplat is installed and ``device`` is a CUDA device (gsplat's kernels are CUDA only)."""
    return device.type == "cuda" and importlib.util.find_spec("gsplat") is not None


def choose_rasterizer(name: str, device: torch.device) -> str:
    """Resolve ``name`` (one of :data:`RASTERIZERS`) to "pointfield" or "gsplat" for ``device``."""
    if name not in RASTERIZERS:
        raise PointfieldError(f"unknown rasterizer {name!r}; choose one of {', '.join(RASTERIZERS)}")
    if name == "auto":
        return "gsplat" if gsplat_usable(device) else "pointfield"
    if name == "gsplat" and not gsplat_usable(device):
        why = ("gsplat is not installed (pip install gsplat)" if importlib.util.find_spec("gsplat") is None
               else f"gsplat needs a CUDA device, and the splats are on {device}")
        raise PointfieldError(f"cannot render with gsplat: {why}; use --rasterizer pointfield")
    return name


def rasterization_gsplat(
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
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, dict[str, torch.Tensor]]:
    """:func:`pointfield.splats.rasterizer.rasterization` computed by ``gsplat.rasterization``.

    Same arguments and returns: ``(colors (C, H, W, D), depths (C, H, W), alphas (C, H, W),
    meta)``, ``depths`` the alpha-weighted sum of camera z (gsplat's "D" render mode), the
    background added as ``colour + (1 - alpha) background``, and ``meta`` with ``means2d``
    ``(C, N, 2)``, ``radii`` ``(C, N)`` (the larger of gsplat's per-axis radii) and ``depths``.
    """
    import gsplat

    rendered, alphas, meta = gsplat.rasterization(
        means, quats, scales, opacities, colors, viewmats, Ks, width, height,
        near_plane=near_plane, far_plane=far_plane, eps2d=screen_dilation, sh_degree=sh_degree,
        packed=False, render_mode="RGB+D", rasterize_mode="antialiased" if antialiased else "classic",
    )
    image, depth, alpha = rendered[..., :-1], rendered[..., -1], alphas[..., 0]
    if backgrounds is not None:
        background = backgrounds if backgrounds.ndim == 1 else backgrounds[:, None, None, :]
        image = image + (1 - alpha)[..., None] * background
    radii = meta["radii"]
    if radii.ndim == 3:  # gsplat >= 1.5 gives (C, N, 2): x and y half-widths
        radii = radii.max(dim=-1).values
    return image, depth, alpha, {"means2d": meta["means2d"], "radii": radii, "depths": meta["depths"]}
