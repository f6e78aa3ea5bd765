"""Building blocks shared by the PointNet family, channels-last.

Per-point tensors are ``(B, N, C)``: B clouds, N points, C channels, with an optional ``mask``
``(B, N)`` (True for real points) for batches padded to a common N. A "shared MLP" — the
paper's name for the same small network applied to every point, written as Conv1d with kernel
size 1 in most code — is here a plain ``nn.Linear`` applied to the ``(B·N, C)`` rows: the same
function, one large matrix product instead of B small ones.

:class:`MaxPooledLinear` is PointNet's signature step: the last shared layer (Linear, BatchNorm,
ReLU) and the symmetric max-pool over points, ``g = max_i ReLU(BN(W x_i))``. Done naively it
builds and keeps for backpropagation a ``(B·N, 1024)`` tensor per batch, the largest in the
network. It is computed here without keeping it, with exact gradients — see
:class:`_BatchNormMaxPool` — and :meth:`MaxPooledLinear.reference` computes the same thing the
plain way, for the tests.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch
import torch.nn.functional as F
from torch import nn

# Points per chunk when the inference path computes W x for very large clouds.
INFERENCE_CHUNK = 16384


def apply_to_rows(
    function: Callable[[torch.Tensor], torch.Tensor],
    x: torch.Tensor,
    mask: torch.Tensor | None = None,
) -> torch.Tensor:
    """Apply a function of ``(rows, C)`` to every point of ``x`` ``(..., C)``: real points only.

    Without a mask all ``prod(x.shape[:-1])`` rows go through at once. With one, only real
    points do (padding is neither computed nor seen by BatchNorm's statistics) and padding
    rows of the result are 0.
    """
    if mask is None:
        return function(x.reshape(-1, x.shape[-1])).reshape(*x.shape[:-1], -1)
    rows = function(x[mask])
    out = rows.new_zeros(*x.shape[:-1], rows.shape[-1])
    out[mask] = rows
    return out


def norm_relu_layers(widths: Sequence[int], dropout: float = 0.0) -> list[nn.Module]:
    """Linear -> BatchNorm -> ReLU (-> Dropout) for each consecutive pair of ``widths``.

    The Linear layers have no bias: BatchNorm subtracts the mean right after, which cancels it.
    """
    layers: list[nn.Module] = []
    for width_in, width_out in zip(widths[:-1], widths[1:]):
        layers += [nn.Linear(width_in, width_out, bias=False), nn.BatchNorm1d(width_out), nn.ReLU()]
        if dropout:
            layers.append(nn.Dropout(dropout))
    return layers


class SharedMLP(nn.Module):
    """The same MLP applied to every point: ``(B, N, widths[0]) -> (B, N, widths[-1])``."""

    def __init__(self, widths: Sequence[int]):
        super().__init__()
        self.widths = tuple(widths)
        self.layers = nn.Sequential(*norm_relu_layers(widths))

    def forward(self, x: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        if len(self.widths) == 1:
            return x
        return apply_to_rows(self.layers, x, mask)


class MLP(nn.Module):
    """Fully connected layers on ``(B, widths[0])`` ending in a plain Linear to ``out_channels``.

    Hidden layers are Linear, BatchNorm, ReLU, then Dropout(``dropout``) when it is non-zero.
    """

    def __init__(self, widths: Sequence[int], out_channels: int, dropout: float = 0.0):
        super().__init__()
        self.hidden = nn.Sequential(*norm_relu_layers(widths, dropout))
        self.out = nn.Linear(widths[-1], out_channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.out(self.hidden(x))


class MaxPooledLinear(nn.Module):
    """``g_b = max_{i in cloud b} ReLU(BN(W x_i))``: the last shared layer and the max-pool.

    ``x`` ``(B, N, in_channels)`` -> ``(B, out_channels)``. The max is over real points only.
    The result does not depend on the order of the points — PointNet's symmetric function.

    ``fast`` (default True) computes it with :class:`_BatchNormMaxPool` in training and with
    the BatchNorm folded into the max in evaluation; ``fast=False`` runs :meth:`reference`.
    Both give the same values and gradients, and share parameters (``linear.weight`` and the
    BatchNorm's), so checkpoints are interchangeable.
    """

    def __init__(self, in_channels: int, out_channels: int, fast: bool = True):
        super().__init__()
        self.linear = nn.Linear(in_channels, out_channels, bias=False)
        self.norm = nn.BatchNorm1d(out_channels)
        self.fast = fast

    def forward(self, x: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        if not self.fast:
            return self.reference(x, mask)
        norm = self.norm
        if self.training:
            if norm.momentum is None:
                raise ValueError("MaxPooledLinear needs a BatchNorm with a float momentum")
            norm.num_batches_tracked += 1
            pooled = _BatchNormMaxPool.apply(
                x, self.linear.weight, norm.weight, norm.bias, mask,
                norm.running_mean, norm.running_var, norm.momentum, norm.eps,
            )
            return F.relu(pooled)
        return F.relu(self._evaluate(x, mask))

    def _evaluate(self, x: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
        """BN with running statistics is ``a z + c`` per channel, so ``max_i BN(z_i)`` is
        ``a max_i z_i + c`` where ``a >= 0`` and ``a min_i z_i + c`` where ``a < 0``; flipping
        the sign of W's rows for negative ``a`` turns both into one max. Only ``(B, C)``
        values are normalised, and W x is computed in chunks of points to bound memory."""
        norm = self.norm
        scale = norm.weight * torch.rsqrt(norm.running_var + norm.eps)
        sign = torch.where(scale >= 0, 1.0, -1.0).to(x.dtype)
        signed_weight = self.linear.weight * sign[:, None]
        best = None
        for lo in range(0, x.shape[1], INFERENCE_CHUNK):
            z = x[:, lo : lo + INFERENCE_CHUNK] @ signed_weight.T
            if mask is not None:
                z = z.masked_fill(~mask[:, lo : lo + INFERENCE_CHUNK, None], float("-inf"))
            chunk_max = z.amax(dim=1)
            best = chunk_max if best is None else torch.maximum(best, chunk_max)
        return scale * (best * sign - norm.running_mean) + norm.bias

    def reference(self, x: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        """The plain computation: Linear, BatchNorm, ReLU on every real point, then max."""
        rows = apply_to_rows(lambda r: F.relu(self.norm(self.linear(r))), x, mask)
        if mask is not None:
            rows = rows.masked_fill(~mask[..., None], float("-inf"))
        return rows.amax(dim=1)


def sparse_products_supported(device: torch.device) -> bool:
    """Whether ``torch.sparse.mm`` runs on ``device`` (CPU and CUDA; not MPS, say)."""
    return device.type in ("cpu", "cuda")


class _BatchNormMaxPool(torch.autograd.Function):
    """``m_bc = max_i BN(z_i)_c`` with ``z_i = W x_i``, BatchNorm in training mode (batch
    statistics over all M real points of the batch), without materialising BN(z) for backward.

    Forward. With ``x̄`` the mean of the inputs and ``Σ = 1/M Σ_i (x_i - x̄)(x_i - x̄)^T`` their
    covariance (``C_in × C_in``, cheap), the batch statistics of z are exactly
    ``μ = W x̄`` and ``σ²_c = w_c^T Σ w_c``. BN is then a per-channel affine map with slope
    ``a_c = γ_c / sqrt(σ²_c + ε)``, so its max over points is taken at
    ``i*(b, c) = argmax_i s_c w_c·(x_i - x̄)`` with ``s_c = sign(γ_c)``, and
    ``m_bc = a_c w_c·(x_{i*} - x̄) + β_c``. Only that max and its argmax are kept.

    Backward, for ``G = dL/dm`` ``(B, C)`` (derivation in docs/models.md):

    - ``dβ_c = Σ_b G_bc`` and ``dγ_c = Σ_b G_bc d_bc / sqrt(σ²_c + ε)`` with
      ``d_bc = w_c·(x_{i*} - x̄)``;
    - ``dL/dz_i = S_i + u ⊙ W(x_i - x̄) + g_μ / M``, where S_i is ``G_bc a_c`` at the argmax
      points (zero elsewhere), ``g_μ = -Σ_b G_bc a_c`` and
      ``u_c = -γ_c (σ²_c + ε)^{-3/2} Σ_b G_bc d_bc / M``;
    - hence ``dW = S^T X + M u ⊙ (W Σ) + g_μ x̄^T`` and
      ``dx_i = W^T S_i + (W^T diag(u) W)(x_i - x̄) + W^T g_μ / M``:
      S has one entry per (cloud, channel), so ``S^T X`` and ``S W`` are sparse products of
      ``B·C·C_in`` work, and the rest are ``C_in × C_in`` products — no ``(M, C)`` tensor.

    Running statistics are updated as ``torch.nn.BatchNorm1d`` does (unbiased variance).
    """

    @staticmethod
    def forward(ctx, x, weight, gamma, beta, mask, running_mean, running_var, momentum, eps):
        rows = x.reshape(-1, x.shape[-1]) if mask is None else x[mask]
        count = rows.shape[0]
        mean = rows.mean(dim=0)
        centred_rows = rows - mean
        covariance = centred_rows.T @ centred_rows / count
        variance = ((weight @ covariance) * weight).sum(dim=1)
        inv_std = torch.rsqrt(variance + eps)
        sign = torch.where(gamma >= 0, 1.0, -1.0).to(x.dtype)
        centred = x - mean
        signed = centred @ (weight * sign[:, None]).T  # (B, N, C), freed on return
        if mask is not None:
            signed = signed.masked_fill(~mask[..., None], float("-inf"))
        peak, argmax = signed.max(dim=1)  # (B, C)
        deviation = peak * sign  # d_bc = w_c·(x_i* - x̄)
        with torch.no_grad():
            running_mean.mul_(1 - momentum).add_(momentum * (weight @ mean))
            unbiased = variance * count / max(count - 1, 1)
            running_var.mul_(1 - momentum).add_(momentum * unbiased)
        ctx.save_for_backward(x, weight, gamma, mask, mean, covariance, inv_std, deviation, argmax)
        ctx.count = count
        return gamma * inv_std * deviation + beta

    @staticmethod
    def backward(ctx, grad):
        x, weight, gamma, mask, mean, covariance, inv_std, deviation, argmax = ctx.saved_tensors
        count = ctx.count
        batch, _, channels_in = x.shape
        slope = gamma * inv_std
        grad_at_max = grad * slope  # (B, C): dL/dz at each argmax point
        grad_mean = -grad_at_max.sum(dim=0)
        grad_dev = (grad * deviation).sum(dim=0)
        grad_gamma = grad_dev * inv_std
        grad_beta = grad.sum(dim=0)
        u = -gamma * inv_std**3 * grad_dev / count
        grad_weight = count * u[:, None] * (weight @ covariance) + grad_mean[:, None] * mean[None, :]
        grad_x = None
        if ctx.needs_input_grad[0]:
            quadratic = weight.T @ (u[:, None] * weight)  # W^T diag(u) W, (C_in, C_in)
            grad_x = (x - mean) @ quadratic + (weight.T @ grad_mean) / count
            if mask is not None:
                grad_x = grad_x * mask[..., None]
        points, channels = x.shape[1], weight.shape[0]
        if sparse_products_supported(x.device):
            # S as a sparse (B·N, C) matrix with one entry per (cloud, channel): two sparse
            # products of B·C·C_in work, where the dense ones would cost B·N·C·C_in.
            rows = torch.arange(batch, device=x.device)[:, None] * points + argmax
            columns = torch.arange(channels, device=x.device).expand(batch, -1)
            sparse = torch.sparse_coo_tensor(
                torch.stack([rows.reshape(-1), columns.reshape(-1)]), grad_at_max.reshape(-1),
                (batch * points, channels), check_invariants=False,
            )
            grad_weight = grad_weight + torch.sparse.mm(sparse.t(), x.reshape(-1, channels_in))
            if grad_x is not None:
                grad_x = grad_x + torch.sparse.mm(sparse, weight).view_as(x)
        else:  # backends without sparse products: gather the argmax rows instead
            index = argmax.unsqueeze(-1).expand(batch, -1, channels_in)
            picked = torch.gather(x, 1, index)
            grad_weight = grad_weight + torch.einsum("bc,bci->ci", grad_at_max, picked)
            if grad_x is not None:
                grad_x = grad_x.scatter_add(
                    1, index, grad_at_max.unsqueeze(-1) * weight.unsqueeze(0)
                )
        return grad_x, grad_weight, grad_gamma, grad_beta, None, None, None, None, None
