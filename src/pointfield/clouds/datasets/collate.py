"""Collation of clouds of different sizes into one padded, masked batch.

:class:`CloudCollate` is a DataLoader ``collate_fn``: it turns ``(cloud, label)`` samples into a
:class:`CloudBatch` whose points are padded to the largest cloud, with a mask marking the real
ones.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import torch

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.datasets.base import PART_LABEL_FIELD
from pointfield.errors import PointfieldError


@dataclass
class CloudBatch:
    """B clouds padded to a common size N, real points first.

    ``points`` ``(B, N, 3)`` float32; ``features`` ``(B, N, C)`` float32 extra per-point inputs
    (normals, ...) or None; ``mask`` ``(B, N)`` bool, True for real points, or None when every
    cloud has N points; ``labels`` ``(B,)`` int64 class indices; ``point_labels`` ``(B, N)``
    int64 part labels with -1 at padding, or None.
    """

    points: torch.Tensor
    labels: torch.Tensor
    features: torch.Tensor | None = None
    mask: torch.Tensor | None = None
    point_labels: torch.Tensor | None = None

    def __len__(self) -> int:
        return len(self.points)

    def to(self, device: torch.device | str) -> CloudBatch:
        def move(tensor: torch.Tensor | None) -> torch.Tensor | None:
            return None if tensor is None else tensor.to(device, non_blocking=True)

        return replace(
            self, points=move(self.points), labels=move(self.labels),
            features=move(self.features), mask=move(self.mask),
            point_labels=move(self.point_labels),
        )


class CloudCollate:
    """``collate(samples) -> CloudBatch`` for a DataLoader's ``collate_fn``.

    ``features`` names the per-point fields fed to the model besides xyz, in order (e.g.
    ``("normals",)``); their components are concatenated into ``CloudBatch.features``.
    ``point_labels`` True collects the ``label`` field for segmentation. A cloud with no points
    is an error here, never a silent NaN later. Clouds are padded to the longest of the batch, or
    to ``length`` if that is longer: with a fixed ``length`` a cloud's scores do not depend on the
    clouds it shares a batch with (PointNet++ takes as many first-level centroids as the batch
    is long, up to 512, repeating a short cloud's start point), which whole-scan prediction needs.
    """

    def __init__(self, features: Sequence[str] = (), point_labels: bool = False, length: int | None = None):
        self.features = tuple(features)
        self.point_labels = point_labels
        self.length = length or 0

    def __call__(self, samples: Sequence[tuple[PointCloud, int]]) -> CloudBatch:
        sizes = [len(cloud) for cloud, _ in samples]
        if min(sizes) == 0:
            raise PointfieldError("a cloud in the batch has no points")
        batch, size = len(samples), max(*sizes, self.length)
        points = torch.zeros(batch, size, 3)
        for cloud, _ in samples:  # every sample checked first: the error names the file that lacks a field
            for name in self.features:
                if name not in cloud.fields:
                    source = cloud.metadata.get("source", "a cloud of the batch")
                    raise PointfieldError(f"{source}: has no {name!r} field to use as a feature "
                                          f"(its fields: {', '.join(cloud.fields) or 'none'})")
        channels = sum(_channels(samples[0][0], name) for name in self.features)
        features = torch.zeros(batch, size, channels) if self.features else None
        point_labels = torch.full((batch, size), -1, dtype=torch.long) if self.point_labels else None
        mask = torch.zeros(batch, size, dtype=torch.bool)
        for row, (cloud, _) in enumerate(samples):
            n = len(cloud)
            points[row, :n] = torch.from_numpy(np.asarray(cloud.points, np.float32))
            mask[row, :n] = True
            if features is not None:
                columns = [_feature(cloud, name) for name in self.features]
                features[row, :n] = torch.from_numpy(np.concatenate(columns, axis=1))
            if point_labels is not None:
                if PART_LABEL_FIELD not in cloud.fields:
                    source = cloud.metadata.get("source", "a cloud of the batch")
                    raise PointfieldError(f"{source}: has no per-point {PART_LABEL_FIELD!r} field")
                point_labels[row, :n] = torch.from_numpy(
                    cloud.fields[PART_LABEL_FIELD].astype(np.int64)
                )
        labels = torch.tensor([label for _, label in samples], dtype=torch.long)
        return CloudBatch(
            points, labels, features, None if min(sizes) == size else mask, point_labels
        )


def _channels(cloud: PointCloud, name: str) -> int:
    return _feature(cloud, name).shape[1]


def _feature(cloud: PointCloud, name: str) -> np.ndarray:
    if name not in cloud.fields:
        raise PointfieldError(f"a cloud has no {name!r} field to use as a feature")
    values = cloud.fields[name].reshape(len(cloud), -1).astype(np.float32)
    return np.nan_to_num(values, nan=0.0, posinf=0.0, neginf=0.0)
