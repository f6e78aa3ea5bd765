"""What every benchmark shares: peer timing, the compiled-path check, time to PSNR, and its record.

A benchmark builds a :class:`Record`, measures, adds tables and verdicts to it (each printed as
it is added), and ends with :meth:`Record.finish`, which writes ``benchmarks/records/<name>.json``
with the figures and the conditions they were measured under (commit, uncommitted changes,
threads, CPUs, load before and after, date, device). ``benchmarks/report.py`` turns those
records into ``benchmarks/RESULTS.md``, each section headed by the command that printed it::

    record = Record("march", "Ray marching through an occupancy grid", issue="6")
    timings = interleaved({"compiled": march_compiled, "eager": march_eager}, repeats=15)
    record.require_compiled(_FUSED_OCCUPIED_CANDIDATES)
    record.table(["backend", "median ms", "spread"], [...])
    record.verdict("the compiled march is faster than eager", ok, "1.9x")
    sys.exit(record.finish())

Time to a PSNR has one definition for every model (:func:`training_curve`): seconds of
training, evaluations excluded; one-time start-up is reported beside it, never inside it.
"""

from __future__ import annotations

import datetime
import json
import os
import platform
import shlex
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from pointfield.atomic import atomic_path
from pointfield.compiling import CompiledOrEager

ROOT = Path(__file__).resolve().parents[1]
OUTPUT = Path(__file__).resolve().parent / "records"  # committed, so RESULTS.md can be regenerated anywhere
ENVIRONMENT_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "CUDA_VISIBLE_DEVICES")
"""Variables that change what a benchmark measures; when set they are part of its command."""


# -- timing a peer -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class Timing:
    """Seconds of repeated calls of one contender: their median and spread."""

    seconds: tuple[float, ...]

    @property
    def median(self) -> float:
        return statistics.median(self.seconds)

    @property
    def spread(self) -> float:
        """``(slowest - fastest) / median``: how far to trust the median on a noisy machine."""
        return (max(self.seconds) - min(self.seconds)) / self.median

    def as_dict(self) -> dict[str, Any]:
        return {"median_seconds": self.median, "min_seconds": min(self.seconds),
                "max_seconds": max(self.seconds), "spread": self.spread, "repeats": len(self.seconds)}


def round_order(names: Sequence[str], round_: int) -> list[str]:
    """The order contenders run in round ``round_`` of an interleaved measurement: as given in even
    rounds, reversed in odd ones (A B, B A, A B, ...; see :func:`interleaved`)."""
    return list(names) if round_ % 2 == 0 else list(reversed(names))


def interleaved(contenders: dict[str, Callable[[], Any]], repeats: int, warmup: int = 1,
                synchronize: Callable[[], None] | None = None,
                clock: Callable[[], float] = time.perf_counter) -> dict[str, Timing]:
    """Time each contender ``repeats`` times, alternating them, after ``warmup`` untimed rounds.

    Round r runs the contenders in order, round r + 1 in reverse (A B, B A, A B, ...), so that a
    machine slowing down or speeding up -- other jobs, thermal limits -- hits all of them alike
    and none always runs first after the other's caches. ``synchronize`` (e.g.
    ``torch.cuda.synchronize``) is called before each clock reading where work is asynchronous;
    ``clock`` is wall time unless said (``time.process_time`` for CPU time).
    """
    if repeats < 1:
        raise ValueError(f"repeats must be at least 1, got {repeats}")
    wait = synchronize or (lambda: None)
    names = list(contenders)
    for _ in range(warmup):
        for name in names:
            contenders[name]()
    samples: dict[str, list[float]] = {name: [] for name in names}
    for round_ in range(repeats):
        for name in round_order(names, round_):
            wait()
            started = clock()
            contenders[name]()
            wait()
            samples[name].append(clock() - started)
    return {name: Timing(tuple(times)) for name, times in samples.items()}


# -- time to a PSNR ----------------------------------------------------------------------------------


def training_seconds(record: dict[str, Any], evaluation_so_far: float) -> float:
    """Training seconds at ``record`` of a run's metrics.jsonl (or its metrics.json), evaluations excluded.

    The loop writes ``training_seconds``; records written before it did are read as their
    ``seconds`` (the run's clock) minus ``evaluation_so_far``, the ``evaluation_seconds`` of
    this and every earlier record.
    """
    if "training_seconds" in record:
        return float(record["training_seconds"])
    return float(record["seconds"]) - evaluation_so_far


