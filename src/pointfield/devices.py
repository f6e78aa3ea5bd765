"""The one place that decides where tensors live: CPU, a CUDA GPU, or Apple's MPS.

Every command's ``--device`` goes through :func:`pick_device`, so "auto" means the same thing
everywhere: the first CUDA GPU when there is one, else MPS, else the CPU.
"""

from __future__ import annotations

import torch

from pointfield.errors import PointfieldError

DEVICE_NAMES = ("auto", "cpu", "cuda", "cuda:N", "mps")


def pick_device(name: str | torch.device | None = None) -> torch.device:
    """The ``torch.device`` that ``name`` asks for, checked to exist on this machine.

    ``None`` or ``"auto"``: ``cuda`` if a CUDA GPU is usable, else ``mps`` if Apple's Metal
    backend is, else ``cpu``. ``"cpu"``, ``"cuda"`` (GPU 0), ``"cuda:1"`` and ``"mps"`` are
    taken literally; asking for a device this machine does not have raises
    :class:`PointfieldError` naming what is available instead of failing later inside torch.

    Example::

        >>> pick_device("cpu")
        device(type='cpu')
    """
    if isinstance(name, torch.device):
        name = str(name)
    spelled = (name or "auto").strip().lower()
    if spelled == "auto":
        if torch.cuda.is_available():
            return torch.device("cuda", 0)
        if _mps_available():
            return torch.device("mps")
        return torch.device("cpu")
    try:
        device = torch.device(spelled)
    except (RuntimeError, ValueError):
        raise PointfieldError(
            f"unknown device {name!r}: expected one of {', '.join(DEVICE_NAMES)}"
        ) from None
    if device.type == "cpu":
        return torch.device("cpu")
    if device.type == "cuda":
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        index = 0 if device.index is None else device.index
        if index >= count:
            raise PointfieldError(
                f"device {name!r} is not available: this machine has "
                f"{'no CUDA GPU' if count == 0 else f'{count} CUDA GPU(s), cuda:0..cuda:{count - 1}'}"
                f" ({available_devices_text()})"
            )
        return torch.device("cuda", index)
    if device.type == "mps":
        if not _mps_available():
            raise PointfieldError(
                f"device {name!r} is not available: no Apple MPS backend here "
                f"({available_devices_text()})"
            )
        return torch.device("mps")
    raise PointfieldError(f"unsupported device {name!r}: expected one of {', '.join(DEVICE_NAMES)}")


def available_devices_text() -> str:
    """A short phrase listing the devices this machine has, for error messages and ``--help``."""
    names = ["cpu"]
    if torch.cuda.is_available():
        names += [f"cuda:{i}" for i in range(torch.cuda.device_count())]
    if _mps_available():
        names.append("mps")
    return "available: " + ", ".join(names)


def _mps_available() -> bool:
    backend = getattr(torch.backends, "mps", None)
    return bool(backend is not None and backend.is_available())
