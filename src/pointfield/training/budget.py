"""The wall clock a whole training command may take: ``--max-time`` / ``max_time``.

A user who writes ``--max-time 60`` expects the command back in a minute, so the budget covers
everything the call does -- opening the data, building and compiling the model, training, the
evaluations during training, the final evaluation and the run's files -- not training alone.
:class:`TimeBudget` is that clock, started when the call starts. The training loop stops
training early enough to leave :meth:`TimeBudget.reserve` seconds for what follows it, and the
final evaluation renders held-out views only while the budget lasts (at least one), saying in
``metrics.json`` how many it scored (:func:`pointfield.scenes.heldout.heldout_scores`).

Benchmarks that fix the training time instead (time-to-PSNR curves) pass ``max_training_time``,
which counts ``training_seconds`` (evaluation excluded) and is followed by the full final
evaluation.
"""

from __future__ import annotations

import math
import time

FINAL_SHARE = 0.2
"""The share of the budget held back for what follows training (the final evaluation and the run's
files) while the final evaluation's cost is not yet known."""
MEASURED_FINAL_SHARE = 0.5
"""The largest share held back once that cost is measured. A score over some of the held-out views
is not comparable with one over all of them, so the whole evaluation is kept for up to half the
budget: a field's view of the fox's photos at 479 px takes about 21 s on 2 CPU cores, and its seven
views did not fit a fifth of the default 540 s (bench_photos scored five)."""
FINISHING_SECONDS = 2.0
"""Held back beyond the final evaluation's measured cost: the checkpoint, the curves and the
held-out panels written after training (about a second for lego at 100 x 100 pixels on a busy
2-core CPU), with a margin."""
WRITING_SECONDS = 1.0
"""Of those, what the final evaluation leaves for writing its panels and ``metrics.json``."""


class TimeBudget:
    """``seconds`` of wall clock from ``started`` (a :func:`time.perf_counter` reading; default now).

    ``seconds`` None is no limit: :meth:`left` is infinite and nothing is ever cut short.
    """

    def __init__(self, seconds: float | None = None, started: float | None = None):
        if seconds is not None and not seconds > 0:
            raise ValueError(f"a time budget must be a positive number of seconds, got {seconds}")
        self.seconds = seconds
        self.started = time.perf_counter() if started is None else started

    @property
    def limited(self) -> bool:
        return self.seconds is not None

    @property
    def deadline(self) -> float:
        """The :func:`time.perf_counter` reading by which the call must be done (inf: none)."""
        return math.inf if self.seconds is None else self.started + self.seconds

    def elapsed(self) -> float:
        return time.perf_counter() - self.started

    def left(self) -> float:
        return self.deadline - time.perf_counter()

    def reserve(self, finishing: float | None) -> float:
        """Seconds to keep for what follows training, given the final evaluation's estimated cost.

        ``finishing`` None (not measured yet): :data:`FINAL_SHARE` of the budget. Otherwise that
        cost plus :data:`FINISHING_SECONDS`, but never more than :data:`MEASURED_FINAL_SHARE` of
        it: a final evaluation dearer than that scores fewer views rather than taking more of the
        training's time.
        """
        if self.seconds is None:
            return 0.0
        if finishing is None:
            return FINAL_SHARE * self.seconds
        return min(finishing + FINISHING_SECONDS, MEASURED_FINAL_SHARE * self.seconds)

    def __repr__(self) -> str:
        return f"TimeBudget({self.seconds}, elapsed={self.elapsed():.1f})"
