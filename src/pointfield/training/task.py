"""A task: one kind of training (classify, segment, nerf, splat) as the lifecycle sees it.

:func:`pointfield.training.lifecycle.train` does what every task shares -- a new run or a resumed
one, the settings a resumed run may change, the run folder, the loop (:func:`~pointfield.training.fit`),
the final metrics -- and a :class:`Task` says only what is its own:

=================================  ==============================================================
settings -> a checked config       :meth:`Task.configure` (a classmethod: nothing is built yet)
config -> data, model, optimizer   ``Task(config, device, distributed, progress)``
kernels built before the clock     :meth:`Task.warm_up`
an epoch's batches                 :meth:`Task.batches`
the loss of a batch                :meth:`Task.step` -> :class:`Step`
held-out scores after an epoch     :meth:`Task.evaluate`
pictures of the history            :meth:`Task.draw`
the final metrics                  :meth:`Task.finish`
what finishing will cost           :meth:`Task.finishing_seconds` (kept for it from ``max_time``)
=================================  ==============================================================

The lifecycle sets ``time_budget`` (:class:`~pointfield.training.budget.TimeBudget`, the call's
``max_time``) and ``training_budget`` (``max_training_time``, seconds or None) before
:meth:`Task.warm_up`; a task's :meth:`Task.finish` fits its final evaluation into the first, and
a schedule may be sized to both (:class:`~pointfield.training.schedules.BudgetCosine`).

A step returns its loss and, separately and by name, any auxiliary losses (PointNet's
orthogonality regulariser, the proposal networks' interlevel loss): the loop adds them to the
loss and logs each one, so nothing is found on the model by ``hasattr`` or left on it by ``forward``.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any, ClassVar

import torch
from torch import nn

from pointfield.training.budget import TimeBudget
from pointfield.training.distributed import Distributed
from pointfield.training.loop import TrainingState
from pointfield.training.run import RunDirectory


@dataclass
class Step:
    """What one training step gives the loop.

    ``loss``: the task's own loss, a scalar with gradients; ``auxiliary``: further named loss
    terms, added to it (each is logged as ``train_<name>``); ``stats``: numbers worth logging
    (``{"accuracy": 0.9}``, ``{"psnr": 21.3}``).
    """

    loss: torch.Tensor
    stats: dict[str, float] = field(default_factory=dict)
    auxiliary: dict[str, torch.Tensor] = field(default_factory=dict)

    def total(self) -> tuple[torch.Tensor, dict[str, float]]:
        """The loss the optimizer minimises and every number to log, as :func:`fit` takes them."""
        total = self.loss
        stats = dict(self.stats)
        for name, term in self.auxiliary.items():
            total = total + term
            stats[name] = float(term.detach())
        return total, stats


class Task:
    """Base of every training recipe; subclasses set the class attributes and the methods below.

    After ``__init__`` a task holds ``config`` (what ``config.json`` records, with anything
    learned from the data added), ``model`` (what checkpoints hold), ``trained`` (the module
    the loop steps: ``model`` or its DDP wrapper), ``optimizer``, ``scheduler`` (or None),
    ``epochs`` (the loop's epochs: passes over the data, or rounds of steps between
    evaluations) and ``identity`` (what a checkpoint must match to be resumed or loaded).
    """

    name: ClassVar[str]
    """``config["task"]``: the word runs are known by."""
    extendable: ClassVar[tuple[str, ...]] = ()
    """Settings a resumed run takes from the caller (a longer run); every other one is the run's own."""
    loss_aliases: ClassVar[tuple[str, ...]] = ()
    """More record keys for the epoch's mean training loss (see :func:`fit`)."""

    config: dict[str, Any]
    model: nn.Module
    trained: nn.Module
    optimizer: torch.optim.Optimizer
    scheduler: Any = None
    epochs: int
    identity: dict[str, Any]
    time_budget: TimeBudget = TimeBudget()
    training_budget: float | None = None

    def __init__(
        self, config: dict[str, Any], device: torch.device, distributed: Distributed | None, progress: bool
    ):
        self.config = config
        self.device = device
        self.distributed = distributed
        self.progress = progress

    @classmethod
    def configure(cls, settings: dict[str, Any]) -> dict[str, Any]:
        """A new run's config from the caller's settings: defaults filled in, values checked."""
        raise NotImplementedError

    def warm_up(self) -> None:
        """One-time work kept off the training clock (compiling kernels); nothing by default."""

    def batches(self, epoch: int) -> Iterable[Any]:
        """Epoch ``epoch``'s batches, the same every time they are asked for (seeded by the epoch)."""
        raise NotImplementedError

    def step(self, batch: Any) -> Step:
        """The loss of one batch."""
        raise NotImplementedError

    def evaluate(self, epoch: int) -> dict[str, float]:
        """Held-out scores after epoch ``epoch`` (collective in a distributed run); none by default."""
        return {}

    def draw(self, run: RunDirectory, history: list[dict[str, Any]]) -> None:
        """Redraw the run's pictures from its history (rank 0 only); nothing by default."""

    def finish(self, run: RunDirectory, state: TrainingState) -> dict[str, Any]:
        """The task's final metrics and any final pictures; the lifecycle adds the clock's figures."""
        raise NotImplementedError

    def finishing_seconds(self) -> float | None:
        """Estimated seconds of :meth:`finish` at its full size (None: not known yet; 0 by default)."""
        return 0.0
