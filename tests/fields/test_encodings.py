"""Fourier positional encoding gamma(p)."""

import math

import torch

from pointfield.fields.encodings.fourier import PositionalEncoding, positional_encoding


def test_encoding_is_p_then_sines_and_cosines_of_doubling_frequencies():
    p = torch.tensor([[0.1, -0.3, 0.7]], dtype=torch.float64)
    encoded = positional_encoding(p, 3)
    assert encoded.shape == (1, 3 * 7)
    torch.testing.assert_close(encoded[:, :3], p)
    for k in range(3):
        block = encoded[:, 3 + 6 * k : 3 + 6 * (k + 1)]
        torch.testing.assert_close(block[:, :3], torch.sin(2**k * math.pi * p))
        torch.testing.assert_close(block[:, 3:], torch.cos(2**k * math.pi * p))


def test_nerf_widths_are_63_for_positions_and_27_for_directions():
    assert PositionalEncoding(10).output_dim(3) == 63 == PositionalEncoding(10)(torch.zeros(5, 3)).shape[-1]
    assert PositionalEncoding(4).output_dim(3) == 27
    assert PositionalEncoding(4, include_input=False)(torch.zeros(2, 7, 3)).shape == (2, 7, 24)
