"""The one training loop that every pointfield model plugs into.

A model plugs in with two callables:

- ``batches(epoch) -> iterable of batches``: that epoch's data, the same every time it is
  asked for (seed the shuffling with the epoch), so a resumed run sees what it would have seen;
- ``step(batch) -> (loss, stats)``: the forward pass and the loss (a scalar tensor with
  gradients), plus any per-batch numbers worth logging (``{"accuracy": 0.9}``).

:func:`fit` does the rest: zero the gradients, backpropagate, step the optimizer; average the
loss and stats over the epoch (over all processes, in a distributed run); call ``evaluate``
after each epoch; log one record per epoch to ``metrics.jsonl``; checkpoint at the end of each
epoch and every ``checkpoint_seconds`` within one; resume from the last checkpoint; stop in
time (below); show a progress bar with the epoch's running means of the loss and of every
stat (``loss=0.0123, psnr=19.12``) on a terminal, and where the output goes to a file or a pipe
(a batch job, a CI log) a line at least every minute instead (:mod:`~pointfield.training.console`), as nerfstudio's
console writer does. A loss that is NaN or infinite stops training with an error naming the
epoch and step, never a silently ruined model.

An epoch's record holds ``epoch``, ``step``, ``seconds`` (wall clock, evaluation included),
``training_seconds`` (evaluation excluded: what time-to-PSNR figures read), ``lr``, the epoch's mean loss as
``train_loss`` (and under each of ``loss_aliases``), the mean of each stat as ``train_<stat>``,
and what ``evaluate`` returned.

Stopping in time: ``max_training_seconds`` stops once ``training_seconds`` (summed over resumed
sessions) reaches it; a ``budget`` (:class:`~pointfield.training.budget.TimeBudget`, the whole
command's wall clock) stops training once no more than :meth:`TimeBudget.reserve` of it is
left for what follows (the final evaluation, whose estimated cost ``finishing()`` gives), and
skips an epoch's evaluation that would eat into that reserve. A run stopped within an epoch
still ends with a record of it, marked ``"partial": true`` with ``epoch`` the fraction of
epochs done: it is written to ``metrics.jsonl`` and drawn by ``on_epoch_end``, but kept out of
the checkpoint's history, so a resumed run replaces it with the whole epoch's record.

Resuming restores the model, optimizer, scheduler, torch's random generator and the position
within the epoch, and rewrites ``metrics.jsonl`` from the history kept in the checkpoint, so
a run killed at any moment — even between two files being written — resumes and finishes
with one line per epoch.

Watching: inside ``with watched_by(watcher):`` every :func:`fit` (on rank 0) calls
``watcher.after_step(model, state, loss)`` after each optimizer step, in the training thread, so
the watcher sees the model between steps, never during one. It returns the seconds it held
training paused, which the clock leaves out; the time it spends otherwise (the browser viewer
rendering a frame, :mod:`pointfield.viewer.training`) counts as training time.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from typing import Any, Protocol

import torch
from torch import nn

from pointfield.errors import PointfieldError
from pointfield.training import console
from pointfield.training.budget import TimeBudget
from pointfield.training.checkpoints import load_checkpoint, restore, save_checkpoint
from pointfield.training.distributed import Distributed
from pointfield.training.run import RunDirectory

StepFunction = Callable[[Any], tuple[torch.Tensor, dict[str, float]]]


@dataclass
class TrainingState:
    """Where training stands; saved in every checkpoint.

    ``epoch`` epochs and ``step`` optimizer steps are finished; ``batch`` batches of the
    current epoch are done (0 at an epoch boundary); ``seconds`` of wall clock so far, over all
    sessions, of which ``evaluation_seconds`` went to evaluation; ``history`` holds one record per finished epoch; ``running`` the sums behind the
    current epoch's averages.
    """

    epoch: int = 0
    step: int = 0
    batch: int = 0
    seconds: float = 0.0
    evaluation_seconds: float = 0.0
    history: list[dict[str, Any]] = field(default_factory=list)
    running: dict[str, float] = field(default_factory=dict)

    @property
    def training_seconds(self) -> float:
        """Wall clock minus evaluation: the one clock every time-to-PSNR figure reads."""
        return self.seconds - self.evaluation_seconds


class Watcher(Protocol):
    """Something that sees training step by step (the browser viewer); see the module doc."""

    def after_step(self, model: nn.Module, state: TrainingState, loss: float) -> float:
        """Called after each optimizer step; returns the seconds it held training paused."""


_watchers: list[Watcher] = []


@contextmanager
def watched_by(watcher: Watcher) -> Iterator[Watcher]:
    """Within the block, every :func:`fit` calls ``watcher.after_step`` after each step (rank 0 only)."""
    _watchers.append(watcher)
    try:
        yield watcher
    finally:
        _watchers.remove(watcher)


def fit(
    model: nn.Module,
    optimizer: torch.optim.Optimizer,
    step: StepFunction,
    batches: Callable[[int], Iterable[Any]],
    epochs: int,
    *,
    run: RunDirectory | None = None,
    identity: dict[str, Any] | None = None,
    scheduler: Any = None,
    evaluate: Callable[[int], dict[str, float]] | None = None,
    on_epoch_end: Callable[[list[dict[str, Any]]], None] | None = None,
    loss_aliases: tuple[str, ...] = (),
    resume: bool = False,
    checkpoint_seconds: float | None = 300.0,
    max_training_seconds: float | None = None,
    budget: TimeBudget | None = None,
    finishing: Callable[[], float | None] | None = None,
    distributed: Distributed | None = None,
    device: torch.device | None = None,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
) -> TrainingState:
    """Train ``model`` for ``epochs`` epochs; returns the final :class:`TrainingState`.

    ``run`` is where checkpoints and ``metrics.jsonl`` go (None: keep nothing). In a
    distributed run every process passes the same ``run`` (all read the checkpoint when
    resuming) and only rank 0 writes. ``evaluate(epoch)`` returns metrics to add to the
    epoch's record (it must be collective in a distributed run); ``on_epoch_end(history)``
    runs on rank 0 after each record is logged (to redraw plots, say). ``loss_aliases`` are
    more record keys for the epoch's mean training loss besides ``train_loss`` (NeRF and
    splat records name it ``loss`` too, as their issues do); the printed line leaves them out.
    ``identity`` is stored in checkpoints and must match when resuming. ``log`` receives one
    line per epoch (default: printed above the progress bar, and flushed). ``max_training_seconds``,
    ``budget`` and ``finishing``: when to stop (module doc).
    """
    is_main = distributed is None or distributed.is_main
    device = device or next(model.parameters()).device
    write = log or _progress_write
    budget = budget or TimeBudget()
    limited = max_training_seconds is not None or budget.limited
    state = TrainingState()
    if resume and run is not None and run.checkpoint.is_file():
        payload = load_checkpoint(run.checkpoint, identity, map_location=device)
        restore(run.checkpoint, payload, model, optimizer, scheduler, rng=True)
        state = TrainingState(**payload["state"])
        if is_main:
            run.write_metrics_log(state.history)
            write(f"resuming {run.path} at epoch {state.epoch + 1}, batch {state.batch}")

    def checkpoint() -> None:
        if run is not None and is_main:
            save_checkpoint(
                run.checkpoint, identity=identity or {}, model=model, optimizer=optimizer,
                scheduler=scheduler, state=asdict(state),
            )

    def reserve() -> float:
        return budget.reserve(finishing() if finishing is not None else None)

    def time_is_up() -> bool:
        over = (max_training_seconds is not None and state.training_seconds >= max_training_seconds) or (
            budget.left() <= reserve())
        if distributed is not None:  # every process stops at the same step, or the collectives hang
            over = not distributed.all_true(not over, device)
        return over

    session_start = time.perf_counter()
    seconds_before = state.seconds
    last_checkpoint = time.perf_counter()
    last_evaluation: float | None = None
    out_of_time = False
    while state.epoch < epochs and not out_of_time:
        model.train()
        epoch_batches = batches(state.epoch)
        total = _length(epoch_batches)
        remaining = itertools.islice(epoch_batches, state.batch, None)
        bar = _progress_bar(total, state, epochs, progress and is_main)
        # Off a terminal the bar is silent (tqdm's disable=None): a status line now and then instead.
        quiet = progress and is_main and getattr(bar, "disable", False)
        status = _StatusLines(write, state, epochs, total) if quiet else None
        for batch in remaining:
            loss, stats = step(batch)
            finite = bool(torch.isfinite(loss.detach()).item())
            if distributed is not None:
                finite = distributed.all_true(finite, device)
            if not finite:
                bar.close()
                raise PointfieldError(
                    f"the loss became {loss.item() if loss.numel() == 1 else 'non-finite'} at "
                    f"epoch {state.epoch + 1}, step {state.step + 1}: the data may hold NaN or "
                    f"infinite values, or the learning rate is too high; nothing was saved "
                    f"from this step"
                )
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            state.step += 1
            state.batch += 1
            loss_value = float(loss.detach())
            _accumulate(state.running, {"loss": loss_value, **stats})
            for watcher in _watchers if is_main else ():
                session_start += watcher.after_step(model, state, loss_value)  # paused: off the clock
            state.seconds = seconds_before + time.perf_counter() - session_start
            bar.update(1)
            bar.set_postfix(_running_means(state.running))
            if status is not None:
                status.maybe()
            if limited and time_is_up():
                out_of_time = True
            if out_of_time or (
                checkpoint_seconds is not None
                and time.perf_counter() - last_checkpoint >= checkpoint_seconds
            ):
                if out_of_time or total is None or state.batch < total:
                    checkpoint()
                    last_checkpoint = time.perf_counter()
            if out_of_time:
                break
        bar.close()
        if out_of_time and total is not None and state.batch < total:
            partial = _partial_record(state, distributed, device, total, optimizer, loss_aliases)
            if is_main:
                if run is not None:
                    run.write_metrics_log([*state.history, partial])
                write(_format_record(partial, epochs, hidden=loss_aliases))
                if on_epoch_end is not None:
                    on_epoch_end([*state.history, partial])
            break
        record = _finish_epoch(state, distributed, device)
        if "train_loss" in record:  # an epoch without batches has no loss to alias
            record.update({alias: record["train_loss"] for alias in loss_aliases})
        if scheduler is not None:
            scheduler.step()
        record["lr"] = optimizer.param_groups[0]["lr"]
        # An evaluation the budget cannot hold besides its reserve is left to the final one.
        affordable = last_evaluation is None or budget.left() - reserve() >= last_evaluation
        if distributed is not None and budget.limited:
            affordable = distributed.all_true(affordable, device)
        if evaluate is not None and affordable:
            evaluation_started = time.perf_counter()
            record.update(evaluate(state.epoch))
            last_evaluation = time.perf_counter() - evaluation_started
            record["evaluation_seconds"] = round(last_evaluation, 3)
            state.evaluation_seconds += record["evaluation_seconds"]
        elif evaluate is not None:
            out_of_time = True
        state.epoch += 1
        state.seconds = seconds_before + time.perf_counter() - session_start
        record = {"epoch": state.epoch, "step": state.step, "seconds": round(state.seconds, 3),
                  "training_seconds": round(state.training_seconds, 3), **record}
        state.history.append(record)
        if is_main:
            if run is not None:
                run.write_metrics_log(state.history)
            write(_format_record(record, epochs, hidden=loss_aliases))
            if on_epoch_end is not None:
                on_epoch_end(state.history)
        checkpoint()
        last_checkpoint = time.perf_counter()
        if limited and not out_of_time and state.epoch < epochs:
            out_of_time = time_is_up()
    return state


def _accumulate(running: dict[str, float], values: dict[str, float]) -> None:
    for name, value in values.items():
        running[name] = running.get(name, 0.0) + float(value)
    running["batches"] = running.get("batches", 0.0) + 1


def _running_means(running: dict[str, float]) -> dict[str, str]:
    """The epoch's means so far, loss first, formatted for the progress bar.

    A stat's mean is the mean of its per-batch values (as in the epoch's record): for PSNR, the
    mean of the batches' PSNR, not the PSNR of their mean squared error.
    """
    count = running["batches"]
    return {name: _short(total / count) for name, total in running.items() if name != "batches"}


def _short(value: float) -> str:
    """Four significant digits below 1 (a loss of 0.0001234), two decimals up to 1000, else none."""
    if abs(value) < 1:
        return f"{value:.4g}"
    return f"{value:.2f}" if abs(value) < 1000 else f"{value:.0f}"


def _finish_epoch(
    state: TrainingState, distributed: Distributed | None, device: torch.device
) -> dict[str, float]:
    """The epoch's averages (over every process's batches), and a clean slate for the next."""
    running, state.running, state.batch = state.running, {}, 0
    return _means(running, distributed, device)


def _partial_record(
    state: TrainingState, distributed: Distributed | None, device: torch.device, total: int,
    optimizer: torch.optim.Optimizer, loss_aliases: tuple[str, ...],
) -> dict[str, Any]:
    """The record of an epoch stopped after ``state.batch`` of its ``total`` batches (module doc)."""
    means = _means(dict(state.running), distributed, device)
    if "train_loss" in means:
        means.update({alias: means["train_loss"] for alias in loss_aliases})
    return {"epoch": round(state.epoch + state.batch / total, 3), "step": state.step,
            "seconds": round(state.seconds, 3), "training_seconds": round(state.training_seconds, 3),
            "partial": True, **means, "lr": optimizer.param_groups[0]["lr"]}


def _means(running: dict[str, float], distributed: Distributed | None, device: torch.device) -> dict[str, float]:
    """``train_<stat>`` (``train_loss``) means of the running sums, over every process's batches."""
    names = sorted(running)
    if distributed is not None:
        totals = torch.tensor([running.get(n, 0.0) for n in names], dtype=torch.float64,
                              device=device)
        running = dict(zip(names, distributed.all_reduce_sum(totals).tolist()))
    count = running.pop("batches", 0.0)
    return {
        f"train_{name}" if name != "loss" else "train_loss": (value / count if count else math.nan)
        for name, value in running.items()
    }


