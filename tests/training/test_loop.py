"""The training loop: records, checkpoints, resuming exactly, NaN losses, time limits."""

from __future__ import annotations

import io
import json
import sys

import pytest
import torch
from torch import nn

from pointfield.errors import PointfieldError
from pointfield.training import (
    RunDirectory,
    fit,
    load_checkpoint,
    loop,
    restore,
    save_checkpoint,
)
from pointfield.training.budget import TimeBudget

IDENTITY = {"task": "toy", "model": "linear"}


class Interrupted(Exception):
    """Stands in for the process being killed."""


def toy_problem(seed: int = 0):
    """A linear classifier on fixed random data; steps add torch noise to test RNG restoring."""
    torch.manual_seed(seed)
    model = nn.Sequential(nn.Linear(4, 8), nn.Dropout(0.2), nn.Linear(8, 3))
    optimizer = torch.optim.SGD(model.parameters(), lr=0.1)
    generator = torch.Generator().manual_seed(1)
    data = [(torch.randn(8, 4, generator=generator), torch.randint(0, 3, (8,), generator=generator))
            for _ in range(5)]

    def batches(epoch: int):
        order = torch.randperm(len(data), generator=torch.Generator().manual_seed(epoch))
        return [data[i] for i in order]

    def step(batch):
        x, y = batch
        logits = model(x + 0.01 * torch.randn_like(x))
        loss = nn.functional.cross_entropy(logits, y)
        return loss, {"accuracy": float((logits.argmax(-1) == y).float().mean())}

    return model, optimizer, batches, step


def weights(model: nn.Module) -> list[torch.Tensor]:
    return [p.detach().clone() for p in model.parameters()]


def test_fit_logs_one_record_per_epoch_and_checkpoints(tmp_path):
    model, optimizer, batches, step = toy_problem()
    run = RunDirectory(tmp_path)
    run.create(resume=False)
    state = fit(model, optimizer, step, batches, 3, run=run, identity=IDENTITY,
                evaluate=lambda epoch: {"test_score": float(epoch)}, progress=False,
                log=lambda line: None)
    records = [json.loads(line) for line in run.metrics_log.read_text().splitlines()]
    assert [r["epoch"] for r in records] == [1, 2, 3] and state.step == 15
    assert {"train_loss", "train_accuracy", "test_score", "lr", "seconds"} <= set(records[0])
    payload = load_checkpoint(run.checkpoint, IDENTITY)
    assert payload["state"]["epoch"] == 3 and len(payload["state"]["history"]) == 3


def test_the_progress_bar_shows_the_running_mean_of_the_loss_and_every_stat(monkeypatch):
    import pointfield.training.loop as loop

    shown: list[dict[str, str]] = []

    class Bar:
        def update(self, count):
            pass

        def set_postfix(self, values):
            shown.append(dict(values))

        def close(self):
            pass

    monkeypatch.setattr(loop, "_progress_bar", lambda *args: Bar())
    losses, psnrs = iter([0.5, 0.25, 0.125]), iter([10.0, 20.0, 40.0])

    model = nn.Linear(1, 1)

    def step(batch):
        return model(batch).sum() * 0 + next(losses), {"psnr": next(psnrs)}

    fit(model, torch.optim.SGD(model.parameters(), lr=0.0), step,
        lambda epoch: [torch.ones(1, 1)] * 3 if epoch == 0 else [], 1, log=lambda line: None)
    assert shown == [{"loss": "0.5", "psnr": "10.00"}, {"loss": "0.375", "psnr": "15.00"},
                     {"loss": "0.2917", "psnr": "23.33"}]
    assert list(shown[0]) == ["loss", "psnr"]


def test_loss_aliases_repeat_the_training_loss_in_each_record_but_not_in_the_printed_line(tmp_path):
    model, optimizer, batches, step = toy_problem()
    run = RunDirectory(tmp_path)
    run.create(resume=False)
    lines: list[str] = []
    fit(model, optimizer, step, batches, 2, run=run, loss_aliases=("loss",), progress=False,
        log=lines.append)
    records = run.read_metrics_log()
    assert all(r["loss"] == r["train_loss"] for r in records)
    assert all(" loss " not in line.replace("train loss", "") for line in lines)


def test_records_have_no_loss_alias_unless_asked(tmp_path):
    model, optimizer, batches, step = toy_problem()
    state = fit(model, optimizer, step, batches, 1, progress=False, log=lambda line: None)
    assert "loss" not in state.history[0] and "train_loss" in state.history[0]


def test_resuming_after_an_epoch_gives_the_same_model_as_never_stopping(tmp_path):
    model, optimizer, batches, step = toy_problem()
    fit(model, optimizer, step, batches, 4, progress=False, log=lambda line: None)
    expected = weights(model)

    run = RunDirectory(tmp_path)
    run.create(resume=False)
    model, optimizer, batches, step = toy_problem()
    fit(model, optimizer, step, batches, 2, run=run, progress=False, log=lambda line: None)
    model, optimizer, batches, step = toy_problem(seed=99)  # a fresh process
    fit(model, optimizer, step, batches, 4, run=run, resume=True, progress=False,
        log=lambda line: None)
    for a, b in zip(weights(model), expected):
        torch.testing.assert_close(a, b, rtol=0, atol=0)
    assert [r["epoch"] for r in run.read_metrics_log()] == [1, 2, 3, 4]


