"""3D Gaussian splatting in plain PyTorch: model, rasterizer, densification, the splat .ply.

- :class:`Gaussians` (``gaussians.py``): means, wxyz quaternions, log-scales, opacity logits,
  SH colour up to degree 3; from points, at random in a box, or from a ``.ply``.
- :func:`rasterization` (``rasterizer.py``): the differentiable tile rasterizer (gsplat's
  conventions); :func:`rasterization_reference` (``reference.py``) its slow reference.
- :class:`DefaultStrategy` (``densification.py``): clone, split, prune, reset; SH schedule.
- :func:`read_splats`, :func:`write_splats` (``ply.py``): the standard splat ``.ply``.
- :func:`splat_loss` (``loss.py``): ``0.8 L1 + 0.2 (1 - SSIM)``.
- ``train.py``: :func:`~pointfield.splats.train.train`, ``render``, ``export`` (``pointfield splat``).
"""

from pointfield.splats.densification import DefaultStrategy
from pointfield.splats.gaussians import Gaussians
from pointfield.splats.loss import splat_loss
from pointfield.splats.ply import read_splats, write_splats
from pointfield.splats.rasterizer import rasterization
from pointfield.splats.reference import rasterization_reference

__all__ = [
    "DefaultStrategy",
    "Gaussians",
    "rasterization",
    "rasterization_reference",
    "read_splats",
    "splat_loss",
    "write_splats",
]
