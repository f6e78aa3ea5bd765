"""Radiance fields: reconstruct a scene from posed photos and render new views.

The vocabulary follows the data (nerfstudio's): cameras -> rays -> samples -> field -> renderer.

- :mod:`~pointfield.fields.rays`: :class:`RayBundle` (rays with near and far bounds),
  :class:`SceneExtent` (where along any ray the scene lies: each ray's own near and far) and
  :class:`RaySamples` (intervals along them, padded ``(R, K)`` or packed ``(S,)``).
- :mod:`~pointfield.fields.training_rays`: the training pixels, their rays jittered inside them.
- :mod:`~pointfield.fields.sampling`: the samplers -- stratified and importance (NeRF),
  occupancy grid and ray marcher (bounded scenes), proposal networks (unbounded scenes).
- :mod:`~pointfield.fields.encodings`: Fourier features, the multiresolution hash grid,
  spherical harmonics, scene contraction.
- :mod:`~pointfield.fields.rendering`: the compositor (colour, depth, opacity, weights) of any
  field given as a callable ``(positions, directions) -> (sigma, rgb)``.
- :mod:`~pointfield.fields.field`: the model contract (:class:`RadianceField`,
  :class:`FieldOutput`), the :class:`RayBudget` of adaptive batches, :func:`render_in_chunks`.
- :mod:`~pointfield.fields.nerf`: TinyNeRF and NeRF (coarse + fine).
- :mod:`~pointfield.fields.ngp`: the fast field (``--model ngp``): hash-grid field and its sampler.
- :mod:`~pointfield.fields.models`: the models by name (:func:`build_model`).
- :mod:`~pointfield.fields.scene_box`: the box to reconstruct, bounded or unbounded.
- :mod:`~pointfield.fields.train`: training and evaluation on a scene (``pointfield nerf``).
- :mod:`~pointfield.fields.views`: rendering camera paths to GIF / MP4 / PNG.
- :mod:`~pointfield.fields.exercise`: the lesson's TinyNeRF exercise as a report.

Example::

    import torch
    from pointfield.fields import RayBundle, TinyNeRF

    model = TinyNeRF()
    rays = RayBundle(torch.zeros(8, 3), torch.tensor([[0.0, 0.0, 1.0]]).expand(8, 3),
                     torch.full((8,), 2.0), torch.full((8,), 6.0))
    model(rays).final.color.shape   # torch.Size([8, 3])
"""

from pointfield.fields.encodings import PositionalEncoding, positional_encoding
from pointfield.fields.field import FieldOutput, RadianceField, RayBudget, render_in_chunks
from pointfield.fields.models import MODELS, build_model
from pointfield.fields.nerf import NeRF, RadianceMLP, TinyNeRF
from pointfield.fields.ngp import InstantNGP
from pointfield.fields.rays import RayBundle, RaySamples, SceneExtent
from pointfield.fields.rendering import RenderedRays, composite, render_rays, render_weights_from_density
from pointfield.fields.sampling import hierarchical_samples, importance_samples, stratified_samples

__all__ = [
    "MODELS",
    "FieldOutput",
    "InstantNGP",
    "NeRF",
    "PositionalEncoding",
    "RadianceField",
    "RadianceMLP",
    "RayBudget",
    "RayBundle",
    "RaySamples",
    "RenderedRays",
    "SceneExtent",
    "TinyNeRF",
    "build_model",
    "composite",
    "hierarchical_samples",
    "importance_samples",
    "positional_encoding",
    "render_in_chunks",
    "render_rays",
    "render_weights_from_density",
    "stratified_samples",
]
