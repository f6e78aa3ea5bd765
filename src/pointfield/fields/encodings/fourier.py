"""Fourier positional encoding: the encoding of NeRF's positions and view directions.

An MLP fed raw coordinates learns smooth functions only (its spectral bias); NeRF maps each
coordinate through sines and cosines of growing frequency first (Mildenhall et al. 2020, eq. 4):

    gamma(p) = (p, sin(2^0 pi p), cos(2^0 pi p), ..., sin(2^(L-1) pi p), cos(2^(L-1) pi p))

applied to every component of p separately; L = 10 for positions and 4 for view directions.
"""

from __future__ import annotations

import math

import torch
from torch import nn

POSITION_FREQUENCIES = 10
"""L for positions in NeRF: the highest frequency is 2^9 pi."""

DIRECTION_FREQUENCIES = 4
"""L for view directions in NeRF: colour changes slowly with the viewing angle."""


def positional_encoding(values: torch.Tensor, frequencies: int, include_input: bool = True) -> torch.Tensor:
    """Fourier features gamma(p) of the last axis of ``values``.

    ``values``: ``(..., D)``. Returns ``(..., D * (2 L + 1))`` with ``include_input`` (p first),
    else ``(..., D * 2 L)``; ``L = frequencies``. Order: ``p``, then for k = 0..L-1 the D sines
    ``sin(2^k pi p)`` followed by the D cosines ``cos(2^k pi p)``.

    Example::

        >>> positional_encoding(torch.tensor([[0.25]]), 2)
        tensor([[ 2.5000e-01,  7.0711e-01,  7.0711e-01,  1.0000e+00, -4.3711e-08]])
    """
    scales = (2.0 ** torch.arange(frequencies, device=values.device, dtype=values.dtype)) * math.pi
    angles = values[..., None, :] * scales[:, None]  # (..., L, D)
    features = torch.cat([torch.sin(angles), torch.cos(angles)], dim=-1).flatten(-2)  # (..., L * 2D)
    return torch.cat([values, features], dim=-1) if include_input else features


class PositionalEncoding(nn.Module):
    """gamma(p) with ``frequencies`` L as a module: ``PositionalEncoding(10)(xyz)`` -> ``(..., 63)``."""

    def __init__(self, frequencies: int, include_input: bool = True):
        super().__init__()
        if frequencies < 0:
            raise ValueError(f"frequencies must be >= 0, got {frequencies}")
        self.frequencies = int(frequencies)
        self.include_input = bool(include_input)

    def output_dim(self, input_dim: int = 3) -> int:
        """Width of the encoding of ``input_dim`` coordinates."""
        return input_dim * (2 * self.frequencies + int(self.include_input))

    def forward(self, values: torch.Tensor) -> torch.Tensor:
        return positional_encoding(values, self.frequencies, self.include_input)

    def extra_repr(self) -> str:
        return f"frequencies={self.frequencies}, include_input={self.include_input}"
