"""The splat model: a set of 3D Gaussians with opacity and spherical-harmonic colour.

Each of the N Gaussians is stored the way the original 3D Gaussian splatting code (and every
standard splat ``.ply``) stores it, so that optimisation is unconstrained:

==================  ===============  ========================================================
parameter           shape            meaning
==================  ===============  ========================================================
``means``           ``(N, 3)``       centre in world coordinates
``quats``           ``(N, 4)``       rotation as a quaternion **wxyz**, not necessarily unit:
                                     it is normalised wherever it is used
``log_scales``      ``(N, 3)``       log of the standard deviations along the rotated axes
``opacity_logits``  ``(N,)``         ``opacity = sigmoid(opacity_logit)``
``sh_dc``           ``(N, 1, 3)``    degree-0 SH coefficient per colour channel
``sh_rest``         ``(N, K-1, 3)``  higher SH coefficients, K = (sh_degree + 1)^2
==================  ===============  ========================================================

The covariance is ``Sigma = R S S^T R^T`` with ``R`` the rotation of the normalised quaternion
and ``S = diag(exp(log_scales))``. ``active_sh_degree`` (0 .. ``sh_degree``) is how many SH bands
rendering uses; training raises it step by step.

The number of Gaussians changes while training: densification swaps each parameter for a
longer or shorter one and updates the optimizer to match
(:func:`pointfield.splats.densification.replace_parameter`), and
:meth:`Gaussians.load_state_dict` resizes the model to the checkpoint it loads.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from pointfield.fields.encodings.spherical_harmonics import rgb_to_sh_dc, sh_coefficient_count

PARAMETER_NAMES = ("means", "quats", "log_scales", "opacity_logits", "sh_dc", "sh_rest")


def quaternion_to_rotation(quats: torch.Tensor) -> torch.Tensor:
    """Rotation matrices ``(N, 3, 3)`` of quaternions ``(N, 4)`` in wxyz order (normalised here)."""
    w, x, y, z = (quats / quats.norm(dim=-1, keepdim=True)).unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).reshape(*quats.shape[:-1], 3, 3)


def covariances(quats: torch.Tensor, scales: torch.Tensor) -> torch.Tensor:
    """World-space covariances ``(N, 3, 3)``: ``R S S^T R^T`` from wxyz ``quats`` and ``scales`` (N, 3)."""
    rotation_scale = quaternion_to_rotation(quats) * scales[:, None, :]
    return rotation_scale @ rotation_scale.transpose(1, 2)


class Gaussians(nn.Module):
    """N 3D Gaussians (see the module docstring for the parameters and their conventions).

    Build one with :meth:`from_points` (a point cloud: COLMAP sparse points, a synthetic
    scene's surface points, gsplat's garden points), :meth:`random_in_box`, or directly from
    the six parameter tensors (as the ``.ply`` reader does).
    """

    def __init__(
        self,
        means: torch.Tensor,
        quats: torch.Tensor,
        log_scales: torch.Tensor,
        opacity_logits: torch.Tensor,
        sh_dc: torch.Tensor,
        sh_rest: torch.Tensor,
        active_sh_degree: int | None = None,
    ):
        super().__init__()
        count = means.shape[0]
        expected = {
            "means": (count, 3), "quats": (count, 4), "log_scales": (count, 3),
            "opacity_logits": (count,), "sh_dc": (count, 1, 3),
        }
        given = dict(zip(PARAMETER_NAMES, (means, quats, log_scales, opacity_logits, sh_dc, sh_rest)))
        for name, shape in expected.items():
            if tuple(given[name].shape) != shape:
                raise ValueError(f"{name} must have shape {shape}, got {tuple(given[name].shape)}")
        if sh_rest.ndim != 3 or sh_rest.shape[0] != count or sh_rest.shape[2] != 3:
            raise ValueError(f"sh_rest must have shape ({count}, K-1, 3), got {tuple(sh_rest.shape)}")
        coefficients = sh_rest.shape[1] + 1
        self.sh_degree = next((d for d in range(4) if (d + 1) ** 2 == coefficients), None)
        if self.sh_degree is None:
            raise ValueError(f"{coefficients} SH coefficients per channel is not 1, 4, 9 or 16")
        for name, value in given.items():
            setattr(self, name, nn.Parameter(value.detach().clone()))
        self.active_sh_degree = self.sh_degree if active_sh_degree is None else int(active_sh_degree)
        # Mip-Splatting's 3D filter variance per splat (N,), or None: not a parameter and not
        # saved, recomputed from the training cameras (pointfield.splats.mip).
        self.smoothing: torch.Tensor | None = None

    # -- construction ------------------------------------------------------------------------

    @classmethod
    def from_points(
        cls,
        points,
        colors=None,
        *,
        sh_degree: int = 3,
        opacity: float = 0.1,
        neighbours: int = 3,
        dtype: torch.dtype = torch.float32,
    ) -> Gaussians:
        """Isotropic Gaussians centred on ``points`` ``(N, 3)``, as the 3DGS paper initialises.

        ``colors`` ``(N, 3)`` are floats in [0, 1] or uint8 (grey 0.5 when None). Each scale is
        the root mean square distance to the ``neighbours`` nearest other points (so the
        splats just cover the cloud's surface); rotations are the identity, opacities
        ``opacity``, higher SH coefficients zero. Active SH degree starts at 0.
        """
        means = torch.as_tensor(np.asarray(points), dtype=dtype)
        if means.ndim != 2 or means.shape[1] != 3 or len(means) == 0:
            raise ValueError(f"points must be a non-empty (N, 3) array, got shape {tuple(means.shape)}")
        count = len(means)
        if colors is None:
            rgb = torch.full((count, 3), 0.5, dtype=dtype)
        else:
            colors = np.asarray(colors)
            rgb = torch.as_tensor(colors[:, :3], dtype=dtype)
            if colors.dtype == np.uint8:
                rgb = rgb / 255
            elif colors.dtype == np.uint16:
                rgb = rgb / 65535
        distance = nearest_neighbour_distance(means, neighbours).clamp_min(1e-7)
        return cls(
            means=means,
            quats=torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=dtype).repeat(count, 1),
            log_scales=torch.log(distance)[:, None].repeat(1, 3),
            opacity_logits=torch.full((count,), math.log(opacity / (1 - opacity)), dtype=dtype),
            sh_dc=rgb_to_sh_dc(rgb)[:, None, :],
            sh_rest=torch.zeros(count, sh_coefficient_count(sh_degree) - 1, 3, dtype=dtype),
            active_sh_degree=0,
        )

    @classmethod
    def random_in_box(
        cls,
        count: int,
        low,
        high,
        *,
        sh_degree: int = 3,
        opacity: float = 0.1,
        seed: int = 0,
        dtype: torch.dtype = torch.float32,
    ) -> Gaussians:
        """``count`` Gaussians uniformly in the box ``[low, high]`` (each (3,)), random colours."""
        generator = torch.Generator().manual_seed(seed)
        low = torch.as_tensor(np.asarray(low, dtype=np.float64), dtype=dtype)
        high = torch.as_tensor(np.asarray(high, dtype=np.float64), dtype=dtype)
        points = low + (high - low) * torch.rand(count, 3, generator=generator, dtype=dtype)
        colors = torch.rand(count, 3, generator=generator, dtype=dtype)
        return cls.from_points(points.numpy(), colors.numpy(), sh_degree=sh_degree, opacity=opacity, dtype=dtype)

    # -- derived quantities ------------------------------------------------------------------

    def __len__(self) -> int:
        return self.means.shape[0]

    @property
    def scales(self) -> torch.Tensor:
        """Standard deviations along the rotated axes ``(N, 3)``: ``exp(log_scales)``."""
        return torch.exp(self.log_scales)

    @property
    def opacities(self) -> torch.Tensor:
        """``(N,)`` opacities in (0, 1): ``sigmoid(opacity_logits)``."""
        return torch.sigmoid(self.opacity_logits)

    @property
    def sh_coefficients(self) -> torch.Tensor:
        """All SH coefficients ``(N, K, 3)``: ``sh_dc`` followed by ``sh_rest``."""
        return torch.cat([self.sh_dc, self.sh_rest], dim=1)

    def parameters_by_name(self) -> dict[str, nn.Parameter]:
        return {name: getattr(self, name) for name in PARAMETER_NAMES}

    def __repr__(self) -> str:
        return (f"Gaussians({len(self)} splats, SH degree {self.sh_degree} "
                f"(active {self.active_sh_degree}), {self.means.dtype})")

    # -- resizing ----------------------------------------------------------------------------

    def get_extra_state(self) -> dict[str, int]:
        return {"active_sh_degree": int(self.active_sh_degree)}

    def set_extra_state(self, state: dict[str, int]) -> None:
        self.active_sh_degree = int(state["active_sh_degree"])

    def load_state_dict(self, state_dict, strict: bool = True, assign: bool = False):
        """Load parameters of any splat count: each parameter is first resized to the state's."""
        for name in PARAMETER_NAMES:
            if name in state_dict:
                parameter = getattr(self, name)
                if parameter.shape[1:] != state_dict[name].shape[1:]:
                    raise RuntimeError(
                        f"{name} has shape {tuple(state_dict[name].shape)} in the checkpoint, "
                        f"expected (N, {', '.join(map(str, parameter.shape[1:]))})"
                    )
                # In place, so an optimizer built on this model still holds its parameters
                # (resuming loads the model, then the optimizer's state for the same objects).
                parameter.data = torch.empty_like(state_dict[name], dtype=parameter.dtype, device=parameter.device)
        return super().load_state_dict(state_dict, strict=strict, assign=assign)


def nearest_neighbour_distance(points: torch.Tensor, neighbours: int = 3) -> torch.Tensor:
    """Root mean square distance of each point ``(N, 3)`` to its ``neighbours`` nearest others: ``(N,)``.

    A k-d tree (scipy) makes this O(N log N): gsplat's 138,766 garden points take well under
    a second. With a single point, 1.
    """
    from scipy.spatial import cKDTree

    count = len(points)
    if count == 1:
        return torch.ones(1, dtype=points.dtype)
    k = min(neighbours, count - 1)
    array = points.detach().cpu().double().numpy()
    # The k + 1 nearest include the point itself at distance 0.
    distances, _ = cKDTree(array).query(array, k=k + 1)
    squared = distances[:, 1:] ** 2
    return torch.as_tensor(np.sqrt(squared.mean(1)), dtype=points.dtype)