def training_curve(records: Iterable[dict[str, Any]], final: dict[str, Any] | None = None) -> list[dict[str, Any]]:
    """``[{"step", "training_seconds", "psnr"}]``, one point per held-out evaluation of a run.

    ``records``: the run's metrics.jsonl (:meth:`pointfield.training.RunDirectory.read_metrics_log`);
    ``final``: its metrics.json, the evaluation on all held-out views after the last step, a
    point of the curve too when training stopped between two evaluations (at a time limit).
    """
    curve, evaluating = [], 0.0
    for record in records:
        evaluating += float(record.get("evaluation_seconds", 0.0))
        if "psnr" in record:
            curve.append({"step": record["step"], "training_seconds": round(training_seconds(record, evaluating), 2),
                          "psnr": round(float(record["psnr"]), 3)})
    if final is not None and (not curve or final["steps"] > curve[-1]["step"]):
        curve.append({"step": final["steps"], "training_seconds": round(training_seconds(final, evaluating), 2),
                      "psnr": round(float(final["psnr"]), 3)})
    return curve


def time_to(curve: list[dict[str, Any]], psnr: float) -> dict[str, Any] | None:
    """The first point of ``curve`` at or above ``psnr`` dB, or None."""
    return next((point for point in curve if point["psnr"] >= psnr), None)


# -- the record ----------------------------------------------------------------------------------------


@dataclass
class Record:
    """One benchmark run: its command, conditions, tables and verdicts; written by :meth:`finish`.

    ``name`` names the file (``benchmarks/records/<name>.json``) and the section of RESULTS.md;
    ``title`` heads the section; ``issue`` is the tracker issue whose claims it checks; ``about``
    is a paragraph saying what is measured and against which peer.
    """

    name: str
    title: str
    issue: str | None = None
    about: str = ""
    device: str = "cpu"
    command: str = field(default_factory=lambda: command_line(sys.argv))
    environment: dict[str, Any] = field(default_factory=lambda: environment_before())
    figures: dict[str, Any] = field(default_factory=dict)
    tables: list[dict[str, Any]] = field(default_factory=list)
    verdicts: list[dict[str, Any]] = field(default_factory=list)
    compiled: dict[str, bool] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def table(self, columns: list[str], rows: list[list[Any]], title: str | None = None) -> None:
        """Print a table and keep it, its cells exactly as printed (format numbers before)."""
        cells = [[str(cell) for cell in row] for row in rows]
        entry = {"title": title, "columns": list(columns), "rows": cells}
        self.tables.append(entry)
        print(("\n" + title + "\n" if title else "\n") + format_table(entry), flush=True)

    def verdict(self, claim: str, ok: bool, detail: str = "") -> None:
        """Record whether a claim of the issue holds in this run; printed as ``ok``/``MISS`` lines."""
        self.verdicts.append({"claim": claim, "ok": bool(ok), "detail": detail})
        print(format_verdict(self.verdicts[-1]), flush=True)

    def note(self, text: str) -> None:
        """A sentence printed and kept with the figures (a caveat of this run, a definition)."""
        self.notes.append(text)
        print(text, flush=True)

    def require_compiled(self, *kernels: CompiledOrEager) -> bool:
        """Check that each kernel ran compiled in this process; record ``compiled`` per kernel.

        Call it after the timed runs of the compiled path. A kernel that fell back to eager (its
        compiler failed) or never compiled (no compiler here) is recorded ``False`` with a
        loud message, and :meth:`finish` then returns 1: a "compiled" figure measured on the
        eager path would be a lie.
        """
        for kernel in kernels:
            # CompiledOrEager keeps its compiled callable once torch.compile has produced it and
            # sets ``failed`` when a call of it raised; between them they say what really ran.
            ran_compiled = kernel.ran_compiled
            # Kernels may share a name ("the splat binning" is two): the name holds if all of them ran compiled.
            self.compiled[kernel.what] = self.compiled.get(kernel.what, True) and ran_compiled
            if not ran_compiled:
                reason = "fell back to eager" if kernel.failed else "was never compiled"
                print(f"COMPILED PATH NOT COMPILED: {kernel.what} {reason}; its figures are eager ones",
                      file=sys.stderr, flush=True)
        return all(self.compiled.values())

    def as_dict(self) -> dict[str, Any]:
        return {"benchmark": self.name, "title": self.title, "issue": self.issue, "about": self.about,
                "command": self.command, "environment": {**self.environment, "device": self.device},
                "figures": self.figures, "tables": self.tables, "verdicts": self.verdicts,
                "compiled": self.compiled or None, "notes": self.notes}

    def finish(self, output: Path = OUTPUT) -> int:
        """Note the load after the run, write ``output/<name>.json``; 1 if a compiled path was not compiled."""
        self.environment.update(environment_after())
        output.mkdir(parents=True, exist_ok=True)
        path = output / f"{self.name}.json"
        with atomic_path(path) as temporary:
            temporary.write_text(json.dumps(self.as_dict(), indent=2, default=_plain) + "\n")
        load = self.environment
        print(f"\nwrote {path} (commit {load['commit'][:10]}{' + uncommitted changes' if load['dirty'] else ''}, "
              f"load {load['load_before'][0]:.2f} -> {load['load_after'][0]:.2f})", flush=True)
        return 0 if all(self.compiled.values()) else 1


