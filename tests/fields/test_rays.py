"""Rays and samples: one RayBundle, one RaySamples in a padded and a packed layout."""

import pytest
import torch

from pointfield.fields.rays import RayBundle, RaySamples


def _bundle(count: int) -> RayBundle:
    generator = torch.Generator().manual_seed(count)
    directions = torch.nn.functional.normalize(torch.randn(count, 3, generator=generator), dim=-1)
    return RayBundle(torch.randn(count, 3, generator=generator), directions, torch.rand(count, generator=generator),
                     2 + torch.rand(count, generator=generator))


def test_a_bundle_is_indexed_by_slices_masks_and_index_tensors_alike():
    rays = _bundle(6)
    mask = torch.tensor([True, False, True, False, False, True])
    for index, expected in ((slice(1, 4), [1, 2, 3]), (mask, [0, 2, 5]), (torch.tensor([4, 0]), [4, 0])):
        picked = rays[index]
        assert len(picked) == len(expected)
        for name in ("origins", "directions", "near", "far"):
            assert torch.equal(getattr(picked, name), getattr(rays, name)[expected]), name


def test_bundles_concatenate_in_order():
    rays = _bundle(5)
    joined = RayBundle.cat([rays[:2], rays[2:]])
    for name in ("origins", "directions", "near", "far"):
        assert torch.equal(getattr(joined, name), getattr(rays, name))


def test_a_bundle_with_mismatched_shapes_names_them():
    with pytest.raises(ValueError, match=r"near and far \(R,\)"):
        RayBundle(torch.zeros(4, 3), torch.zeros(4, 3), torch.zeros(4), torch.zeros(3))


def test_padded_samples_lie_on_their_rays_at_their_midpoints():
    rays = _bundle(3)
    edges = torch.linspace(1.0, 3.0, 5).expand(3, 5)
    samples = RaySamples.from_bin_edges(edges)
    assert not samples.is_packed and samples.num_rays == 3 and len(samples) == 12
    torch.testing.assert_close(samples.t, torch.tensor([1.25, 1.75, 2.25, 2.75]).expand(3, 4))
    torch.testing.assert_close(samples.deltas, torch.full((3, 4), 0.5))
    expected = rays.origins[:, None] + samples.t[..., None] * rays.directions[:, None]
    torch.testing.assert_close(samples.positions(rays), expected)
    assert samples.view_directions(rays).shape == (3, 4, 3)


def test_packing_keeps_each_sample_with_its_ray_and_its_position():
    rays = _bundle(3)
    padded = RaySamples.from_points(torch.tensor([[1.0, 2.0], [1.5, 2.5], [0.5, 3.0]]), rays.far)
    packed = padded.packed()
    assert packed.is_packed and packed.num_rays == 3 and len(packed) == 6
    assert packed.ray_indices.tolist() == [0, 0, 1, 1, 2, 2]
    torch.testing.assert_close(packed.positions(rays), padded.positions(rays).reshape(-1, 3))
    torch.testing.assert_close(packed.deltas, padded.deltas.reshape(-1))
    torch.testing.assert_close(packed.view_directions(rays), rays.directions.repeat_interleave(2, dim=0))


def test_selecting_packed_samples_keeps_the_ray_count_and_evaluation_points():
    padded = RaySamples.from_points(torch.tensor([[1.0, 2.0], [1.5, 2.5]]), 4.0)
    kept = padded.packed().select(torch.tensor([True, False, False, True]))
    assert kept.num_rays == 2 and kept.ray_indices.tolist() == [0, 1]
    assert kept.t.tolist() == [1.0, 2.5] and kept.t_ends.tolist() == [2.0, 4.0]


def test_points_past_far_get_empty_intervals_not_negative_ones():
    samples = RaySamples.from_points(torch.tensor([[1.0, 5.0]]), 3.0)
    assert samples.deltas.tolist() == [[4.0, 0.0]]


def test_packed_samples_need_their_ray_count():
    with pytest.raises(ValueError, match="num_rays"):
        RaySamples(torch.zeros(3), torch.ones(3), ray_indices=torch.zeros(3, dtype=torch.long))
    with pytest.raises(ValueError, match="packed samples"):
        RaySamples.from_points(torch.zeros(2, 3), 1.0).select(torch.tensor([0]))
