"""Each long-running command says in its ``--help`` what a default run costs, as docs/runs.md measured it."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from pointfield.cli import main

RUNS_DOC = Path(__file__).resolve().parents[1] / "docs" / "runs.md"


@pytest.mark.parametrize(("command", "said"), [
    (["classify", "train"], "A default run (PointNet, 10 epochs of the built-in shapes) takes about 15 minutes"),
    (["segment", "train"], "takes about 25 minutes on a 2-core laptop CPU, 2.5 minutes an epoch"),
])
def test_train_help_says_what_a_default_run_costs(command, said, capsys):
    with pytest.raises(SystemExit):
        main([*command, "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert said in text
    cpu = re.search(r"one epoch costs about (\d+) CPU-seconds", text).group(1)
    measured = [row for row in RUNS_DOC.read_text().splitlines() if row.startswith(f"| `pointfield {command[0]} train")]
    assert len(measured) == 1
    cpu_measured = int(re.search(r"\| (\d+) s \(\d", measured[0]).group(1))
    assert abs(int(cpu) - cpu_measured) <= 0.05 * cpu_measured  # the help's figure is the measurement's


def test_nerf_exercise_help_says_what_its_100_epochs_cost(capsys):
    with pytest.raises(SystemExit):
        main(["nerf", "exercise", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "100 epochs (about 20 minutes on a 2-core laptop CPU: one epoch costs about 18 CPU-seconds" in text
    assert "(18 s each)" in RUNS_DOC.read_text()
