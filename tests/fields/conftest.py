"""Fixtures shared by the field tests."""

from __future__ import annotations

from collections.abc import Callable

import pytest
import torch

Rays = tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]


@pytest.fixture(scope="session")
def rays_at_the_box() -> Callable[..., Rays]:
    """``(count, seed=0) -> (origins, directions, near, far)``: rays from a sphere of radius 3 at the box [-1, 1]^3.

    Each aims at a random point of the central [-0.8, 0.8]^3; some start inside the box (near from
    1 to 2.5) and some end inside it (far 0.5 to 3.5 beyond near).
    """

    def rays(count: int, seed: int = 0) -> Rays:
        generator = torch.Generator().manual_seed(seed)
        origins = torch.nn.functional.normalize(torch.randn(count, 3, generator=generator), dim=-1) * 3
        targets = (torch.rand(count, 3, generator=generator) - 0.5) * 1.6
        directions = torch.nn.functional.normalize(targets - origins, dim=-1)
        near = 1.0 + 1.5 * torch.rand(count, generator=generator)
        far = near + 0.5 + 3 * torch.rand(count, generator=generator)
        return origins, directions, near, far

    return rays