def command_line(argv: list[str]) -> str:
    """The command that reproduces this run: the variables that matter, the script, its arguments."""
    script = Path(argv[0]).resolve()
    shown = script.relative_to(ROOT) if script.is_relative_to(ROOT) else script
    variables = [f"{name}={os.environ[name]}" for name in ENVIRONMENT_VARIABLES if name in os.environ]
    return shlex.join([*variables, "python", str(shown), *argv[1:]])


def environment_before() -> dict[str, Any]:
    """The conditions at the start: code version, threads, CPUs, load, date."""
    commit, changed = _git("rev-parse", "HEAD"), _git("status", "--porcelain", "--untracked-files=no")
    # Other benchmarks' fresh records and the report made from them are output, not code.
    changed_files = [line[3:] for line in (changed or "").splitlines()
                     if not line[3:].startswith(("benchmarks/records/", "benchmarks/RESULTS.md"))]
    return {
        "commit": (commit or "unknown").strip(),
        "dirty": bool(changed_files),
        "changed_files": changed_files,
        "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
        "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "cpu_count": os.cpu_count(),
        "cpu": _cpu_model(),
        "python": platform.python_version(),
        "load_before": list(os.getloadavg()),
    }


def environment_after() -> dict[str, Any]:
    """Load and threads at the end (a benchmark may have set the thread count itself)."""
    return {"load_after": list(os.getloadavg()), "torch_threads": torch.get_num_threads()}


def device_name(device: torch.device) -> str:
    """``"cpu"``, or ``"cuda (NVIDIA H100 ...)"``: what to put in :attr:`Record.device`."""
    if device.type == "cuda":
        return f"cuda ({torch.cuda.get_device_name(device)})"
    return device.type


def format_table(table: dict[str, Any]) -> str:
    """The table as fixed-width text: first column left-aligned, the others right-aligned."""
    columns, rows = table["columns"], table["rows"]
    widths = [max(len(str(cell)) for cell in column) for column in zip(columns, *rows)]

    def line(cells):
        return "  ".join(cell.ljust(width) if i == 0 else cell.rjust(width)
                         for i, (cell, width) in enumerate(zip(cells, widths))).rstrip()

    return "\n".join([line(columns), *(line(row) for row in rows)])


def format_verdict(verdict: dict[str, Any]) -> str:
    detail = f" ({verdict['detail']})" if verdict["detail"] else ""
    return f"{'ok  ' if verdict['ok'] else 'MISS'} {verdict['claim']}{detail}"


def _git(*arguments: str) -> str | None:
    try:
        completed = subprocess.run(["git", *arguments], cwd=ROOT, capture_output=True, text=True, check=True)
    except (OSError, subprocess.CalledProcessError):
        return None
    return completed.stdout


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as info:
            for line in info:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def _plain(value: Any) -> Any:
    """JSON for numpy and torch scalars a benchmark left in its figures."""
    if hasattr(value, "item"):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"{type(value).__name__} is not JSON")
