"""PointNet: shapes of the outputs, true parameter counts, permutation invariance, T-Nets."""

from __future__ import annotations

import pytest
import torch

from pointfield.clouds.models import build_model, count_parameters
from pointfield.clouds.models.pointnet import (
    PointNetClassifier,
    PointNetSegmenter,
    TNet,
    orthogonality_loss,
)


def test_classifier_and_segmenter_output_shapes():
    points = torch.randn(3, 40, 3)
    assert PointNetClassifier(7)(points).shape == (3, 7)
    assert PointNetSegmenter(5)(points).shape == (3, 40, 5)
    with_normals = PointNetClassifier(7, in_channels=3)
    assert with_normals(points, torch.randn(3, 40, 3)).shape == (3, 7)


def test_parameter_counts_are_those_measured_and_documented():
    lesson = PointNetClassifier(40, input_transform=False, feature_transform=False,
                                local_widths=(64,), global_widths=(128, 1024))
    assert count_parameters(lesson) == 809_064  # the lesson's "1.6M" network: about 0.81M
    bare = PointNetClassifier(40, input_transform=False, feature_transform=False)
    assert count_parameters(bare) == 817_512
    assert count_parameters(PointNetClassifier(40, feature_transform=False)) == 1_618_609
    assert count_parameters(PointNetClassifier(40)) == 3_473_969  # both T-Nets: about 3.5M


@pytest.mark.parametrize("model_class", [PointNetClassifier, PointNetSegmenter])
def test_shuffling_the_points_changes_nothing(model_class):
    torch.manual_seed(0)
    model = model_class(6).eval()
    points = torch.randn(2, 128, 3)
    order = torch.randperm(128)
    with torch.no_grad():
        original, shuffled = model(points), model(points[:, order])
    if model_class is PointNetSegmenter:
        original = original[:, order]  # per-point outputs follow their points
    torch.testing.assert_close(original, shuffled, atol=1e-5, rtol=1e-5)


def test_a_padded_cloud_gives_what_it_gives_alone():
    torch.manual_seed(1)
    model = PointNetClassifier(4).eval()
    small = torch.randn(1, 20, 3)
    batch = torch.cat([torch.cat([small, torch.full((1, 12, 3), 50.0)], dim=1),
                       torch.randn(1, 32, 3)])
    mask = torch.ones(2, 32, dtype=torch.bool)
    mask[0, 20:] = False
    with torch.no_grad():
        torch.testing.assert_close(model(batch, mask=mask)[0], model(small)[0],
                                   atol=1e-5, rtol=1e-5)


def test_tnets_start_as_the_identity():
    transform = TNet(64).eval()(torch.randn(2, 30, 64))
    torch.testing.assert_close(transform, torch.eye(64).expand(2, 64, 64))


def test_orthogonality_loss_is_zero_for_rotations_and_positive_otherwise():
    angle = torch.tensor(0.7)
    rotation = torch.tensor([[torch.cos(angle), -torch.sin(angle), 0],
                             [torch.sin(angle), torch.cos(angle), 0], [0, 0, 1]])
    assert orthogonality_loss(rotation[None]) < 1e-12
    assert orthogonality_loss(2 * rotation[None]) > 1


def test_the_regulariser_is_returned_to_the_training_step_when_asked():
    model = PointNetClassifier(3)
    logits, regulariser = model(torch.randn(4, 16, 3), with_regulariser=True)
    assert logits.shape == (4, 3)
    assert regulariser.requires_grad and regulariser >= 0
    assert not hasattr(model, "regulariser")  # nothing is left on the model by forward
    bare = PointNetClassifier(3, feature_transform=False)
    _, none = bare(torch.randn(4, 16, 3), with_regulariser=True)
    assert float(none) == 0


def test_build_model_by_name():
    model = build_model("pointnet", "segment", 5, input_transform=False)
    assert isinstance(model, PointNetSegmenter) and model.encoder.input_transform is None
