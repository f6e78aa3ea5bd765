"""PointNet (Qi et al., CVPR 2017): a shared per-point MLP, then a symmetric max-pool.

    f(P) = γ( max_{p in P} h(p) )

h is an MLP applied to each point independently and the max is taken channel by channel, so
f does not depend on the order of the points, nor on duplicated points. The paper's figure,
as this file builds it (widths are the defaults)::

    points (N, 3) ─ [input T-Net: 3x3] ─ shared MLP (64, 64) ─ [feature T-Net: 64x64] ─┐
                                                                                       │ local (N, 64)
                          shared MLP (64, 128, 1024) ─ max-pool ─ global (1024) ───────┤
    classification:  global ─ FC 512 ─ FC 256 ─ dropout ─ FC k           ─> (k) scores │
    segmentation:    [local, global] per point ─ 512 ─ 256 ─ 128 ─ k  ─> (N, k) scores ┘

A T-Net is a small PointNet that predicts a transform applied to the points (3x3) or to the
local features (64x64), starting from the identity. The feature transform is kept near a
rotation by the paper's regulariser ``L_reg = ||I - A A^T||_F²`` (weight 0.001), which each
forward pass leaves in ``model.regulariser`` for the training step to add to the loss.

Parameters (measured, see docs/models.md): classifier for 40 classes with both T-Nets
3,473,969; with the input T-Net only 1,618,609; without T-Nets 817,512.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from pointfield.clouds.models.layers import MLP, MaxPooledLinear, SharedMLP, apply_to_rows

REGULARISER_WEIGHT = 0.001


class TNet(nn.Module):
    """Predicts a ``k x k`` matrix from a cloud of k-dimensional points: ``(B, N, k) -> (B, k, k)``.

    A PointNet of its own: shared MLP (k, 64, 128, 1024), max-pool, FC 512, 256, then a linear
    layer to k² numbers added to the identity. That layer starts at zero, so the transform
    starts as the identity and training moves it only as far as it helps.
    """

    def __init__(self, k: int):
        super().__init__()
        self.k = k
        self.points = SharedMLP([k, 64, 128])
        self.pool = MaxPooledLinear(128, 1024)
        self.regress = MLP([1024, 512, 256], k * k)
        nn.init.zeros_(self.regress.out.weight)
        nn.init.zeros_(self.regress.out.bias)

    def forward(self, x: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        pooled = self.pool(self.points(x, mask), mask)
        offset = self.regress(pooled).view(-1, self.k, self.k)
        return torch.eye(self.k, dtype=x.dtype, device=x.device) + offset


def orthogonality_loss(transform: torch.Tensor) -> torch.Tensor:
    """``mean_b ||I - A_b A_b^T||_F²`` for transforms ``(B, k, k)``: 0 exactly for rotations."""
    identity = torch.eye(transform.shape[-1], dtype=transform.dtype, device=transform.device)
    gram = transform @ transform.transpose(1, 2)
    return ((identity - gram) ** 2).sum(dim=(1, 2)).mean()


class PointNetEncoder(nn.Module):
    """Points to a global feature and per-point local features.

    ``points`` ``(B, N, 3)``, optional per-point ``features`` ``(B, N, in_channels)``
    (normals, ...) and ``mask`` ``(B, N)``. Returns ``(global (B, global_widths[-1]),
    local (B, N, local_widths[-1]), regulariser)``; the regulariser is the weighted
    orthogonality loss of the feature transform, 0 without one.

    ``local_widths`` are the layers before the feature transform, ``global_widths`` those after
    it, the last of which is max-pooled. The paper: (64, 64) and (64, 128, 1024); the lesson's
    smaller network: (64,) and (128, 1024). The input transform turns xyz only.
    """

    def __init__(
        self,
        in_channels: int = 0,
        local_widths: Sequence[int] = (64, 64),
        global_widths: Sequence[int] = (64, 128, 1024),
        input_transform: bool = True,
        feature_transform: bool = True,
    ):
        super().__init__()
        self.input_transform = TNet(3) if input_transform else None
        self.local_mlp = SharedMLP([3 + in_channels, *local_widths])
        self.feature_transform = TNet(local_widths[-1]) if feature_transform else None
        self.global_mlp = SharedMLP([local_widths[-1], *global_widths[:-1]])
        self.pool = MaxPooledLinear((local_widths[-1], *global_widths)[-2], global_widths[-1])
        self.local_channels = local_widths[-1]
        self.global_channels = global_widths[-1]

    def forward(
        self,
        points: torch.Tensor,
        features: torch.Tensor | None = None,
        mask: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        if self.input_transform is not None:
            points = points @ self.input_transform(points, mask)  # rows: p' = p A
        x = points if features is None else torch.cat([points, features], dim=-1)
        local = self.local_mlp(x, mask)
        regulariser = points.new_zeros(())
        if self.feature_transform is not None:
            transform = self.feature_transform(local, mask)
            local = local @ transform
            regulariser = REGULARISER_WEIGHT * orthogonality_loss(transform)
        pooled = self.pool(self.global_mlp(local, mask), mask)
        return pooled, local, regulariser


class PointNetClassifier(nn.Module):
    """PointNet for shape classification: ``(B, N, 3) -> (B, num_classes)`` scores (logits).

    Encoder, then FC 512 and 256 with BatchNorm and ReLU and dropout 0.3 (the paper keeps
    0.7), then a linear layer to the class scores. ``model(..., with_regulariser=True)``
    returns ``(logits, regulariser)``: the feature T-Net's orthogonality loss, for the training step.
    """

    def __init__(
        self,
        num_classes: int,
        in_channels: int = 0,
        input_transform: bool = True,
        feature_transform: bool = True,
        local_widths: Sequence[int] = (64, 64),
        global_widths: Sequence[int] = (64, 128, 1024),
        head_widths: Sequence[int] = (512, 256),
        dropout: float = 0.3,
    ):
        super().__init__()
        self.encoder = PointNetEncoder(
            in_channels, local_widths, global_widths, input_transform, feature_transform
        )
        self.head = MLP([self.encoder.global_channels, *head_widths], num_classes, dropout)

    def forward(
        self,
        points: torch.Tensor,
        features: torch.Tensor | None = None,
        mask: torch.Tensor | None = None,
        with_regulariser: bool = False,
    ) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        pooled, _, regulariser = self.encoder(points, features, mask)
        logits = self.head(pooled)
        return (logits, regulariser) if with_regulariser else logits


class PointNetSegmenter(nn.Module):
    """PointNet for per-point labels: ``(B, N, 3) -> (B, N, num_classes)`` scores (logits).

    Each point's local feature (64) is joined to the cloud's global feature (1024) and an MLP
    (512, 256, 128) maps the pair to part scores. The first layer acts on the concatenation
    ``[local, global]`` as ``W_l local + W_g global``: the global half is computed once per
    cloud instead of once per point.
    """

    def __init__(
        self,
        num_classes: int,
        in_channels: int = 0,
        input_transform: bool = True,
        feature_transform: bool = True,
        local_widths: Sequence[int] = (64, 64),
        global_widths: Sequence[int] = (64, 128, 1024),
        head_widths: Sequence[int] = (512, 256, 128),
    ):
        super().__init__()
        self.encoder = PointNetEncoder(
            in_channels, local_widths, global_widths, input_transform, feature_transform
        )
        self.from_local = nn.Linear(self.encoder.local_channels, head_widths[0], bias=False)
        self.from_global = nn.Linear(self.encoder.global_channels, head_widths[0], bias=False)
        self.joint = nn.Sequential(nn.BatchNorm1d(head_widths[0]), nn.ReLU())
        self.head = SharedMLP(head_widths)
        self.out = nn.Linear(head_widths[-1], num_classes)

    def forward(
        self,
        points: torch.Tensor,
        features: torch.Tensor | None = None,
        mask: torch.Tensor | None = None,
        with_regulariser: bool = False,
    ) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        pooled, local, regulariser = self.encoder(points, features, mask)
        joined = self.from_local(local) + self.from_global(pooled)[:, None, :]
        logits = self.out(self.head(apply_to_rows(self.joint, joined, mask), mask))
        return (logits, regulariser) if with_regulariser else logits
