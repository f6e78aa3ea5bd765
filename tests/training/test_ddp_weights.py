"""Two CPU processes training one classifier with DDP hold the same weights after their steps.

torchrun starts two processes (gloo backend) that each call ``pointfield.clouds.tasks.train``.
Each records, through torch's global hooks and nothing of pointfield's, the first batch its
model is given, every parameter after its first and its last optimizer step, and the model's
state at the start of each evaluation; the test then compares the two processes' records.
Identical weights mean something only if the processes trained on different data, so that is
checked too, as is that the weights moved at all.
"""

from __future__ import annotations

import subprocess
import sys

import pytest
import torch

TIMEOUT = 240
TINY = dict(shapes_per_class=4, points=64, epochs=2, batch_size=4, input_transform=False,
            feature_transform=False)

WORKER = """
import os, sys
import torch
from torch.nn.modules.module import register_module_forward_hook, register_module_forward_pre_hook
from torch.optim.optimizer import register_optimizer_step_post_hook
import pointfield.clouds.tasks as tasks
from pointfield.training.distributed import exit_joined

out, record = sys.argv[1], sys.argv[2]
first_batch, after_first_step, after_last_step, evaluations = [], [], [], []
depth, steps, evaluated_after = [0], [0], [-1]

def before_forward(module, args):
    if depth[0] == 0:  # the model itself (or its DDP wrapper), not one of its layers
        if module.training and not first_batch and args and isinstance(args[0], torch.Tensor):
            first_batch.append(args[0].detach().clone())
        if not module.training and evaluated_after[0] != steps[0]:  # an evaluation begins
            evaluated_after[0] = steps[0]
            evaluations.append({k: v.detach().clone() for k, v in module.state_dict().items()})
    depth[0] += 1

def after_forward(module, args, output):
    depth[0] -= 1

def after_step(optimizer, args, kwargs):
    steps[0] += 1
    parameters = [p.detach().clone() for group in optimizer.param_groups for p in group["params"]]
    if not after_first_step:
        after_first_step.extend(parameters)
    after_last_step[:] = parameters

register_module_forward_pre_hook(before_forward)
register_module_forward_hook(after_forward)
register_optimizer_step_post_hook(after_step)
tasks.train("classify", out=out, device="cpu", progress=False, checkpoint_seconds=None, **TINY)
torch.save({"first_batch": first_batch[0], "after_first_step": after_first_step,
            "after_last_step": after_last_step, "evaluations": evaluations},
           record.format(rank=os.environ["RANK"]))
exit_joined(0)  # as the command line ends: see pointfield.training.distributed.shutdown
"""


@pytest.fixture(scope="module")
def ranks(tmp_path_factory, checkout_environment) -> list[dict]:
    """What each of the two processes recorded, rank 0 first."""
    folder = tmp_path_factory.mktemp("ddp-weights")
    worker = folder / "worker.py"
    worker.write_text(f"TINY = {TINY!r}\n{WORKER}")
    environment = {
        **checkout_environment,
        "POINTFIELD_CACHE": str(folder / "cache"),
        "OMP_NUM_THREADS": "1",  # one thread per process: the test machine's cores are shared
    }
    command = [
        sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2",
        str(worker), str(folder / "run"), str(folder / "rank{rank}.pt"),
    ]
    result = subprocess.run(command, env=environment, capture_output=True, text=True,
                            timeout=TIMEOUT, check=False)
    assert result.returncode == 0, result.stderr[-3000:]
    return [torch.load(folder / f"rank{rank}.pt", weights_only=True) for rank in (0, 1)]


def test_the_two_processes_train_on_different_batches(ranks):
    assert not torch.equal(ranks[0]["first_batch"], ranks[1]["first_batch"])


@pytest.mark.parametrize("when", ["after_first_step", "after_last_step"])
def test_every_parameter_is_identical_in_both_processes(ranks, when):
    zero, one = ranks[0][when], ranks[1][when]
    assert len(zero) == len(one) > 0
    different = [i for i, (a, b) in enumerate(zip(zero, one)) if not torch.equal(a, b)]
    largest = max((zero[i] - one[i]).abs().max().item() for i in different) if different else 0
    assert not different, f"parameter tensors {different} differ, by up to {largest}"


def test_training_moved_the_weights(ranks):
    first, last = ranks[0]["after_first_step"], ranks[0]["after_last_step"]
    assert any(not torch.equal(a, b) for a, b in zip(first, last))


def test_both_processes_evaluate_with_the_same_weights_and_batchnorm_statistics(ranks):
    # Each rank updates BatchNorm's running statistics from its own batches; before evaluating,
    # every rank takes rank 0's, so the test score is that of the one model rank 0 saves.
    for zero, one in zip(ranks[0]["evaluations"], ranks[1]["evaluations"]):
        different = [name for name in zero if not torch.equal(zero[name], one[name])]
        assert not different, f"rank 1 evaluates with other values of {different}"
