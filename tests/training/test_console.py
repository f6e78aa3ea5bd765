"""What ``nerf train`` and ``splat train`` print when their output is not a terminal (a batch job's log).

Under pytest stdout and stderr are not terminals, as in a batch job: tqdm's bar is off, so the
loop must speak on its own -- a line per evaluation round and a status line at least every
``STATUS_SECONDS`` (set to 0 here, so every step gives one).
"""

from __future__ import annotations

import pytest

from pointfield.fields.train import train as train_field
from pointfield.splats.train import train as train_splats
from pointfield.training import console

CUBE = {"cube_views": 12, "cube_size": 12, "device": "cpu", "steps": 4, "eval_every": 2}


@pytest.mark.parametrize("train", [
    lambda out: train_field(out=out, model="tiny", batch_rays=128, model_options={"samples": 8}, **CUBE),
    lambda out: train_splats(out=out, initial_splats=200, **CUBE),
], ids=["nerf", "splat"])
def test_off_a_terminal_training_prints_each_round_and_status_lines(train, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(console, "STATUS_SECONDS", 0.0)
    train(tmp_path / "run")
    lines = capsys.readouterr().out.splitlines()
    rounds = [line for line in lines if line.startswith(("epoch 1/2  ", "epoch 2/2  ")) and " psnr " in line
              and "batch" not in line]
    status = [line for line in lines if "  batch " in line and "  step " in line]
    assert len(rounds) == 2  # one line per evaluation round, with its held-out PSNR
    assert [line.split("  step ")[1].split()[0] for line in status] == ["1", "2", "3", "4"]


def test_no_progress_means_no_status_lines(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(console, "STATUS_SECONDS", 0.0)
    train_field(out=tmp_path / "run", model="tiny", batch_rays=128, model_options={"samples": 8}, progress=False, **CUBE)
    assert not [line for line in capsys.readouterr().out.splitlines() if "  batch " in line]
