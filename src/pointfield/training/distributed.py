"""Several processes, one model: PyTorch DistributedDataParallel as torchrun launches it.

``torchrun --nproc_per_node=K --no-python pointfield classify train ...`` starts K copies of
the command with ``RANK``, ``LOCAL_RANK`` and ``WORLD_SIZE`` in their environment.
:func:`setup` reads them, joins the process group (``nccl`` between GPUs, ``gloo`` on CPU),
and gives each process its device; without them it is a no-op and training runs as one
process. Each process then trains on its own share of every epoch (``DistributedSampler``),
gradients are averaged across processes after every backward pass, and only rank 0 writes
files.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from datetime import timedelta

import torch
import torch.distributed as dist
from torch import nn

from pointfield.devices import pick_device
from pointfield.errors import PointfieldError

TIMEOUT = timedelta(minutes=30)
_joined = False  # set by setup once this process has joined a group: see exit_joined


@dataclass(frozen=True)
class Distributed:
    """This process's place among ``world_size`` processes."""

    rank: int
    world_size: int
    local_rank: int

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    def all_reduce_sum(self, tensor: torch.Tensor) -> torch.Tensor:
        """Sum ``tensor`` over all processes, in place, and return it."""
        dist.all_reduce(tensor, op=dist.ReduceOp.SUM)
        return tensor

    def all_true(self, flag: bool, device: torch.device) -> bool:
        """True when ``flag`` is True in every process (so all can stop together)."""
        value = torch.tensor([1.0 if flag else 0.0], device=device)
        dist.all_reduce(value, op=dist.ReduceOp.MIN)
        return bool(value.item() == 1.0)

    def barrier(self) -> None:
        dist.barrier()

    def broadcast_buffers(self, model: nn.Module) -> None:
        """Give every process rank 0's buffers (BatchNorm running statistics), in place.

        DDP averages gradients, so parameters agree across processes; buffers are updated by
        each process's own batches and drift apart after the last step. Evaluating -- or
        saving -- without this would score a different model on every rank.
        """
        for buffer in model.buffers():
            dist.broadcast(buffer, src=0)


def launched_by_torchrun() -> bool:
    return int(os.environ.get("WORLD_SIZE", "1")) > 1


def setup(device_name: str | None = None) -> tuple[Distributed | None, torch.device]:
    """Join the process group if torchrun started several processes; pick this one's device.

    Returns ``(None, device)`` for a single process. With CUDA, process ``LOCAL_RANK`` uses
    GPU ``LOCAL_RANK``.
    """
    device = pick_device(device_name)
    if not launched_by_torchrun():
        return None, device
    try:
        rank = int(os.environ["RANK"])
        world_size = int(os.environ["WORLD_SIZE"])
        local_rank = int(os.environ.get("LOCAL_RANK", rank))
    except (KeyError, ValueError) as error:
        raise PointfieldError(f"incomplete torchrun environment: {error}") from None
    if device.type == "cuda":
        device = torch.device("cuda", local_rank)
        torch.cuda.set_device(device)
    elif device.type == "mps":
        raise PointfieldError("several processes on MPS are not supported; use --device cpu")
    if not dist.is_initialized():
        backend = "nccl" if device.type == "cuda" else "gloo"
        dist.init_process_group(backend, timeout=TIMEOUT)
    global _joined
    _joined = True
    return Distributed(rank, world_size, local_rank), device


def shutdown() -> None:
    """Leave the process group (a no-op without one).

    Its gloo worker threads outlive it: DistributedDataParallel keeps the group alive in C++
    (torch 2.13), and even with the wrapper collected, two ``pt_gloo_runloop`` threads are still
    running after ``destroy_process_group`` (counted in ``/proc/self/task``). Left to the
    interpreter's exit, a worker that drops the last reference to a finished all-reduce then
    frees tensors that belong to Python objects, needs the GIL while the interpreter is shutting
    down, and aborts the process ("terminate called without an active exception"; one run in
    about fifteen here, and still now and then with the barrier below; a plain DDP script on
    torch alone keeps the threads too, and torch's own fix, an atexit handler, was abandoned:
    pytorch/pytorch#179291, #190489). So
    :func:`~pointfield.training.lifecycle.train` ends with a barrier: gloo's barrier waits for
    the work in flight, and the slower rank's last writes give the workers time to let go; and
    the command line ends a process that joined a group with :func:`exit_joined`, which skips
    that shutdown altogether.
    """
    if dist.is_available() and dist.is_initialized():
        dist.destroy_process_group()


def exit_joined(code: int) -> int:
    """End this process at once with ``code`` if it joined a process group; else return ``code``.

    ``os._exit`` skips the interpreter's shutdown, where gloo's surviving worker threads can
    abort the process (:func:`shutdown`). Nothing is lost by skipping it: every file a run
    writes is written atomically and closed before training returns, and the standard streams
    are flushed here.
    """
    if not _joined:
        return code
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def wrap(model: nn.Module, distributed: Distributed | None, device: torch.device) -> nn.Module:
    """The model wrapped for DDP when several processes train it (else the model itself)."""
    if distributed is None:
        return model
    device_ids = [device.index] if device.type == "cuda" else None
    return nn.parallel.DistributedDataParallel(model, device_ids=device_ids)


def shard(count: int, distributed: Distributed | None) -> list[int]:
    """This process's share of ``count`` items for evaluation: every world_size-th, no padding.

    Unlike ``DistributedSampler`` nothing is repeated, so summed counts are exact.
    """
    if distributed is None:
        return list(range(count))
    return list(range(distributed.rank, count, distributed.world_size))
