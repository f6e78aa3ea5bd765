"""Radiance fields: reconstruct a scene from posed photos and render new views.

The vocabulary follows the data: cameras -> rays -> samples -> field -> compositing -> pixels.

- :mod:`~pointfield.fields.encodings`: Fourier positional encoding gamma(p).
- :mod:`~pointfield.fields.sampling`: stratified samples, inverse-CDF importance sampling.
- :mod:`~pointfield.fields.rendering`: volumetric compositing (colour, depth, opacity, weights)
  of any field given as a callable ``(positions, directions) -> (sigma, rgb)``.
- :mod:`~pointfield.fields.nerf`: TinyNeRF and NeRF (coarse + fine).
- :mod:`~pointfield.fields.hashgrid`: Instant-NGP's multiresolution hash encoding (and its reference).
- :mod:`~pointfield.fields.ngp`: the fast field (``--model ngp``): hash grid, occupancy grid,
  packed ray marching, early termination.
- :mod:`~pointfield.fields.proposal`: unbounded scenes: scene contraction, proposal sampler.
- :mod:`~pointfield.fields.train`: training and evaluation on a scene (``pointfield nerf``).
- :mod:`~pointfield.fields.views`: rendering camera paths to GIF / MP4 / PNG.
- :mod:`~pointfield.fields.exercise`: the lesson's TinyNeRF exercise as a report.

Example::

    import torch
    from pointfield.fields import TinyNeRF, composite_along_rays, stratified_samples

    model = TinyNeRF()
    origins, directions = torch.zeros(8, 3), torch.tensor([[0.0, 0.0, 1.0]]).expand(8, 3)
    [rendered] = model(origins, directions, torch.full((8,), 2.0), torch.full((8,), 6.0))
    rendered.color.shape   # torch.Size([8, 3])
"""

from pointfield.fields.encodings import PositionalEncoding, positional_encoding
from pointfield.fields.nerf import MODELS, NeRF, RadianceMLP, TinyNeRF, build_model, render_in_chunks
from pointfield.fields.rendering import RenderedRays, composite_along_rays, render_rays, render_weights_from_density
from pointfield.fields.sampling import hierarchical_samples, importance_samples, sample_deltas, stratified_samples

__all__ = [
    "MODELS",
    "NeRF",
    "PositionalEncoding",
    "RadianceMLP",
    "RenderedRays",
    "TinyNeRF",
    "build_model",
    "composite_along_rays",
    "hierarchical_samples",
    "importance_samples",
    "positional_encoding",
    "render_in_chunks",
    "render_rays",
    "render_weights_from_density",
    "sample_deltas",
    "stratified_samples",
]
