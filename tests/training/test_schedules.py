"""The learning-rate schedule sized to a run's budget: warm-up, then a cosine that reaches its floor
at whichever limit (steps, training seconds, wall clock) comes first, and resumes where it was."""

from __future__ import annotations

import math
import time

import pytest
import torch

from pointfield.training.budget import TimeBudget
from pointfield.training.schedules import BudgetCosine


def optimizer(rate: float = 0.01) -> torch.optim.Optimizer:
    return torch.optim.SGD([torch.nn.Parameter(torch.zeros(2))], lr=rate)


def test_the_rate_warms_up_then_falls_by_a_cosine_to_its_floor_at_the_last_step():
    schedule = BudgetCosine(optimizer(0.01), total_steps=100, warmup=0.1, start=0.1, final=0.01)
    rates = [schedule.advance() for _ in range(101)]
    assert rates[0] == pytest.approx(0.001)  # start x base
    assert rates[5] == pytest.approx(0.001 + 0.009 * 0.5)  # halfway up the warm-up
    assert rates[10] == pytest.approx(0.01) == max(rates)
    assert rates[55] == pytest.approx(0.01 * (0.01 + 0.99 * 0.5))  # the cosine's middle
    assert rates[100] == pytest.approx(0.0001)
    assert all(a >= b for a, b in zip(rates[10:], rates[11:]))


def test_a_run_stopped_by_its_training_seconds_ends_annealed_whatever_its_epochs():
    schedule = BudgetCosine(optimizer(), total_steps=10**6, training_seconds=1e-9)
    schedule.advance()
    assert schedule.advance() == pytest.approx(0.01 * 0.01)  # past its time: at the floor at once
    assert schedule.progress() == 1.0


def test_the_wall_clock_budget_counts_too():
    spent = TimeBudget(10.0, started=0.0)  # started long ago: its 10 s are gone
    schedule = BudgetCosine(optimizer(), total_steps=10**6, wall=spent)
    assert schedule.advance() == pytest.approx(0.0001)


def test_paused_time_is_not_training_time():
    schedule = BudgetCosine(optimizer(), training_seconds=100.0)
    schedule.advance()
    schedule.pause()
    time.sleep(0.3)  # an evaluation, off the clock
    schedule.resume()
    schedule.advance()
    assert schedule.seconds < 0.3
    time.sleep(0.3)  # a step, on it
    schedule.advance()
    assert schedule.seconds >= 0.3


def test_a_resumed_schedule_continues_from_its_saved_step():
    first = BudgetCosine(optimizer(), total_steps=40)
    for _ in range(25):
        first.advance()
    second = BudgetCosine(optimizer(), total_steps=40)
    second.load_state_dict(first.state_dict())
    assert second.advance() == pytest.approx(first.advance())
    assert second.factor(1.0) == pytest.approx(0.01) and math.isclose(second.factor(0.0), 0.1)
