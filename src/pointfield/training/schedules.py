"""A learning-rate schedule sized to whatever ends the run: its epochs, its training time or its wall clock.

A cosine over ``epochs`` (what a run of fixed length uses) never decays in a run stopped by the
clock after a few of its epochs: the model then ends at the full learning rate, which costs a
segmenter several points of mIoU against the same steps annealed. :class:`BudgetCosine` follows
the share of the run's budget already spent instead,

    p = max(steps / total_steps, trained_seconds / max_training_time, elapsed / max_time)

(each term where that limit is set), and sets, before every step,

    lr(p) = base · (start + (1 - start) · p / warmup)                                  p < warmup
    lr(p) = base · (final + (1 - final) · (1 + cos(π (p - warmup) / (1 - warmup))) / 2)   p >= warmup

a linear warm-up then a cosine to ``final`` of the base rate: the shape of Pointcept's OneCycle
(warm-up 5 %) and of timm's cosine-with-warm-up, reached at whichever limit comes first.
``trained_seconds`` is the time between one step and the next (data, forward, backward,
optimizer), summed over resumed sessions and kept in the checkpoint; an evaluation between
:meth:`BudgetCosine.pause` and :meth:`BudgetCosine.resume` is left out. ``elapsed`` is the wall clock of the
current call (:class:`~pointfield.training.budget.TimeBudget`), evaluations included, as
``max_time`` counts it: a run resumed with a new ``max_time`` anneals again over that call.
"""

from __future__ import annotations

import math
import time
from typing import Any

import torch

from pointfield.training.budget import TimeBudget

WARMUP = 0.05
START = 0.1


class BudgetCosine:
    """Warm-up then cosine over the spent share of a run's budget (module doc); the base rates are
    the optimizer's at construction.

    Call :meth:`advance` at the start of every step (it sets the rate for that step's update),
    :meth:`pause` where the training clock stops (an evaluation between epochs) and :meth:`resume`
    where it starts again (an epoch's first batch). :meth:`step` is what the training loop calls
    after each epoch: nothing, the rate moves by steps.
    """

    def __init__(
        self,
        optimizer: torch.optim.Optimizer,
        *,
        total_steps: int | None = None,
        training_seconds: float | None = None,
        wall: TimeBudget | None = None,
        warmup: float = WARMUP,
        start: float = START,
        final: float = 0.01,
    ):
        if not 0 <= warmup < 1:
            raise ValueError(f"warm-up is a share of the budget in [0, 1), got {warmup}")
        self.optimizer = optimizer
        self.base = [group["lr"] for group in optimizer.param_groups]
        self.total_steps, self.training_seconds, self.wall = total_steps, training_seconds, wall
        self.warmup, self.start, self.final = warmup, start, final
        self.steps, self.seconds = 0, 0.0
        self._tick: float | None = None
        self._set(self.factor(0.0))

    def progress(self) -> float:
        """The share of the budget spent, p in [0, 1]."""
        shares = [0.0]
        if self.total_steps:
            shares.append(self.steps / self.total_steps)
        if self.training_seconds:
            shares.append(self.seconds / self.training_seconds)
        if self.wall is not None and self.wall.limited:
            shares.append(self.wall.elapsed() / self.wall.seconds)
        return min(max(shares), 1.0)

    def factor(self, p: float) -> float:
        """The learning rate at ``p`` as a multiple of the base rate."""
        if p < self.warmup:
            return self.start + (1.0 - self.start) * p / self.warmup
        q = (p - self.warmup) / (1.0 - self.warmup)
        return self.final + (1.0 - self.final) * 0.5 * (1.0 + math.cos(math.pi * min(q, 1.0)))

    def advance(self) -> float:
        """Count the time since the previous step and set this step's rate; returns it."""
        self._count()
        self._tick = time.perf_counter()
        rate = self._set(self.factor(self.progress()))
        self.steps += 1
        return rate

    def pause(self) -> None:
        """Count the time since the previous step (its backward pass) and stop the clock."""
        self._count()
        self._tick = None

    def resume(self) -> None:
        """Start the clock again if it was stopped."""
        if self._tick is None:
            self._tick = time.perf_counter()

    def _count(self) -> None:
        if self._tick is not None:
            self.seconds += time.perf_counter() - self._tick

    def step(self) -> None:
        """Per epoch, as :func:`~pointfield.training.fit` calls it: the rate moves per step instead."""

    def get_last_lr(self) -> list[float]:
        return [group["lr"] for group in self.optimizer.param_groups]

    def state_dict(self) -> dict[str, Any]:
        return {"steps": self.steps, "seconds": self.seconds}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        # A checkpoint of another schedule (an epoch cosine's) has neither: its run starts this one afresh.
        self.steps, self.seconds = int(state.get("steps", 0)), float(state.get("seconds", 0.0))
        self._tick = None
        self._set(self.factor(self.progress()))

    def _set(self, factor: float) -> float:
        for group, base in zip(self.optimizer.param_groups, self.base):
            group["lr"] = base * factor
        return self.optimizer.param_groups[0]["lr"]
