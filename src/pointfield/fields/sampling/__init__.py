"""Where along each ray a radiance field is evaluated: the samplers.

- :mod:`~pointfield.fields.sampling.stratified`: NeRF's stratified samples and inverse-CDF
  importance (hierarchical) samples.
- :mod:`~pointfield.fields.sampling.occupancy`: bounded scenes -- Instant-NGP's occupancy grid
  and the ray marcher that skips empty cells (packed samples).
- :mod:`~pointfield.fields.sampling.proposal`: unbounded scenes -- nerfacto's proposal
  networks and sampler, with mip-NeRF 360's interlevel loss (its distortion loss, for any
  samples, is :func:`pointfield.fields.rendering.distortion_loss`).
"""

from pointfield.fields.sampling.occupancy import OccupancyGrid, march_rays, ray_box_intersection
from pointfield.fields.sampling.proposal import (
    ProposalNetwork,
    ProposalSampler,
    interlevel_loss,
    proposal_anneal,
)
from pointfield.fields.sampling.stratified import hierarchical_samples, importance_samples, stratified_samples

__all__ = [
    "OccupancyGrid",
    "ProposalNetwork",
    "ProposalSampler",
    "hierarchical_samples",
    "importance_samples",
    "interlevel_loss",
    "march_rays",
    "proposal_anneal",
    "ray_box_intersection",
    "stratified_samples",
]
