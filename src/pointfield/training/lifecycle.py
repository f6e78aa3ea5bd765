"""The life of every run, written once: start or resume it, train it, open it again later.

:func:`train` takes a :class:`~pointfield.training.task.Task` class and the caller's settings:

1. the task checks the settings into a config (:meth:`Task.configure`); resuming, the run's
   own ``config.json`` wins except for the task's ``extendable`` settings (a longer run);
2. the task opens its data and builds its model -- before the run folder is touched, so a bad
   scene or option leaves an existing folder as it was;
3. the folder is created (refusing to start over an old run unless resuming) and the config
   written; the task warms up off the clock;
4. :func:`~pointfield.training.fit` trains, checkpointing atomically, resuming where a killed
   run stopped;
5. the task's final metrics go to ``metrics.json`` (strict JSON: NaN is written as null),
   with the clock's figures, the same for every task: ``seconds`` (wall clock, evaluation
   included), ``training_seconds`` (evaluation excluded), ``startup_seconds`` (this session's
   time from the call to the first step: data, model, kernel compilation, which neither clock
   counts) and ``wall_seconds`` (this session's whole call, up to writing ``metrics.json``).

``max_time`` is the wall clock of the whole call, start-up and final evaluation included
(:mod:`~pointfield.training.budget`); ``max_training_time`` the training clock alone, for
benchmarks that compare runs at equal training time.

Under ``torchrun`` every process runs the same lifecycle; only rank 0 writes.

:func:`open_run` is the other half: a run folder opened as a :class:`~pointfield.training.Run`
of the class that knows its task, whose ``open`` loads the model with :func:`restore_model` --
the last checkpoint, checked against what the run's config says it is (``weights_only``
loading, see :mod:`~pointfield.training.checkpoints`).
"""

from __future__ import annotations

import os
import time
from typing import Any

import torch
from torch import nn

from pointfield.devices import pick_device
from pointfield.errors import PointfieldError
from pointfield.training import distributed as processes
from pointfield.training.budget import TimeBudget
from pointfield.training.checkpoints import load_checkpoint, restore
from pointfield.training.loop import fit
from pointfield.training.run import Run, RunDirectory
from pointfield.training.task import Task


def train(
    task_class: type[Task],
    settings: dict[str, Any],
    *,
    options: dict[str, Any] | None = None,
    out: str | os.PathLike[str],
    resume: bool = False,
    device: str | None = None,
    max_time: float | None = None,
    max_training_time: float | None = None,
    checkpoint_seconds: float | None = 300.0,
    progress: bool = True,
) -> dict[str, Any]:
    """Train a new run of ``task_class`` into ``out``, or resume it; returns the final metrics.

    ``settings`` are the task's own (see its ``configure``); a setting given as None means
    "the default", or, when resuming, "as the run had it". ``options`` go to the task's
    constructor and are not part of the run's record (data-loading workers, say). ``max_time``:
    the call returns within that many seconds of wall clock, with its final evaluation scaled to
    fit (module doc). ``max_training_time``: stop training after that many seconds of it
    (evaluation excluded), summed over resumed sessions. Launched by ``torchrun`` with several
    processes, this trains with DistributedDataParallel.
    """
    started = time.perf_counter()
    try:
        budget = TimeBudget(max_time, started)
    except ValueError as error:
        raise PointfieldError(f"max_time: {error}") from None
    distributed, torch_device = processes.setup(device)
    is_main = distributed is None or distributed.is_main
    try:
        run = RunDirectory(out)
        config = task_class.configure(settings)
        if resume and run.exists():
            saved = run.read_config()
            if saved.get("task") != task_class.name:
                raise PointfieldError(
                    f"{run.path} is a {saved.get('task')!r} run, not a {task_class.name!r} run"
                )
            given = {name: config[name] for name in task_class.extendable if settings.get(name) is not None}
            config = {**saved, **given}
        torch.manual_seed(config["seed"])
        task = task_class(config, torch_device, distributed, progress and is_main, **(options or {}))
        task.time_budget = budget
        task.training_budget = max_training_time
        if is_main:
            run.create(resume)  # only now: a bad scene or option leaves an existing folder untouched
            run.write_config(task.config)
        task.warm_up()
        # Opening the data, building the model, compiling kernels: reported beside the training
        # clock, never on it (this session's; a resumed run's earlier start-ups are gone).
        startup_seconds = time.perf_counter() - started

        def step(batch: Any) -> tuple[torch.Tensor, dict[str, float]]:
            return task.step(batch).total()

        state = fit(
            task.trained, task.optimizer, step, task.batches, task.epochs, run=run,
            identity=task.identity, scheduler=task.scheduler, evaluate=task.evaluate,
            on_epoch_end=lambda history: task.draw(run, history), loss_aliases=task.loss_aliases,
            resume=resume, checkpoint_seconds=checkpoint_seconds, max_training_seconds=max_training_time,
            budget=budget, finishing=task.finishing_seconds,
            distributed=distributed, device=torch_device, progress=task.progress,
        )
        metrics = {
            **task.finish(run, state),
            "seconds": round(state.seconds, 3),
            "training_seconds": round(state.training_seconds, 3),
            "startup_seconds": round(startup_seconds, 3),
            "wall_seconds": round(budget.elapsed(), 3),
        }
        if is_main:
            run.write_final_metrics(metrics)
        if distributed is not None:
            # Leave together, once gloo's workers have let go of the last collective's tensors:
            # see processes.shutdown.
            distributed.barrier()
        return metrics
    finally:
        processes.shutdown()


def restore_model(
    run: RunDirectory, model: nn.Module, identity: dict[str, Any], device: torch.device
) -> nn.Module:
    """``model`` with the run's last checkpoint loaded, on ``device``, in evaluation mode.

    The checkpoint must match ``identity`` (what the run's config says it is), else
    :class:`PointfieldError` names the difference.
    """
    payload = load_checkpoint(run.checkpoint, identity, map_location=device)
    restore(run.checkpoint, payload, model)
    return model.to(device).eval()


def open_run(
    run_classes: tuple[type[Run], ...], path: str | os.PathLike[str], device: str | torch.device | None = None
) -> Run:
    """The run in folder ``path``, opened by whichever of ``run_classes`` knows its task, on ``device``.

    A folder that is not a run, or a run of a task none of them opens, raises
    :class:`PointfieldError` saying so.
    """
    directory = RunDirectory(path)
    config = directory.read_config()
    task = config.get("task")
    for run_class in run_classes:
        if task in run_class.tasks:
            return run_class.open(directory, config, pick_device(device))
    expected = " or ".join(repr(name) for run_class in run_classes for name in run_class.tasks)
    raise PointfieldError(f"{directory.path}: a run of task {task!r}, not {expected}")
