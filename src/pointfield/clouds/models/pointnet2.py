"""PointNet++ (Qi et al., NeurIPS 2017): PointNet applied to local regions, hierarchically.

A set abstraction level turns N points into S < N centroids, each carrying a feature of its
neighbourhood::

    points (N, 3 + C) ─ farthest point sampling: S centroids
                      ─ ball query: for each centroid, K points within radius r
                      ─ PointNet on each group, coordinates relative to its centroid
                      ─> centroids (S, 3) with features (S, C')

The classifier (single-scale grouping, "SSG", the defaults below)::

    N points ─ SA(512 centroids, r 0.2, K 32; MLP 64, 64, 128)
             ─ SA(128 centroids, r 0.4, K 64; MLP 128, 128, 256)
             ─ SA(all points; MLP 256, 512, 1024) ─ FC 512 ─ FC 256 ─ FC k   (dropout 0.5)

Multi-scale grouping ("MSG") groups each centroid's neighbourhood at several radii and
concatenates the features. The segmenter propagates features back to every point: each
feature propagation level interpolates the coarser level's features at the finer level's
points, ``f(x) = Σ_i w_i f_i / Σ_i w_i`` over the 3 nearest coarse points with
``w_i = 1 / d(x, x_i)²``, concatenates the finer level's own features (a skip link) and
applies a shared MLP.

Differences from the original code. For permutation invariance: farthest point sampling
starts at the point farthest from the centroid (not at index 0), and the ball query keeps the
K *nearest* points inside the ball (not the first K in storage order); both make the result
independent of the order of the input points. For short trainings: offsets within a group are
divided by the ball radius (see :class:`GroupPointNet`).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from pointfield.clouds import batched
from pointfield.clouds.models.layers import (
    MLP,
    MaxPooledLinear,
    SharedMLP,
    apply_to_rows,
)

# (centroids, radius, neighbours, widths) per level of the single-scale networks.
SSG_LEVELS = ((512, 0.2, 32, (64, 64, 128)), (128, 0.4, 64, (128, 128, 256)))
GLOBAL_WIDTHS = (256, 512, 1024)
# (centroids, radii, neighbours, widths per radius) per level of the multi-scale classifier.
MSG_LEVELS = (
    (512, (0.1, 0.2, 0.4), (16, 32, 128), ((32, 32, 64), (64, 64, 128), (64, 96, 128))),
    (128, (0.2, 0.4, 0.8), (32, 64, 128), ((64, 64, 128), (128, 128, 256), (128, 128, 256))),
)
# The multi-scale segmenter's second level, as in the reference implementations.
MSG_SEGMENTATION_LEVEL_2 = (128, (0.4, 0.8), (64, 128), ((128, 128, 256), (128, 196, 256)))


class GroupPointNet(nn.Module):
    """A PointNet on every group: ``max_k MLP([(x_k - c) / r; f_k])`` over a group's K members.

    ``widths`` are the MLP's layer widths, the last one max-pooled. Offsets from the centroid
    are divided by the ball radius r (as PointNeXt does; the paper leaves them in metres), so
    the first layer sees unit-scale inputs at every level and its BatchNorm statistics settle
    within a few steps instead of hundreds.

    The first layer is linear, so it is applied to the N points *before* grouping and the
    centroid's share subtracted after: ``W [(x_k - c) / r; f_k] = W [x_k / r; f_k] -
    W_xyz c / r``. That is N rows of work instead of S·K (16 times fewer at the second level),
    for the same result.
    """

    def __init__(self, in_channels: int, widths: Sequence[int], radius: float):
        super().__init__()
        if len(widths) < 2:
            raise ValueError(f"a group PointNet needs at least 2 layers, got widths {widths}")
        self.radius = radius
        self.first = nn.Linear(in_channels + 3, widths[0], bias=False)
        self.first_activation = nn.Sequential(nn.BatchNorm1d(widths[0]), nn.ReLU())
        self.mlp = SharedMLP(widths[:-1])
        self.pool = MaxPooledLinear(widths[-2], widths[-1])

    def forward(
        self,
        xyz: torch.Tensor,
        features: torch.Tensor | None,
        centres: torch.Tensor,
        group: torch.Tensor,
    ) -> torch.Tensor:
        """``xyz`` (B, N, 3), ``features`` (B, N, C), ``centres`` (B, S, 3) and member indices
        ``group`` (B, S, K) -> (B, S, widths[-1])."""
        scaled = xyz / self.radius
        inputs = scaled if features is None else torch.cat([scaled, features], dim=-1)
        projected = self.first(inputs)
        offset = (centres / self.radius) @ self.first.weight[:, :3].T
        hidden = batched.gather_points(projected, group) - offset.unsqueeze(2)  # (B, S, K, C0)
        hidden = self.mlp(apply_to_rows(self.first_activation, hidden))
        batch, count, size, channels = hidden.shape
        return self.pool(hidden.reshape(batch * count, size, channels)).view(batch, count, -1)


class SetAbstraction(nn.Module):
    """One level: FPS centroids, then for each radius a ball query and a PointNet per group.

    ``(xyz (B, N, 3), features (B, N, C) | None, mask) -> (centroids (B, S, 3), features
    (B, S, sum of widths[-1]))`` with ``S = min(centroids, N)``. One radius is single-scale
    grouping; several are multi-scale. Group coordinates are relative to their centroid, as
    in the paper, and divided by the radius.
    """

    def __init__(
        self,
        centroids: int,
        radii: Sequence[float],
        neighbours: Sequence[int],
        in_channels: int,
        widths: Sequence[Sequence[int]],
    ):
        super().__init__()
        if not len(radii) == len(neighbours) == len(widths):
            raise ValueError("radii, neighbours and widths need one entry per scale")
        self.centroids = centroids
        self.radii = tuple(radii)
        self.neighbours = tuple(neighbours)
        self.scales = nn.ModuleList(
            GroupPointNet(in_channels, w, r) for w, r in zip(widths, radii)
        )
        self.out_channels = sum(w[-1] for w in widths)

    def forward(
        self,
        xyz: torch.Tensor,
        features: torch.Tensor | None,
        mask: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        # A level never takes more centroids than its input has points: for small clouds the
        # extra ones would only repeat the start point.
        count = min(self.centroids, xyz.shape[1])
        with torch.no_grad():
            chosen = batched.farthest_point_sample_batched(xyz, count, mask)
        centres = batched.gather_points(xyz, chosen)  # (B, S, 3)
        pooled = []
        for radius, size, pointnet in zip(self.radii, self.neighbours, self.scales):
            with torch.no_grad():
                group = batched.ball_query(centres, xyz, radius, size, mask)  # (B, S, K)
            pooled.append(pointnet(xyz, features, centres, group))
        return centres, torch.cat(pooled, dim=-1)


class GlobalAbstraction(nn.Module):
    """The last level: one group holding every point, centred on the origin -> ``(B, C')``."""

    def __init__(self, in_channels: int, widths: Sequence[int]):
        super().__init__()
        self.mlp = SharedMLP([in_channels + 3, *widths[:-1]])
        self.pool = MaxPooledLinear(([in_channels + 3, *widths])[-2], widths[-1])
        self.out_channels = widths[-1]

    def forward(self, xyz: torch.Tensor, features: torch.Tensor) -> torch.Tensor:
        return self.pool(self.mlp(torch.cat([xyz, features], dim=-1)))


class FeaturePropagation(nn.Module):
    """Interpolate coarse features at fine points, join the fine skip features, shared MLP.

    ``(fine_xyz (B, N, 3), coarse_xyz (B, S, 3), fine_features (B, N, C1) | None,
    coarse_features (B, S, C2), mask) -> (B, N, widths[-1])``; ``in_channels = C1 + C2``.
    With a single coarse point (the global level) its feature is copied to every point.
    """

    def __init__(self, in_channels: int, widths: Sequence[int]):
        super().__init__()
        self.mlp = SharedMLP([in_channels, *widths])

    def forward(
        self,
        fine_xyz: torch.Tensor,
        coarse_xyz: torch.Tensor,
        fine_features: torch.Tensor | None,
        coarse_features: torch.Tensor,
        mask: torch.Tensor | None = None,
    ) -> torch.Tensor:
        if coarse_xyz.shape[1] == 1:
            interpolated = coarse_features.expand(-1, fine_xyz.shape[1], -1)
        else:
            with torch.no_grad():
                distance, nearest = batched.knn(fine_xyz, coarse_xyz, min(3, coarse_xyz.shape[1]))
                weight = 1.0 / distance.clamp_min(1e-10)  # w_i = 1 / d², the paper's p = 2
                weight = weight / weight.sum(dim=-1, keepdim=True)
            neighbours = batched.gather_points(coarse_features, nearest)  # (B, N, 3, C2)
            interpolated = (neighbours * weight.unsqueeze(-1)).sum(dim=2)
        joined = interpolated if fine_features is None else torch.cat(
            [interpolated, fine_features], dim=-1
        )
        return self.mlp(joined, mask)


def _fill_padding(
    points: torch.Tensor, features: torch.Tensor | None, mask: torch.Tensor | None
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Give padding points the coordinates and features of their cloud's first point.

    Grouping may then pick a padding point only as a duplicate of a real one, which changes
    no max-pool; farthest point sampling is also told the mask and never starts from padding.
    """
    if mask is None:
        return points, features
    padding = ~mask[..., None]
    points = torch.where(padding, points[:, :1], points)
    if features is not None:
        features = torch.where(padding, features[:, :1], features)
    return points, features


def _encoder_levels(in_channels: int, multi_scale: bool, segmentation: bool) -> nn.ModuleList:
    if not multi_scale:
        specs = [(s, (r,), (k,), (w,)) for s, r, k, w in SSG_LEVELS]
    elif segmentation:
        specs = [MSG_LEVELS[0], MSG_SEGMENTATION_LEVEL_2]
    else:
        specs = list(MSG_LEVELS)
    levels, channels = nn.ModuleList(), in_channels
    for centroids, radii, neighbours, widths in specs:
        level = SetAbstraction(centroids, radii, neighbours, channels, widths)
        levels.append(level)
        channels = level.out_channels
    return levels


class PointNet2Classifier(nn.Module):
    """PointNet++ for shape classification: ``(B, N, 3) -> (B, num_classes)`` scores.

    ``multi_scale`` picks MSG instead of SSG. With ``with_regulariser`` it returns
    ``(logits, 0)``, as every pointfield cloud model does for the training step.
    """

    def __init__(
        self,
        num_classes: int,
        in_channels: int = 0,
        multi_scale: bool = False,
        dropout: float = 0.5,
    ):
        super().__init__()
        self.levels = _encoder_levels(in_channels, multi_scale, segmentation=False)
        self.global_level = GlobalAbstraction(self.levels[-1].out_channels, GLOBAL_WIDTHS)
        self.head = MLP([GLOBAL_WIDTHS[-1], 512, 256], num_classes, dropout)

    def forward(
        self,
        points: torch.Tensor,
        features: torch.Tensor | None = None,
        mask: torch.Tensor | None = None,
        with_regulariser: bool = False,
    ) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        xyz, features = _fill_padding(points, features, mask)
        for level in self.levels:
            xyz, features = level(xyz, features, mask)
            mask = None  # centroids are real points
        logits = self.head(self.global_level(xyz, features))
        return (logits, points.new_zeros(())) if with_regulariser else logits


class PointNet2Segmenter(nn.Module):
    """PointNet++ for per-point labels: ``(B, N, 3) -> (B, N, num_classes)`` scores.

    The encoder of the classifier (SSG, or MSG with ``multi_scale``), then three feature
    propagation levels back to the input points — (256, 256), (256, 128), (128, 128, 128) —
    and a per-point head 128 -> dropout 0.5 -> num_classes.
    """

    def __init__(
        self,
        num_classes: int,
        in_channels: int = 0,
        multi_scale: bool = False,
        dropout: float = 0.5,
    ):
        super().__init__()
        self.levels = _encoder_levels(in_channels, multi_scale, segmentation=True)
        first, second = self.levels[0].out_channels, self.levels[1].out_channels
        self.global_level = GlobalAbstraction(second, GLOBAL_WIDTHS)
        self.propagate = nn.ModuleList([
            FeaturePropagation(GLOBAL_WIDTHS[-1] + second, (256, 256)),
            FeaturePropagation(256 + first, (256, 128)),
            FeaturePropagation(128 + 3 + in_channels, (128, 128, 128)),
        ])
        self.head = nn.Sequential(SharedMLP([128, 128]), nn.Dropout(dropout), nn.Linear(128, num_classes))

    def forward(
        self,
        points: torch.Tensor,
        features: torch.Tensor | None = None,
        mask: torch.Tensor | None = None,
        with_regulariser: bool = False,
    ) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        xyz, filled = _fill_padding(points, features, mask)
        inputs = xyz if filled is None else torch.cat([xyz, filled], dim=-1)
        xyz_1, features_1 = self.levels[0](xyz, filled, mask)
        xyz_2, features_2 = self.levels[1](xyz_1, features_1)
        global_feature = self.global_level(xyz_2, features_2)[:, None, :]
        origin = xyz_2.new_zeros(len(xyz_2), 1, 3)
        up_2 = self.propagate[0](xyz_2, origin, features_2, global_feature)
        up_1 = self.propagate[1](xyz_1, xyz_2, features_1, up_2)
        up_0 = self.propagate[2](xyz, xyz_1, inputs, up_1, mask)
        hidden = self.head[0](up_0, mask)
        logits = self.head[2](self.head[1](hidden))
        return (logits, points.new_zeros(())) if with_regulariser else logits
