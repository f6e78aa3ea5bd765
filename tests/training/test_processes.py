"""Real processes: a run killed with SIGKILL resumes and finishes; two CPU processes train with DDP."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import pointfield

TIMEOUT = 240
TINY = dict(shapes_per_class=4, points=64, epochs=2, batch_size=4, input_transform=False,
            feature_transform=False)


def environment(tmp_path: Path) -> dict[str, str]:
    # One thread per process: the test machine's cores are shared.
    return {**os.environ, "POINTFIELD_CACHE": str(tmp_path / "cache"), "OMP_NUM_THREADS": "1"}


@pytest.mark.skipif(not hasattr(signal, "SIGKILL"), reason="needs POSIX signals")
def test_a_run_killed_mid_training_resumes_and_finishes(tmp_path):
    out = tmp_path / "run"
    script = (
        "import pointfield.clouds.tasks as tasks\n"
        f"tasks.train('classify', out={str(out)!r}, checkpoint_seconds=0, progress=False, "
        f"**{TINY!r})\n"
    )
    process = subprocess.Popen([sys.executable, "-c", script], env=environment(tmp_path),
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    checkpoint = out / "checkpoints" / "last.pt"
    deadline = time.monotonic() + TIMEOUT
    while not checkpoint.exists():
        assert process.poll() is None, process.stderr.read().decode()[-2000:]
        assert time.monotonic() < deadline, "no checkpoint was written"
        time.sleep(0.02)
    time.sleep(0.2)  # a few more steps: the kill lands mid-epoch, maybe mid-write
    process.send_signal(signal.SIGKILL)
    process.wait()
    assert process.returncode == -signal.SIGKILL, "training ended before it could be killed"
    assert not (out / "metrics.json").exists()

    final = pointfield.classify.train(out=out, resume=True, progress=False)
    epochs = [json.loads(line)["epoch"] for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert epochs == [1, 2] and final["epochs"] == 2
    assert json.loads((out / "metrics.json").read_text())["epochs"] == 2
    assert not list(out.rglob(".*.tmp*"))  # what a write cut short left behind is cleared


def test_two_cpu_processes_train_one_model_with_ddp(tmp_path):
    launcher = Path(sys.executable).with_name("pointfield")
    if not launcher.exists():
        pytest.skip(f"the pointfield command is not installed next to {sys.executable}")
    out = tmp_path / "ddp"
    command = [
        sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2",
        "--no-python", str(launcher), "classify", "train", "--out", str(out),
        "--shapes-per-class", "4", "--points", "64", "--epochs", "2", "--batch-size", "4",
        "--device", "cpu", "--no-progress", "--no-input-transform", "--no-feature-transform",
    ]
    result = subprocess.run(command, env=environment(tmp_path), capture_output=True, text=True,
                            timeout=TIMEOUT, check=False)
    assert result.returncode == 0, result.stderr[-3000:]
    config = json.loads((out / "config.json").read_text())
    assert config["world_size"] == 2
    records = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    # 40 training shapes split over 2 processes in batches of 4: 5 steps per epoch.
    assert [r["epoch"] for r in records] == [1, 2] and [r["step"] for r in records] == [5, 10]
    assert result.stdout.count("classify run") == 1  # only rank 0 reports
    assert (out / "metrics.json").is_file() and (out / "confusion_matrix.png").is_file()


def test_a_process_that_joined_no_group_is_not_ended_by_exit_joined():
    from pointfield.training.distributed import exit_joined

    assert exit_joined(3) == 3  # the command line's code, returned to sys.exit as usual
