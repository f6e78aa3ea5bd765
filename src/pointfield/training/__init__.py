"""The one training loop models plug into, with its run folder, checkpoints and DDP helpers.

- :func:`fit` (``loop.py``): epochs of ``step(batch) -> (loss, stats)`` with evaluation,
  logging, progress, atomic checkpoints, resuming, a time limit and NaN checks.
- :class:`RunDirectory` (``run.py``): ``config.json``, ``metrics.jsonl``, ``metrics.json``,
  ``checkpoints/last.pt``.
- :func:`save_checkpoint`, :func:`load_checkpoint`, :func:`restore` (``checkpoints.py``).
- :func:`setup`, :func:`wrap`, :func:`shard`, :func:`shutdown` (``distributed.py``): torchrun.
"""

from pointfield.training.checkpoints import load_checkpoint, restore, save_checkpoint, unwrap
from pointfield.training.distributed import Distributed, setup, shard, shutdown, wrap
from pointfield.training.loop import TrainingState, fit
from pointfield.training.run import RunDirectory

__all__ = [
    "Distributed",
    "RunDirectory",
    "TrainingState",
    "fit",
    "load_checkpoint",
    "restore",
    "save_checkpoint",
    "setup",
    "shard",
    "shutdown",
    "unwrap",
    "wrap",
]
