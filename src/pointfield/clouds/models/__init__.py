"""The PointNet family: one file per model, each reading like its paper's figure.

==================  =================================  ============================================
name                classification                     segmentation
==================  =================================  ============================================
``pointnet``        :class:`PointNetClassifier`        :class:`PointNetSegmenter`
``pointnet2``       :class:`PointNet2Classifier` SSG   :class:`PointNet2Segmenter` SSG
``pointnet2-msg``   :class:`PointNet2Classifier` MSG   :class:`PointNet2Segmenter` MSG
==================  =================================  ============================================

Every model maps ``points`` ``(B, N, 3)``, optional ``features`` ``(B, N, C)`` and ``mask``
``(B, N)`` to scores (logits): ``(B, classes)`` for classification, ``(B, N, classes)`` for
segmentation; called with ``with_regulariser=True`` it returns ``(logits, regulariser)``, a
scalar for the training step to add to the loss (PointNet's feature-transform regulariser; 0
for the others). :func:`build_model` makes one by name.
"""

from __future__ import annotations

from typing import Any

from torch import nn

from pointfield.clouds.models.pointnet import PointNetClassifier, PointNetSegmenter
from pointfield.clouds.models.pointnet2 import PointNet2Classifier, PointNet2Segmenter
from pointfield.errors import PointfieldError

MODEL_NAMES = ("pointnet", "pointnet2", "pointnet2-msg")
TASKS = ("classify", "segment")
# Options each model accepts, with their defaults (stored in a run's config.json).
MODEL_OPTIONS: dict[str, dict[str, Any]] = {
    "pointnet": {"input_transform": True, "feature_transform": True},
    "pointnet2": {},
    "pointnet2-msg": {},
}


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
    settings = {**MODEL_OPTIONS[name], **options}
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
    "build_model",
    "count_parameters",
]
