"""CUDA's TF32 convolutions emulated on any machine, shared by tests/test_metrics.py and
benchmarks/bench_splat_resolution.py.

On CUDA, cuDNN runs float32 convolutions in TF32 by default (``torch.backends.cudnn.allow_tf32``):
inputs rounded to a 10-bit mantissa, products summed in float32. :func:`tf32_convolutions` makes
``torch.nn.functional.conv2d`` do the same to float32 inputs (forward and backward) while it is
active, so that a CPU can show what a GPU would compute; other dtypes convolve as usual.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import torch
import torch.nn.functional as F


def tf32(values: torch.Tensor) -> torch.Tensor:
    """float32 rounded to TF32's 10-bit mantissa (to nearest), as tensor cores read it."""
    bits = values.contiguous().view(torch.int32)
    return ((bits + 0x1000) & ~0x1FFF).view(torch.float32)


class TF32Convolution(torch.autograd.Function):
    """A float32 convolution as cuDNN runs one on CUDA by default: TF32 inputs, float32 sums,
    forward and backward (the gradient with respect to the image; the window is a constant)."""

    @staticmethod
    def forward(ctx, image, weight, convolve):
        ctx.save_for_backward(image, weight)
        return convolve(tf32(image), tf32(weight))

    @staticmethod
    def backward(ctx, grad):
        image, weight = ctx.saved_tensors
        return torch.nn.grad.conv2d_input(image.shape, tf32(weight), tf32(grad)), None, None


@contextmanager
def tf32_convolutions() -> Iterator[None]:
    """While active, ``F.conv2d(image, weight)`` of float32 inputs runs as :class:`TF32Convolution`."""
    convolve = F.conv2d

    def emulated(image, weight):
        return TF32Convolution.apply(image, weight, convolve) if image.dtype == torch.float32 else convolve(image, weight)

    F.conv2d = emulated
    try:
        yield
    finally:
        F.conv2d = convolve
