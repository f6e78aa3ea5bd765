"""Threads on a busy machine: how OpenMP's waiting policy decides a CPU training's speed.

torch's CPU wheels run their parallel operations on GNU OpenMP (libgomp). By default a libgomp
thread that reaches the end of a parallel operation spins up to 300,000 times before it sleeps,
waiting for the others. When another program keeps a core busy, one of the training's threads is
often descheduled, and the others spin through its time slice at every operation: a splat step that
takes a fraction of a second on a quiet machine takes many times longer. With
``OMP_WAIT_POLICY=PASSIVE`` a waiting thread sleeps at once and gives its core back, but on a quiet
machine every wake-up then costs; ``GOMP_SPINCOUNT`` sets the spin in between.

pointfield sets ``GOMP_SPINCOUNT=10000`` when it is imported, unless ``OMP_WAIT_POLICY`` or
``GOMP_SPINCOUNT`` is already set (``pointfield/__init__.py``); it takes effect where pointfield is
imported before torch, as the ``pointfield`` command does. This benchmark is the evidence for that
default. It times a splat training step (``pointfield.splats.train.train`` on the synthetic cube,
``--size`` pixels, ``training_seconds / steps`` over ``--steps`` steps after two warm-up steps in the
same process, so that compiling is outside the figure) in a fresh process for each condition:

- the waiting policy: libgomp's default (torch imported before pointfield, the variables unset),
  pointfield's shorter spin (``GOMP_SPINCOUNT=10000``), and ``PASSIVE``;
- the threads: one per core, and the default at one thread (the advice docs/runs.md gave before);
- the machine: as it is, and with one competing busy process (a Python loop that never sleeps,
  as a second training, a build or a browser tab would).

Conditions run interleaved, ``--rounds`` times; a worker that runs past ``--timeout`` seconds is
stopped and reported as such. The claims, for pointfield's spin at one thread per core: under a
competing process, at least twice as fast as libgomp's default; on the machine as it is, at most
10 % slower. Run on an otherwise quiet machine (the "as it is" rows are then the quiet machine).
Other spins, measured once beside the record (one round, 2 quiet cores, 160 px; seconds a step
quiet / with a busy process): 1,000 0.288 / 0.375; 3,000 0.206 / 0.469; 10,000 0.188 / 0.754;
30,000 0.180 / 1.539; PASSIVE 0.378 / 0.288; the default 0.178 quiet.

Run: ``make bench-threads`` (= ``python benchmarks/bench_threads.py``); the record goes to
``benchmarks/records/threads.json``."""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

POLICIES = {
    "libgomp default": {},
    "GOMP_SPINCOUNT=10000": {"GOMP_SPINCOUNT": "10000"},
    "OMP_WAIT_POLICY=PASSIVE": {"OMP_WAIT_POLICY": "PASSIVE"},
}
"""Waiting policy -> the variables the worker process starts with (every other OpenMP variable unset)."""
POINTFIELD = "GOMP_SPINCOUNT=10000"
"""The policy ``import pointfield`` sets."""
SOURCE = Path(__file__).resolve().parents[1] / "src"


def worker(size: int, steps: int) -> None:
    """Run in a fresh process: print the median seconds of a splat training step, as JSON."""
    import torch  # before pointfield: an unset OMP_WAIT_POLICY stays unset for libgomp

    from pointfield.splats.train import train

    with tempfile.TemporaryDirectory() as folder:
        scene = {"cube_views": 8, "cube_size": size, "device": "cpu", "progress": False, "seed": 0,
                 "eval_every": 10_000, "eval_views": 1}
        train(None, out=Path(folder) / "warm", steps=2, **scene)  # compiles the kernels of this process
        metrics = train(None, out=Path(folder) / "timed", steps=steps, **scene)
    print(json.dumps({"seconds_per_step": metrics["training_seconds"] / metrics["steps"],
                      "threads": torch.get_num_threads()}))


def run_worker(policy: str, threads: int, args) -> float | None:
    """Seconds per step of one worker process, or None when it ran past ``args.timeout``."""
    environment = {name: value for name, value in os.environ.items()
                   if not name.startswith(("OMP_", "GOMP_", "KMP_"))}
    environment.update(POLICIES[policy], OMP_NUM_THREADS=str(threads),
                       PYTHONPATH=os.pathsep.join(filter(None, [str(SOURCE), os.environ.get("PYTHONPATH")])))
    command = [sys.executable, __file__, "--worker", "--size", str(args.size), "--steps", str(args.steps)]
    try:
        done = subprocess.run(command, env=environment, capture_output=True, text=True, timeout=args.timeout,
                              check=True)
    except subprocess.TimeoutExpired:
        return None
    return json.loads(done.stdout.strip().splitlines()[-1])["seconds_per_step"]


