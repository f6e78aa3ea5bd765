"""Median depth: where the accumulated opacity reaches one half, padded and packed alike."""

from __future__ import annotations

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
