"""Checkpoints: written atomically, read with ``weights_only=True``, checked before use.

A checkpoint is one ``torch.save`` file holding only tensors and plain Python values::

    {"format": "pointfield-checkpoint", "version": 1, "pointfield": "0.1.0",
     "identity": {"task": "classify", "model": "pointnet", ...},   # what it is a checkpoint of
     "model": state_dict, "optimizer": state_dict | None, "scheduler": state_dict | None,
     "state": {"epoch": 3, "step": 93, "batch": 0, "seconds": 41.2, "history": [...]},
     "rng": {"torch": ByteTensor, "cuda": [ByteTensor, ...]}}

so it loads with ``torch.load(..., weights_only=True)``, which cannot run code from the file.
Loading compares ``identity`` with what the caller expects and raises :class:`PointfieldError`
naming the difference, so a checkpoint of another model, task or format version is refused
with a clear message rather than a wall of missing-key errors.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import torch
from torch import nn

from pointfield.atomic import atomic_path
from pointfield.errors import PointfieldError
from pointfield.version import __version__

CHECKPOINT_FORMAT = "pointfield-checkpoint"
CHECKPOINT_VERSION = 1


def unwrap(model: nn.Module) -> nn.Module:
    """The model inside a DistributedDataParallel wrapper (or the model itself)."""
    return model.module if isinstance(model, nn.parallel.DistributedDataParallel) else model


def save_checkpoint(
    path: str | os.PathLike[str],
    *,
    identity: dict[str, Any],
    model: nn.Module,
    optimizer: torch.optim.Optimizer | None = None,
    scheduler: Any = None,
    state: dict[str, Any] | None = None,
) -> None:
    """Write a checkpoint atomically: a crash mid-write leaves the previous one intact."""
    payload = {
        "format": CHECKPOINT_FORMAT,
        "version": CHECKPOINT_VERSION,
        "pointfield": __version__,
        "identity": identity,
        "model": unwrap(model).state_dict(),
        "optimizer": optimizer.state_dict() if optimizer is not None else None,
        "scheduler": scheduler.state_dict() if scheduler is not None else None,
        "state": state or {},
        "rng": {
            "torch": torch.get_rng_state(),
            "cuda": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else [],
        },
    }
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)


def load_checkpoint(
    path: str | os.PathLike[str],
    identity: dict[str, Any] | None = None,
    map_location: str | torch.device = "cpu",
) -> dict[str, Any]:
    """Read a checkpoint safely and check it; returns the payload described above.

    Every entry of ``identity`` must equal the checkpoint's, else :class:`PointfieldError`
    says which differs ("checkpoint is of model 'pointnet2', expected 'pointnet'").
    """
    path = Path(path)
    if not path.is_file():
        raise PointfieldError(f"{path}: no such checkpoint")
    try:
        payload = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as error:  # noqa: BLE001 - re-raised as PointfieldError; torch raises many types here (unpickling, zip, EOF, runtime)
        raise PointfieldError(
            f"{path}: not a readable pointfield checkpoint ({type(error).__name__}: "
            f"{str(error).splitlines()[0] if str(error) else 'no detail'})"
        ) from None
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        raise PointfieldError(f"{path}: not a pointfield checkpoint")
    if payload.get("version") != CHECKPOINT_VERSION:
        raise PointfieldError(
            f"{path}: checkpoint format version {payload.get('version')!r} (written by "
            f"pointfield {payload.get('pointfield')}); this pointfield reads version "
            f"{CHECKPOINT_VERSION}"
        )
    found = payload.get("identity") or {}
    for key, expected in (identity or {}).items():
        if found.get(key) != expected:
            raise PointfieldError(
                f"{path}: checkpoint is of {key} {found.get(key)!r}, expected {expected!r}"
            )
    return payload


def restore(
    path: str | os.PathLike[str],
    payload: dict[str, Any],
    model: nn.Module,
    optimizer: torch.optim.Optimizer | None = None,
    scheduler: Any = None,
    *,
    rng: bool = False,
) -> None:
    """Load a checkpoint's states into a model (and optimizer, scheduler, random generators).

    A state that does not fit (other layer names or shapes) raises :class:`PointfieldError`.
    """
    try:
        unwrap(model).load_state_dict(payload["model"])
        if optimizer is not None and payload.get("optimizer") is not None:
            optimizer.load_state_dict(payload["optimizer"])
        if scheduler is not None and payload.get("scheduler") is not None:
            scheduler.load_state_dict(payload["scheduler"])
    except (RuntimeError, KeyError, ValueError) as error:
        first_line = str(error).strip().splitlines()[0] if str(error).strip() else ""
        raise PointfieldError(
            f"{path}: checkpoint does not fit this model: {first_line}"
        ) from None
    if rng:
        # Generator states are CPU byte tensors whatever device they describe; a payload read
        # with map_location="cuda" has them on the GPU, which set_rng_state refuses.
        torch.set_rng_state(payload["rng"]["torch"].cpu())
        cuda_states = [state.cpu() for state in payload["rng"].get("cuda") or []]
        if torch.cuda.is_available() and len(cuda_states) == torch.cuda.device_count():
            torch.cuda.set_rng_state_all(cuda_states)
