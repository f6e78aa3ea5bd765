"""The one training lifecycle every model plugs into: tasks, the loop, run folders, checkpoints, DDP.

- :class:`Task`, :class:`Step` (``task.py``): what a training recipe says of its own -- config,
  batches, the loss of a batch (auxiliary losses by name), evaluation, final metrics.
- :func:`train`, :func:`restore_model` (``lifecycle.py``): new / resumed run, run folder,
  final metrics, written once for every task; a run's model with its checkpoint loaded.
- :func:`fit` (``loop.py``): epochs of steps with evaluation, logging, progress, atomic
  checkpoints, resuming, a time limit and NaN checks.
- :class:`RunDirectory`, :class:`Run` (``run.py``): the folder's files (strict JSON); a run opened for use.
- :class:`TimeBudget` (``budget.py``): ``max_time``, the wall clock of a whole call, and what it keeps
  for the final evaluation; ``console.py``: lines above the bar, flushed, and status lines off a terminal.
- :func:`save_checkpoint`, :func:`load_checkpoint`, :func:`restore` (``checkpoints.py``).
- :func:`setup`, :func:`wrap`, :func:`shard`, :func:`shutdown` (``distributed.py``): torchrun.
"""

from pointfield.training.budget import TimeBudget
from pointfield.training.checkpoints import load_checkpoint, restore, save_checkpoint, unwrap
from pointfield.training.distributed import Distributed, setup, shard, shutdown, wrap
from pointfield.training.lifecycle import restore_model, train
from pointfield.training.loop import TrainingState, fit
from pointfield.training.run import Run, RunDirectory
from pointfield.training.task import Step, Task

__all__ = [
    "Distributed",
    "Run",
    "RunDirectory",
    "Step",
    "Task",
    "TimeBudget",
    "TrainingState",
    "fit",
    "load_checkpoint",
    "restore",
    "restore_model",
    "save_checkpoint",
    "setup",
    "shard",
    "shutdown",
    "train",
    "unwrap",
    "wrap",
]
