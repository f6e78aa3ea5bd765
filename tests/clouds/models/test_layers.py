"""The fused BatchNorm + max-pool layer against its plain reference."""

from __future__ import annotations

import copy

import pytest
import torch

from pointfield.clouds.models import layers
from pointfield.clouds.models.layers import MaxPooledLinear, SharedMLP


def pair(channels_in: int, channels_out: int) -> tuple[MaxPooledLinear, MaxPooledLinear]:
    fast = MaxPooledLinear(channels_in, channels_out).double()
    with torch.no_grad():  # mixed-sign scales exercise the min-instead-of-max channels
        fast.norm.weight.copy_(torch.randn(channels_out, dtype=torch.float64))
        fast.norm.bias.copy_(torch.randn(channels_out, dtype=torch.float64))
    slow = copy.deepcopy(fast)
    slow.fast = False
    return fast, slow


def padding_mask(batch: int, points: int) -> torch.Tensor:
    mask = torch.ones(batch, points, dtype=torch.bool)
    mask[1, points // 2 :] = False
    return mask


@pytest.mark.parametrize("sparse", [True, False])
@pytest.mark.parametrize("points", [9, 140])
@pytest.mark.parametrize("masked", [False, True])
def test_training_values_gradients_and_running_statistics_match_the_reference(
    points, masked, sparse, monkeypatch
):
    monkeypatch.setattr(layers, "sparse_products_supported", lambda device: sparse)
    torch.manual_seed(0)
    fast, slow = pair(5, 7)
    x = torch.randn(3, points, 5, dtype=torch.float64, requires_grad=True)
    mask = padding_mask(3, points) if masked else None
    out_fast, out_slow = fast(x, mask), slow(x, mask)
    torch.testing.assert_close(out_fast, out_slow)
    upstream = torch.randn_like(out_fast)
    grads_fast = torch.autograd.grad(out_fast, [x, *fast.parameters()], upstream)
    grads_slow = torch.autograd.grad(out_slow, [x, *slow.parameters()], upstream)
    for a, b in zip(grads_fast, grads_slow):
        torch.testing.assert_close(a, b)
    torch.testing.assert_close(fast.norm.running_mean, slow.norm.running_mean)
    torch.testing.assert_close(fast.norm.running_var, slow.norm.running_var)
    assert fast.norm.num_batches_tracked == slow.norm.num_batches_tracked == 1


def test_gradcheck_of_the_fused_function():
    torch.manual_seed(1)
    fast, _ = pair(3, 4)
    x = torch.randn(2, 6, 3, dtype=torch.float64, requires_grad=True)
    weight = fast.linear.weight.detach().clone().requires_grad_()
    gamma = fast.norm.weight.detach().clone().requires_grad_()
    beta = fast.norm.bias.detach().clone().requires_grad_()

    def function(x, weight, gamma, beta):
        return layers._BatchNormMaxPool.apply(
            x, weight, gamma, beta, None, torch.zeros(4, dtype=torch.float64),
            torch.ones(4, dtype=torch.float64), 0.1, 1e-5,
        )

    assert torch.autograd.gradcheck(function, (x, weight, gamma, beta))


def test_evaluation_folds_batchnorm_into_the_max_exactly():
    torch.manual_seed(2)
    fast, slow = pair(4, 6)
    x = torch.randn(4, 30, 4, dtype=torch.float64)
    fast(x), slow(x)  # move the running statistics away from their initial values
    fast.eval(), slow.eval()
    mask = padding_mask(4, 30)
    torch.testing.assert_close(fast(x, mask), slow(x, mask))


def test_the_result_ignores_point_order():
    torch.manual_seed(3)
    fast, _ = pair(4, 6)
    fast.eval()
    x = torch.randn(2, 50, 4, dtype=torch.float64)
    torch.testing.assert_close(fast(x), fast(x[:, torch.randperm(50)]))


def test_shared_mlp_leaves_padding_at_zero_and_out_of_the_statistics():
    torch.manual_seed(4)
    mlp = SharedMLP([3, 8, 8])
    x = torch.randn(2, 10, 3)
    mask = padding_mask(2, 10)
    padded = x.clone()
    padded[~mask] = 1e6  # garbage in padding must not reach the real rows
    out = mlp(padded, mask)
    assert (out[~mask] == 0).all()
    reference = SharedMLP([3, 8, 8])
    reference.load_state_dict(mlp.state_dict())
    torch.testing.assert_close(out[mask], reference.layers(x[mask]))
