"""Device choice: auto, explicit devices, and clear errors for absent ones."""

from __future__ import annotations

import pytest
import torch

from pointfield.devices import pick_device
from pointfield.errors import PointfieldError


def test_cpu_is_always_there():
    assert pick_device("cpu") == torch.device("cpu")
    assert pick_device(torch.device("cpu")) == torch.device("cpu")


def test_auto_picks_cuda_when_present_else_cpu_or_mps():
    chosen = pick_device(None)
    assert pick_device("auto") == chosen
    if torch.cuda.is_available():
        assert chosen == torch.device("cuda", 0)
    else:
        assert chosen.type in ("cpu", "mps")


def test_an_absent_gpu_is_a_clear_error():
    count = torch.cuda.device_count() if torch.cuda.is_available() else 0
    with pytest.raises(PointfieldError, match=f"cuda:{count}.*not available.*cpu"):
        pick_device(f"cuda:{count}")


def test_an_unknown_name_lists_the_choices():
    with pytest.raises(PointfieldError, match="auto, cpu, cuda"):
        pick_device("tpu-ish")
