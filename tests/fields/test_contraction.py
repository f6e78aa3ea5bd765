"""Mapping world space onto the unit cube: the box map and mip-NeRF 360's scene contraction."""

import pytest
import torch

from pointfield.errors import PointfieldError
from pointfield.fields.encodings.contraction import box_to_unit, contract

CENTER = torch.tensor([0.5, -1.0, 2.0])
RADIUS = 3.0


def test_the_box_maps_affinely_onto_the_unit_cube():
    box = torch.tensor([[-1.0, 0.0, 2.0], [1.0, 4.0, 3.0]])
    torch.testing.assert_close(box_to_unit(box, box), torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]))
    torch.testing.assert_close(box_to_unit(box.mean(dim=0), box), torch.full((3,), 0.5))


def test_contraction_is_a_rescaling_inside_the_ball():
    directions = torch.nn.functional.normalize(torch.randn(100, 3, generator=torch.Generator().manual_seed(0)), dim=-1)
    inside = CENTER + directions * RADIUS * torch.rand(100, 1, generator=torch.Generator().manual_seed(1))
    torch.testing.assert_close(contract(inside, CENTER, RADIUS), ((inside - CENTER) / RADIUS + 2) / 4)


def test_contraction_sends_infinity_to_radius_two_and_keeps_everything_in_the_unit_cube():
    directions = torch.nn.functional.normalize(torch.randn(50, 3, generator=torch.Generator().manual_seed(2)), dim=-1)
    far_away = CENTER + directions * 1e12
    contracted = contract(far_away, CENTER, RADIUS) * 4 - 2
    torch.testing.assert_close(contracted.norm(dim=-1), torch.full((50,), 2.0))
    torch.testing.assert_close(contracted / 2, directions)
    unit = contract(CENTER + directions * torch.logspace(-3, 9, 50)[:, None], CENTER, RADIUS)
    assert unit.min() >= 0 and unit.max() <= 1


def test_contraction_follows_the_formula_outside_the_ball():
    # ||x'|| = 4: (2 - 1/4) x' / 4 = 1.75 along the axis.
    point = CENTER + torch.tensor([0.0, 4 * RADIUS, 0.0])
    torch.testing.assert_close(contract(point, CENTER, RADIUS), torch.tensor([0.5, (1.75 + 2) / 4, 0.5]))


def test_contraction_is_continuous_across_the_ball_boundary():
    direction = torch.nn.functional.normalize(torch.tensor([1.0, 2.0, -0.5]), dim=0)
    just_in = contract(CENTER + direction * RADIUS * (1 - 1e-6), CENTER, RADIUS)
    just_out = contract(CENTER + direction * RADIUS * (1 + 1e-6), CENTER, RADIUS)
    assert (just_in - just_out).abs().max() < 1e-5


def test_contraction_gradient_is_finite_at_the_centre_and_right_everywhere():
    points = torch.stack([CENTER, CENTER + torch.tensor([7.0, 0.0, 0.0])]).double().requires_grad_()
    contract(points, CENTER.double(), RADIUS)[:, 0].sum().backward()
    assert torch.isfinite(points.grad).all()
    # At the centre the map is x / (4 r); outside, d/dx of (2 - r/x)/4 along the axis is r / (4 x^2).
    torch.testing.assert_close(points.grad[0], torch.tensor([1 / (4 * RADIUS), 0, 0], dtype=torch.float64))
    torch.testing.assert_close(points.grad[1], torch.tensor([RADIUS / (4 * 7.0**2), 0, 0], dtype=torch.float64))


def test_contraction_rejects_a_non_positive_radius():
    with pytest.raises(PointfieldError, match="radius"):
        contract(torch.zeros(1, 3), torch.zeros(3), 0.0)