def test_a_run_killed_mid_epoch_resumes_from_the_last_step_checkpoint(tmp_path):
    model, optimizer, batches, step = toy_problem()
    fit(model, optimizer, step, batches, 2, progress=False, log=lambda line: None)
    expected = weights(model)

    run = RunDirectory(tmp_path)
    run.create(resume=False)
    model, optimizer, batches, step = toy_problem()
    calls = []

    def dying_step(batch):
        calls.append(1)
        if len(calls) == 8:  # the third batch of the second epoch
            raise Interrupted
        return step(batch)

    with pytest.raises(Interrupted):
        fit(model, optimizer, dying_step, batches, 2, run=run, checkpoint_seconds=0,
            progress=False, log=lambda line: None)
    assert load_checkpoint(run.checkpoint)["state"]["batch"] == 2
    model, optimizer, batches, step = toy_problem(seed=5)
    fit(model, optimizer, step, batches, 2, run=run, resume=True, progress=False,
        log=lambda line: None)
    for a, b in zip(weights(model), expected):
        torch.testing.assert_close(a, b, rtol=0, atol=0)
    assert [r["epoch"] for r in run.read_metrics_log()] == [1, 2]


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_a_checkpoint_read_onto_the_gpu_restores_the_random_generators(tmp_path):
    # resuming on a GPU reads the checkpoint with map_location="cuda", which moves the generator
    # states there too; torch.set_rng_state takes CPU byte tensors only
    model = nn.Linear(2, 1)
    torch.manual_seed(3)
    save_checkpoint(tmp_path / "last.pt", identity={"task": "toy"}, model=model)
    expected = torch.rand(4), torch.rand(4, device="cuda")
    restore(tmp_path / "last.pt", load_checkpoint(tmp_path / "last.pt", map_location="cuda"), model, rng=True)
    torch.testing.assert_close(torch.rand(4), expected[0], rtol=0, atol=0)
    torch.testing.assert_close(torch.rand(4, device="cuda"), expected[1], rtol=0, atol=0)


def test_a_nan_loss_stops_training_with_a_clear_error(tmp_path):
    model, optimizer, batches, step = toy_problem()
    before = weights(model)

    def nan_step(batch):
        loss, stats = step(batch)
        return loss * float("nan"), stats

    with pytest.raises(PointfieldError, match="epoch 1, step 1"):
        fit(model, optimizer, nan_step, batches, 1, progress=False, log=lambda line: None)
    for a, b in zip(weights(model), before):
        torch.testing.assert_close(a, b)


def test_max_training_seconds_stops_after_the_current_step_with_a_checkpoint(tmp_path):
    model, optimizer, batches, step = toy_problem()
    run = RunDirectory(tmp_path)
    run.create(resume=False)
    state = fit(model, optimizer, step, batches, 100, run=run, max_training_seconds=0.0,
                progress=False, log=lambda line: None)
    assert state.step == 1 and load_checkpoint(run.checkpoint)["state"]["step"] == 1


def test_a_run_stopped_before_its_first_evaluation_still_logs_a_partial_record_and_draws_it(tmp_path):
    model, optimizer, batches, step = toy_problem()
    run = RunDirectory(tmp_path)
    run.create(resume=False)
    drawn, lines = [], []
    state = fit(model, optimizer, step, batches, 100, run=run, max_training_seconds=0.0,
                evaluate=lambda epoch: {"test_score": 1.0}, on_epoch_end=drawn.append, progress=False,
                log=lines.append)
    records = run.read_metrics_log()
    assert len(records) == 1 and records[0]["partial"] is True
    assert records[0]["epoch"] == pytest.approx(1 / 5) and records[0]["step"] == 1
    assert records[0]["train_loss"] == pytest.approx(state.running["loss"])
    assert "test_score" not in records[0]  # stopped before any evaluation
    assert drawn == [records] and lines[-1].startswith("stopped in time in epoch 1/100 at step 1")
    assert state.history == []  # the checkpoint keeps whole epochs only


def test_resuming_a_partial_epoch_replaces_its_record_with_the_whole_epochs(tmp_path):
    model, optimizer, batches, step = toy_problem()
    run = RunDirectory(tmp_path)
    run.create(resume=False)
    fit(model, optimizer, step, batches, 2, run=run, max_training_seconds=0.0, progress=False, log=lambda line: None)
    fit(model, optimizer, step, batches, 2, run=run, resume=True, progress=False, log=lambda line: None)
    assert [record["epoch"] for record in run.read_metrics_log()] == [1, 2]
    assert not any(record.get("partial") for record in run.read_metrics_log())


