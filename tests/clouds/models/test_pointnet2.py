"""PointNet++: SSG and MSG, classification and segmentation, invariance to point order."""

from __future__ import annotations

import pytest
import torch

from pointfield.clouds.models import build_model, count_parameters
from pointfield.clouds.models.pointnet2 import (
    FeaturePropagation,
    PointNet2Classifier,
    PointNet2Segmenter,
)
from pointfield.errors import PointfieldError


def cloud_batch(batch: int = 2, points: int = 200) -> torch.Tensor:
    torch.manual_seed(0)
    return torch.randn(batch, points, 3) * 0.4


def test_parameter_counts():
    assert count_parameters(PointNet2Classifier(40)) == 1_472_360
    assert count_parameters(PointNet2Classifier(40, multi_scale=True)) == 1_742_856


@pytest.mark.parametrize("multi_scale", [False, True])
def test_output_shapes(multi_scale):
    points = cloud_batch()
    assert PointNet2Classifier(5, multi_scale=multi_scale)(points).shape == (2, 5)
    segmenter = PointNet2Segmenter(4, in_channels=3, multi_scale=multi_scale)
    assert segmenter(points, torch.randn(2, 200, 3)).shape == (2, 200, 4)


@pytest.mark.parametrize("model_class", [PointNet2Classifier, PointNet2Segmenter])
def test_shuffling_the_points_changes_nothing(model_class):
    model = model_class(6).eval()
    points = cloud_batch()
    order = torch.randperm(points.shape[1])
    with torch.no_grad():
        original, shuffled = model(points), model(points[:, order])
    if model_class is PointNet2Segmenter:
        original = original[:, order]
    torch.testing.assert_close(original, shuffled, atol=1e-5, rtol=1e-5)


def test_a_padded_cloud_gives_what_it_gives_alone():
    model = PointNet2Classifier(3).eval()
    points = cloud_batch(2, 150)
    mask = torch.ones(2, 150, dtype=torch.bool)
    mask[0, 90:] = False
    padded = points.clone()
    padded[0, 90:] = 9.0
    with torch.no_grad():
        torch.testing.assert_close(model(padded, mask=mask)[0], model(points[:1, :90])[0],
                                   atol=1e-5, rtol=1e-5)


def test_clouds_smaller_than_the_centroid_count_still_work():
    model = PointNet2Segmenter(3).eval()
    with torch.no_grad():
        assert model(cloud_batch(1, 40)).shape == (1, 40, 3)


def test_feature_propagation_reproduces_features_at_the_coarse_points():
    layer = FeaturePropagation(2, [])  # no MLP layers: the output is the interpolation
    coarse = torch.tensor([[[0.0, 0, 0], [1.0, 0, 0], [0.0, 1, 0]]])
    features = torch.tensor([[[1.0, 0], [0.0, 1], [2.0, 2]]])
    torch.testing.assert_close(layer(coarse, coarse, None, features), features,
                               atol=1e-6, rtol=0)


def test_build_model_rejects_unknown_names_and_options():
    with pytest.raises(PointfieldError, match="unknown model"):
        build_model("pointnet3", "classify", 2)
    with pytest.raises(PointfieldError, match="no options"):
        build_model("pointnet2", "classify", 2, input_transform=False)
