"""The training loop's watcher hook, which ``--view`` uses: called after every step, pauses off the clock."""

from __future__ import annotations

import time

import torch
from torch import nn

from pointfield.training.loop import fit, watched_by


class Recorder:
    """Records each call; holds training for ``pause`` seconds after step 2, as a paused page does."""

    def __init__(self, pause: float):
        self.pause = pause
        self.steps: list[int] = []

    def after_step(self, model, state, loss):
        self.steps.append(state.step)
        assert isinstance(model, nn.Module) and loss > 0
        if state.step == 2:
            time.sleep(self.pause)
            return self.pause
        return 0.0


def train_a_little() -> tuple[float, float]:
    torch.manual_seed(0)
    model = nn.Linear(3, 1)
    data = [(torch.randn(8, 3), torch.randn(8, 1)) for _ in range(4)]

    def step(batch):
        inputs, targets = batch
        return torch.mean((model(inputs) - targets) ** 2), {}

    started = time.perf_counter()
    state = fit(model, torch.optim.SGD(model.parameters(), lr=0.1), step, lambda epoch: data, 1, progress=False)
    return time.perf_counter() - started, state.seconds


def test_a_watcher_sees_every_step_and_its_pause_is_left_off_the_clock():
    watcher = Recorder(pause=0.5)
    with watched_by(watcher):
        wall, clock = train_a_little()
    assert watcher.steps == [1, 2, 3, 4]
    assert wall - clock >= 0.45


def test_nothing_watches_outside_the_block():
    watcher = Recorder(pause=0.0)
    with watched_by(watcher):
        pass
    train_a_little()
    assert watcher.steps == []
