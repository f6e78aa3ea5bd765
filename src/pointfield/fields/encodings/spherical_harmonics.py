"""Real spherical harmonics up to degree 3: an encoding of view directions.

:func:`sh_basis` encodes a unit direction for the fast radiance field's colour network
(:mod:`pointfield.fields.ngp`); the splats use it for their view-dependent colour. A splat's
colour in direction ``d`` (unit, from the camera centre towards the splat) is

    rgb(d) = max(0, sum_{l <= degree} sum_m c_lm Y_lm(d) + 0.5)

with ``(degree + 1)^2`` coefficients per colour channel. The basis, its constants, its sign
convention and the ``+ 0.5`` offset are those of the original 3D Gaussian splatting code (and
gsplat), so coefficients read from any standard splat ``.ply`` give the colours its authors saw.
The degree-0 term alone is a constant colour: ``rgb = C0 * c_00 + 0.5`` with ``C0 = 0.28209...``.
"""

from __future__ import annotations

import torch

C0 = 0.28209479177387814
C1 = 0.4886025119029199
C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)
MAX_SH_DEGREE = 3


def sh_coefficient_count(degree: int) -> int:
    """Coefficients per channel for SH of ``degree``: ``(degree + 1)^2`` (1, 4, 9, 16)."""
    if not 0 <= degree <= MAX_SH_DEGREE:
        raise ValueError(f"spherical-harmonic degree must be 0 to {MAX_SH_DEGREE}, got {degree}")
    return (degree + 1) ** 2


def sh_degree_of(count: int) -> int:
    """The degree whose ``(degree + 1)^2`` equals ``count`` (ValueError for other counts)."""
    for degree in range(MAX_SH_DEGREE + 1):
        if (degree + 1) ** 2 == count:
            return degree
    raise ValueError(f"{count} coefficients per channel is not (degree + 1)^2 for a degree 0 to {MAX_SH_DEGREE}")


def sh_basis(directions: torch.Tensor, degree: int) -> torch.Tensor:
    """The real SH basis ``Y_lm`` at unit ``directions`` ``(..., 3)``: ``(..., (degree + 1)^2)``.

    Order: l = 0; l = 1 (m = -1, 0, 1); l = 2 (m = -2 .. 2); l = 3 (m = -3 .. 3), with the 3DGS
    signs (``Y_1,-1 = -C1 y``, ``Y_10 = C1 z``, ``Y_11 = -C1 x``, ...).
    """
    sh_coefficient_count(degree)  # validates the degree
    x, y, z = directions.unbind(-1)
    terms = [torch.full_like(x, C0)]
    if degree >= 1:
        terms += [-C1 * y, C1 * z, -C1 * x]
    if degree >= 2:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        terms += [
            C2[0] * xy,
            C2[1] * yz,
            C2[2] * (2 * zz - xx - yy),
            C2[3] * xz,
            C2[4] * (xx - yy),
        ]
    if degree >= 3:
        terms += [
            C3[0] * y * (3 * xx - yy),
            C3[1] * xy * z,
            C3[2] * y * (4 * zz - xx - yy),
            C3[3] * z * (2 * zz - 3 * xx - 3 * yy),
            C3[4] * x * (4 * zz - xx - yy),
            C3[5] * z * (xx - yy),
            C3[6] * x * (xx - 3 * yy),
        ]
    return torch.stack(terms, dim=-1)


def sh_to_rgb(coefficients: torch.Tensor, directions: torch.Tensor, degree: int) -> torch.Tensor:
    """Colours ``(N, 3)`` of SH ``coefficients`` ``(N, K, 3)`` seen along ``directions`` ``(N, 3)``.

    Only the first ``(degree + 1)^2`` of the K coefficients are used (the active degree may be
    lower than the stored one while training ramps it up). Directions need not be unit length:
    they are normalised here. Returns ``max(0, sum_k c_k Y_k(d) + 0.5)``.
    """
    count = sh_coefficient_count(degree)
    if coefficients.shape[-2] < count:
        raise ValueError(f"degree {degree} needs {count} coefficients per channel, got {coefficients.shape[-2]}")
    unit = directions / directions.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    basis = sh_basis(unit, degree)
    color = torch.einsum("nk,nkc->nc", basis, coefficients[:, :count])
    return torch.clamp_min(color + 0.5, 0.0)


def rgb_to_sh_dc(rgb: torch.Tensor) -> torch.Tensor:
    """The degree-0 coefficient giving constant colour ``rgb``: ``(rgb - 0.5) / C0``."""
    return (rgb - 0.5) / C0
