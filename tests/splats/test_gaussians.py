"""The splat model: initialisation, derived quantities, spherical harmonics, resizing on load."""

import math

import numpy as np
import pytest
import torch

from pointfield.fields.encodings.spherical_harmonics import C0, rgb_to_sh_dc, sh_basis, sh_to_rgb
from pointfield.splats.gaussians import Gaussians, covariances, quaternion_to_rotation


def test_gsplat_garden_points_initialise_a_model(shared_data):
    garden = np.load(shared_data / "gaussians/gsplat_test_garden.npz")
    gaussians = Gaussians.from_points(garden["means3d"], garden["colors"])
    assert len(gaussians) == 138766
    rgb = sh_to_rgb(gaussians.sh_coefficients, torch.ones(len(gaussians), 3), 0)
    np.testing.assert_allclose(rgb.detach().numpy(), garden["colors"] / 255, atol=1e-5)
    assert torch.isfinite(gaussians.log_scales).all()
    assert gaussians.active_sh_degree == 0


def test_scales_from_points_are_the_neighbour_spacing():
    grid = np.stack(np.meshgrid(*[np.arange(4.0)] * 3, indexing="ij"), -1).reshape(-1, 3) * 0.5
    gaussians = Gaussians.from_points(grid)
    # Every grid point has at least three neighbours at distance 0.5.
    np.testing.assert_allclose(gaussians.scales.detach().numpy(), 0.5, rtol=1e-6)


def test_random_in_box_stays_in_the_box_and_is_seeded():
    a = Gaussians.random_in_box(200, [-1, -2, -3], [1, 2, 3], seed=4)
    b = Gaussians.random_in_box(200, [-1, -2, -3], [1, 2, 3], seed=4)
    assert torch.equal(a.means, b.means)
    assert (a.means.abs() <= torch.tensor([1.0, 2.0, 3.0])).all()


def test_quaternions_are_normalised_and_wxyz():
    # 90 degrees about z, unnormalised: x -> y.
    rotation = quaternion_to_rotation(torch.tensor([[2 * math.cos(math.pi / 4), 0, 0, 2 * math.sin(math.pi / 4)]]))
    np.testing.assert_allclose(rotation[0].numpy(), [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-6)


def test_covariance_is_rotated_diagonal_of_squared_scales():
    quats = torch.randn(5, 4, dtype=torch.float64)
    scales = torch.rand(5, 3, dtype=torch.float64) + 0.1
    rotation = quaternion_to_rotation(quats)
    expected = rotation @ torch.diag_embed(scales**2) @ rotation.transpose(1, 2)
    torch.testing.assert_close(covariances(quats, scales), expected)


def test_sh_degree_0_is_a_constant_colour():
    rgb = torch.tensor([[0.2, 0.5, 0.9]])
    coefficients = rgb_to_sh_dc(rgb)[:, None, :]
    for direction in ([1.0, 0, 0], [0, -1.0, 0.3]):
        torch.testing.assert_close(sh_to_rgb(coefficients, torch.tensor([direction]), 0), rgb)
    assert C0 == pytest.approx(0.5 / math.sqrt(math.pi))


def test_sh_basis_is_orthonormal_on_the_sphere():
    generator = torch.Generator().manual_seed(0)
    directions = torch.randn(200_000, 3, generator=generator, dtype=torch.float64)
    directions = directions / directions.norm(dim=1, keepdim=True)
    basis = sh_basis(directions, 3)
    gram = basis.T @ basis * (4 * math.pi / len(directions))
    torch.testing.assert_close(gram, torch.eye(16, dtype=torch.float64), atol=0.02, rtol=0)


def test_loading_a_state_of_another_splat_count_resizes_the_model():
    small = Gaussians.random_in_box(10, [-1] * 3, [1] * 3)
    large = Gaussians.random_in_box(30, [-1] * 3, [1] * 3, seed=1)
    large.active_sh_degree = 2
    small.load_state_dict(large.state_dict())
    assert len(small) == 30
    assert torch.equal(small.means, large.means)
    assert small.active_sh_degree == 2
