"""Median depth: where the accumulated opacity reaches one half, padded and packed alike."""

from __future__ import annotations

import math

import torch

from pointfield.fields.rays import RaySamples
from pointfield.fields.rendering import composite


def test_median_depth_is_the_first_sample_reaching_half_opacity_padded_and_packed():
    samples = RaySamples.from_points(torch.tensor([[2.0, 3.0, 4.0], [2.0, 3.0, 4.0], [2.0, 3.0, 4.0]]), 5.0)
    # ray 0: a faint layer at 3 (alpha 0.26) before a wall at 4; ray 1: a wall at 3; ray 2: only haze
    sigma = torch.tensor([[0.0, 0.3, 1e6], [0.0, 1e6, 1e6], [0.1, 0.1, 0.1]])
    colors = torch.rand(3, 3, 3)
    padded = composite(sigma, colors, samples)
    torch.testing.assert_close(padded.median_depth, torch.tensor([4.0, 3.0, 0.0]))
    assert 3.0 < padded.depth[0] < 4.0  # the expected depth falls between the layers
    packed_samples = samples.packed()
    keep = torch.ones(9, dtype=torch.bool)
    packed = composite(sigma.reshape(-1)[keep], colors.reshape(-1, 3)[keep], packed_samples)
    torch.testing.assert_close(packed.median_depth, padded.median_depth)


def test_depths_of_a_uniform_medium_match_its_closed_forms_whatever_the_sample_count():
    # Density sigma on [2, 10): the stopping distance is exponential, truncated to the medium.
    sigma, start, end = 0.5, 2.0, 10.0
    length = end - start
    expected = start + 1 / sigma - length * math.exp(-sigma * length) / (1 - math.exp(-sigma * length))
    median = start + math.log(2) / sigma
    for count in (1, 3, 40):
        t = torch.linspace(start, end, count + 1, dtype=torch.float64)[None]
        samples = RaySamples.from_bin_edges(t)
        out = composite(torch.full((1, count), sigma, dtype=torch.float64), torch.rand(1, count, 3, dtype=torch.float64),
                        samples)
        torch.testing.assert_close(out.depth, torch.tensor([expected], dtype=torch.float64))
        torch.testing.assert_close(out.median_depth, torch.tensor([median], dtype=torch.float64))


def test_an_opaque_interval_puts_the_depth_at_its_start_not_its_sample():
    # Intervals of 0.1 evaluated at their midpoints; the second is opaque: the ray stops at 2.1.
    samples = RaySamples.from_bin_edges(torch.tensor([[2.0, 2.1, 2.2, 2.3]]))
    out = composite(torch.tensor([[0.0, 1e5, 1e5]]), torch.rand(1, 3, 3), samples)
    torch.testing.assert_close(out.depth, torch.tensor([2.1]), atol=1e-4, rtol=0)
    torch.testing.assert_close(out.median_depth, torch.tensor([2.1]), atol=1e-4, rtol=0)
