"""World space onto the unit cube a hash grid covers: an affine box map, or a scene contraction.

- :func:`box_to_unit`: bounded scenes (an object in a box) map the box affinely onto ``[0, 1]^3``.
- :func:`contract`: unbounded scenes (real captures that see the horizon) squeeze all of space
  into a ball (mip-NeRF 360, Barron et al. 2022, eq. 10), rescaled into the unit cube.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from pointfield.errors import PointfieldError


def box_to_unit(positions: torch.Tensor, box: torch.Tensor) -> torch.Tensor:
    """Positions ``(..., 3)`` in the ``(2, 3)`` min/max ``box`` mapped affinely onto ``[0, 1]^3``.

    ``u = (x - box_min) / (box_max - box_min)``.

    Example::

        >>> box_to_unit(torch.tensor([[0.0, 1.0, -1.0]]), torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]))
        tensor([[0.5000, 1.0000, 0.0000]])
    """
    return (positions - box[0]) / (box[1] - box[0])


def contract(positions: torch.Tensor, center: torch.Tensor | Sequence[float], radius: float) -> torch.Tensor:
    """Mip-NeRF 360 scene contraction (eq. 10) of world ``positions`` ``(..., 3)`` into ``[0, 1]^3``.

    With ``x' = (x - center) / radius``::

        contract(x') = x'                                  if ||x'|| <= 1
                       (2 - 1 / ||x'||) x' / ||x'||        otherwise          (L2 norm)
        unit(x)      = (contract(x') + 2) / 4

    The ball of ``radius`` around ``center`` maps linearly onto the ball of radius 1/4 around
    ``(1/2, 1/2, 1/2)``; the rest of space fills the shell out to radius 1/2, with points at
    infinity on its surface. Continuous and once differentiable across ``||x'|| = 1``, with
    finite gradients everywhere (also at the centre). Returns ``(..., 3)``.

    Example::

        >>> contract(torch.tensor([[0.0, 0, 0], [2.0, 0, 0], [1e9, 0, 0]]), torch.zeros(3), 1.0)
        tensor([[0.5000, 0.5000, 0.5000],
                [0.8750, 0.5000, 0.5000],
                [1.0000, 0.5000, 0.5000]])
    """
    if not radius > 0:
        raise PointfieldError(f"contraction radius must be positive, got {radius}")
    center = torch.as_tensor(center, dtype=positions.dtype, device=positions.device)
    scaled = (positions - center) / radius
    squared_norm = (scaled * scaled).sum(dim=-1, keepdim=True)
    # The outer branch sees norms >= 1 only, so torch.where's unused branch cannot put 0/0 (NaN)
    # into the gradient at the centre.
    norm = squared_norm.clamp_min(1.0).sqrt()
    outside = (2 - 1 / norm) * (scaled / norm)
    contracted = torch.where(squared_norm <= 1, scaled, outside)
    return (contracted + 2) / 4