def _format_record(record: dict[str, Any], epochs: int, hidden: tuple[str, ...] = ()) -> str:
    if record.get("partial"):
        parts = [f"stopped in time in epoch {math.floor(record['epoch']) + 1}/{epochs} at step {record['step']}"]
    else:
        parts = [f"epoch {record['epoch']}/{epochs}"]
    for name, value in record.items():
        if name in ("epoch", "step", "seconds", "training_seconds", "lr", "evaluation_seconds", "partial") \
                or name in hidden:
            continue
        parts.append(f"{name.replace('_', ' ')} {value:.4f}" if isinstance(value, float)
                     else f"{name} {value}")
    parts.append(f"({record['seconds']:.1f} s)")
    return "  ".join(parts)


def _length(iterable: Iterable[Any]) -> int | None:
    try:
        return len(iterable)  # type: ignore[arg-type]
    except TypeError:
        return None


class _NoBar:
    disable = True

    def update(self, count: int) -> None:
        pass

    def set_postfix(self, values: dict[str, str]) -> None:
        pass

    def close(self) -> None:
        pass


def _progress_bar(total: int | None, state: TrainingState, epochs: int, show: bool):
    if not show:
        return _NoBar()
    return console.progress_bar(True, total=total, initial=state.batch, desc=f"epoch {state.epoch + 1}/{epochs}",
                                unit="batch")


def _progress_write(line: str) -> None:
    console.write_line(line)


class _StatusLines:
    """A line with the step, the epoch's running means and the clock, at least every
    :data:`~pointfield.training.console.STATUS_SECONDS` (the first after the first step, so that
    a log shows training started)."""

    def __init__(self, write: Callable[[str], None], state: TrainingState, epochs: int, total: int | None):
        self.write, self.state, self.epochs, self.total = write, state, epochs, total
        self.last: float | None = None

    def maybe(self) -> None:
        now = time.perf_counter()
        if self.last is not None and now - self.last < console.STATUS_SECONDS:
            return
        self.last = now
        state = self.state
        of = f"/{self.total}" if self.total is not None else ""
        means = "  ".join(f"{name} {value}" for name, value in _running_means(state.running).items())
        self.write(f"epoch {state.epoch + 1}/{self.epochs}  batch {state.batch}{of}  step {state.step}  "
                   f"{means}  ({state.seconds:.0f} s)")
