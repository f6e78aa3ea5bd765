"""The PointNet family: one file per model, each reading like its paper's figure.

==================  =================================  ============================================
name                classification                     segmentation
==================  =================================  ============================================
``pointnet``        :class:`PointNetClassifier`        :class:`PointNetSegmenter`
``pointnet2``       :class:`PointNet2Classifier` SSG   :class:`PointNet2Segmenter` SSG
``pointnet2-msg``   :class:`PointNet2Classifier` MSG   :class:`PointNet2Segmenter` MSG
``ptv3``            —                                  :class:`PTv3Segmenter` (Point Transformer V3)
==================  =================================  ============================================

Every model maps ``points`` ``(B, N, 3)``, optional ``features`` ``(B, N, C)`` and ``mask``
``(B, N)`` to scores (logits): ``(B, classes)`` for classification, ``(B, N, classes)`` for
segmentation; called with ``with_regulariser=True`` it returns ``(logits, regulariser)``, a
scalar for the training step to add to the loss (PointNet's feature-transform regulariser; 0
for the others). :func:`build_model` makes one by name. Point Transformer V3 segments only: it is
the scene backbone beside PointNet++ (``pointfield segment train DATA --model ptv3``).
"""

from __future__ import annotations

from typing import Any

from torch import nn

from pointfield.clouds.models.pointnet import PointNetClassifier, PointNetSegmenter
from pointfield.clouds.models.pointnet2 import PointNet2Classifier, PointNet2Segmenter
from pointfield.clouds.models.ptv3 import PTv3Segmenter
from pointfield.errors import PointfieldError

MODEL_NAMES = ("pointnet", "pointnet2", "pointnet2-msg", "ptv3")
TASKS = ("classify", "segment")
# Options each model accepts, with their defaults (stored in a run's config.json).
MODEL_OPTIONS: dict[str, dict[str, Any]] = {
    "pointnet": {"input_transform": True, "feature_transform": True},
    "pointnet2": {},
    "pointnet2-msg": {},
    # voxel: the level-0 voxel in the crops' units; the scene task sets it to grid / radius.
    "ptv3": {"voxel": 0.025, "patch": 64},
}
# Models for scene segmentation only (pointfield.clouds.scene_tasks), not for object tasks.
SCENE_ONLY = ("ptv3",)


def build_model(
    name: str, task: str, num_classes: int, in_channels: int = 0, **options: Any
) -> nn.Module:
    """A new model ``name`` for ``task`` ("classify" or "segment") with ``num_classes`` outputs.

    ``in_channels`` counts per-point input features besides xyz (3 for normals); ``options``
    are the model's own (see :data:`MODEL_OPTIONS`).
    """
    if name not in MODEL_NAMES:
        raise PointfieldError(f"unknown model {name!r}: expected one of {', '.join(MODEL_NAMES)}")
    if task not in TASKS:
        raise PointfieldError(f"unknown task {task!r}: expected one of {', '.join(TASKS)}")
    unknown = set(options) - set(MODEL_OPTIONS[name])
    if unknown:
        raise PointfieldError(f"model {name!r} has no options {sorted(unknown)}")
    if task == "classify" and name in SCENE_ONLY:
        raise PointfieldError(f"model {name!r} segments scenes; it does not classify: use pointnet or pointnet2")
    settings = {**MODEL_OPTIONS[name], **options}
    if name == "ptv3":
        return PTv3Segmenter(num_classes, in_channels, **settings)
    if name == "pointnet":
        model_class = PointNetClassifier if task == "classify" else PointNetSegmenter
        return model_class(num_classes, in_channels, **settings)
    model_class = PointNet2Classifier if task == "classify" else PointNet2Segmenter
    return model_class(num_classes, in_channels, multi_scale=name == "pointnet2-msg")


def count_parameters(model: nn.Module) -> int:
    """The number of trainable numbers in ``model`` (what papers call its parameters)."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)


__all__ = [
    "MODEL_NAMES",
    "MODEL_OPTIONS",
    "PointNet2Classifier",
    "PointNet2Segmenter",
    "PointNetClassifier",
    "PointNetSegmenter",
    "PTv3Segmenter",
    "SCENE_ONLY",
    "build_model",
    "count_parameters",
]