def busy_process() -> subprocess.Popen:
    """A process that keeps one core busy until it is stopped."""
    return subprocess.Popen([sys.executable, "-c", "while True: pass"])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=160, help="the cube's views, pixels a side (default 160)")
    parser.add_argument("--steps", type=int, default=8, help="timed steps per worker (default 8)")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--timeout", type=float, default=180, help="seconds before a worker is stopped")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker(args.size, args.steps)
        return 0

    from harness import Record

    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    record = Record(
        "threads", "Threads on a busy machine: OpenMP's waiting policy and a CPU training's speed", issue="43",
        about=f"Seconds per splat training step (the synthetic cube at {args.size} x {args.size}, median of "
              f"`training_seconds / steps` over {args.rounds} interleaved rounds of {args.steps} steps each after "
              "two warm-up steps) in a fresh process per condition: libgomp's default waiting policy (torch imported "
              "first, the variables unset), a shorter spin (`GOMP_SPINCOUNT=10000`, what `import pointfield` sets) "
              "and `OMP_WAIT_POLICY=PASSIVE`, at one thread per core, and the default at one thread, on the "
              "machine as it is and with one competing busy process (a Python loop that never sleeps).")
    conditions = [(policy, cores) for policy in POLICIES] + [("libgomp default", 1)]
    seconds: dict[tuple[str, int, int], list[float | None]] = {}
    for round_ in range(args.rounds):
        for competitors in (0, 1):
            busy = [busy_process() for _ in range(competitors)]
            try:
                order = conditions if round_ % 2 == 0 else conditions[::-1]
                for policy, threads in order:
                    started = time.perf_counter()
                    value = run_worker(policy, threads, args)
                    seconds.setdefault((policy, threads, competitors), []).append(value)
                    shown = f"{value:.3f} s/step" if value is not None else f"stopped after {args.timeout:.0f} s"
                    print(f"round {round_ + 1}, {competitors} busy, {policy}, {threads} thread(s): {shown} "
                          f"({time.perf_counter() - started:.0f} s)", flush=True)
            finally:
                for process in busy:
                    process.kill()
                    process.wait()

    def median(key) -> float | None:
        values = seconds[key]
        return None if any(v is None for v in values) else statistics.median(values)

    def shown(value: float | None) -> str:
        return f"{value:.3f}" if value is not None else f"stopped after {args.timeout:.0f} s"

    rows = []
    for policy, threads in conditions:
        quiet, busy = median((policy, threads, 0)), median((policy, threads, 1))
        slowdown = f"{busy / quiet:.1f}x" if quiet and busy else "-"
        rows.append([policy, threads, shown(quiet), shown(busy), slowdown])
    record.table(["waiting policy", "threads", "s/step, machine as it is", "s/step, one busy process",
                  "slowed by the busy process"], rows)
    record.figures["seconds_per_step"] = {f"{policy} | {threads} | {competitors}": values
                                          for (policy, threads, competitors), values in seconds.items()}
    default_busy, chosen_busy = median(("libgomp default", cores, 1)), median((POINTFIELD, cores, 1))
    default_quiet, chosen_quiet = median(("libgomp default", cores, 0)), median((POINTFIELD, cores, 0))
    claim = f"with a busy process, pointfield's {POINTFIELD} is at least 2x as fast as libgomp's default"
    if chosen_busy is None:
        record.verdict(claim, False, f"{POINTFIELD} ran past the timeout")
    elif default_busy is None:
        record.verdict(claim, True, f"the default's worker ran past {args.timeout:.0f} s; "
                                    f"{POINTFIELD}'s took {chosen_busy:.3f} s a step")
    else:
        record.verdict(claim, default_busy / chosen_busy >= 2, f"{default_busy / chosen_busy:.1f}x at {cores} threads")
    if default_quiet and chosen_quiet:
        cost = chosen_quiet / default_quiet - 1
        record.verdict(f"on the machine as it is, {POINTFIELD} costs at most 10 %", cost <= 0.10,
                       f"{chosen_quiet:.3f} against {default_quiet:.3f} s/step ({cost:+.0%})")
    return record.finish()


if __name__ == "__main__":
    sys.exit(main())