def test_a_time_budget_stops_training_leaving_its_reserve_for_the_final_evaluation():
    model, optimizer, batches, step = toy_problem()
    budget = TimeBudget(10.0)
    finishing = 7.0  # the final evaluation's estimated seconds: the budget keeps 5 s (its largest share) for it
    state = fit(model, optimizer, step, batches, 10**6, budget=budget, finishing=lambda: finishing,
                progress=False, log=lambda line: None)
    assert budget.reserve(finishing) == pytest.approx(5.0)
    assert 4.9 <= budget.left() <= 5.0 + 0.5 and state.step > 1


def test_an_evaluation_the_budget_cannot_hold_is_left_to_the_final_one(monkeypatch):
    model, optimizer, batches, step = toy_problem()
    clock = [0.0]
    monkeypatch.setattr(loop.time, "perf_counter", lambda: clock[0])

    def ticking_step(batch):
        clock[0] += 1.0
        return step(batch)

    def evaluate(epoch):
        clock[0] += 20.0
        return {"test_score": float(epoch)}

    # Epochs of 5 steps (5 s); the first evaluation takes 20 s; 100 s of budget, 20 s of which are kept.
    state = fit(model, optimizer, ticking_step, batches, 100, budget=TimeBudget(100.0, started=0.0),
                evaluate=evaluate, progress=False, log=lambda line: None)
    evaluated = ["test_score" in record for record in state.history]
    # Three epochs of 5 + 20 s end at 75 s; the fourth's steps end at 80 s, where only the 20 s kept
    # for the final evaluation are left: its evaluation is skipped and training stops there.
    assert evaluated == [True, True, True, False] and clock[0] == 80.0


def test_off_a_terminal_training_prints_a_status_line_at_least_every_minute(monkeypatch):
    model, optimizer, batches, step = toy_problem()
    clock = [0.0]
    monkeypatch.setattr(loop.time, "perf_counter", lambda: clock[0])

    def slow_step(batch):
        clock[0] += 25.0
        return step(batch)

    lines: list[str] = []
    monkeypatch.setattr(loop, "_progress_bar", lambda *args: loop._NoBar())  # what tqdm is off a terminal
    fit(model, optimizer, slow_step, batches, 1, progress=True, log=lines.append)
    status = [line for line in lines if "batch" in line]
    # Steps end at 25, 50, ..., 125 s: a line after the first, then once 60 s have passed (at 100 s).
    assert [line.split("  ")[1] for line in status] == ["batch 1/5", "batch 4/5"]
    assert lines[-1].startswith("epoch 1/1")


def test_no_status_lines_when_asked_for_no_progress(monkeypatch):
    model, optimizer, batches, step = toy_problem()
    lines: list[str] = []
    fit(model, optimizer, step, batches, 1, progress=False, log=lines.append)
    assert len(lines) == 1 and lines[0].startswith("epoch 1/1")


def test_each_line_is_flushed_so_a_log_file_shows_it_at_once(monkeypatch):
    class File(io.StringIO):
        flushed = ""

        def flush(self):
            self.flushed = self.getvalue()

    output = File()
    monkeypatch.setattr(sys, "stdout", output)
    model, optimizer, batches, step = toy_problem()
    fit(model, optimizer, step, batches, 1, progress=False)
    assert output.flushed.startswith("epoch 1/1") and output.flushed == output.getvalue()


def test_a_checkpoint_of_another_model_is_refused_by_name(tmp_path):
    model, optimizer, _, _ = toy_problem()
    path = tmp_path / "last.pt"
    save_checkpoint(path, identity={"task": "toy", "model": "pointnet2"}, model=model)
    with pytest.raises(PointfieldError, match="model 'pointnet2', expected 'linear'"):
        load_checkpoint(path, IDENTITY)


def test_files_that_are_not_checkpoints_are_refused(tmp_path):
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(b"\x00" * 100)
    with pytest.raises(PointfieldError, match="not a readable pointfield checkpoint"):
        load_checkpoint(garbage)
    other = tmp_path / "other.pt"
    torch.save({"weights": torch.zeros(2)}, other)
    with pytest.raises(PointfieldError, match="not a pointfield checkpoint"):
        load_checkpoint(other)
    future = tmp_path / "future.pt"
    torch.save({"format": "pointfield-checkpoint", "version": 99}, future)
    with pytest.raises(PointfieldError, match="version 99"):
        load_checkpoint(future)


def test_a_new_run_refuses_to_overwrite_an_old_one_in_python_words(tmp_path):
    run = RunDirectory(tmp_path)
    run.create(resume=False)
    run.write_config({"task": "toy"})
    with pytest.raises(PointfieldError, match="pass resume=True to continue it, or choose another out$") as refused:
        RunDirectory(tmp_path).create(resume=False)
    assert "--" not in str(refused.value)
    assert refused.value.command_line.endswith("pass --resume to continue it, or choose another --out")
