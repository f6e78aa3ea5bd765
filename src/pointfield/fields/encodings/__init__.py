"""Encodings that let a small MLP represent fine detail, and the maps into their domain.

- :mod:`~pointfield.fields.encodings.fourier`: NeRF's Fourier positional encoding gamma(p).
- :mod:`~pointfield.fields.encodings.hashgrid`: Instant-NGP's multiresolution hash encoding,
  with its slow reference implementation.
- :mod:`~pointfield.fields.encodings.spherical_harmonics`: the real SH basis of view
  directions (the fast field's colour input; the splats' view-dependent colour).
- :mod:`~pointfield.fields.encodings.contraction`: world space onto the unit cube (box map,
  mip-NeRF 360 scene contraction).
"""

from pointfield.fields.encodings.contraction import box_to_unit, contract
from pointfield.fields.encodings.fourier import (
    DIRECTION_FREQUENCIES,
    POSITION_FREQUENCIES,
    PositionalEncoding,
    positional_encoding,
)
from pointfield.fields.encodings.hashgrid import HashEncoding, reference_hash_encoding
from pointfield.fields.encodings.spherical_harmonics import sh_basis, sh_to_rgb

__all__ = [
    "DIRECTION_FREQUENCIES",
    "POSITION_FREQUENCIES",
    "HashEncoding",
    "PositionalEncoding",
    "box_to_unit",
    "contract",
    "positional_encoding",
    "reference_hash_encoding",
    "sh_basis",
    "sh_to_rgb",
]
