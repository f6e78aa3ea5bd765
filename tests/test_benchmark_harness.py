"""The benchmark harness and the RESULTS.md generator (benchmarks/harness.py, benchmarks/report.py)."""

import importlib.util
import json
import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def _load(name):
    """Import a benchmarks/ module by path (benchmarks/ is not a package); report.py imports harness by name."""
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, BENCHMARKS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


harness = _load("harness")
report = _load("report")


def _fake_record():
    return {
        "benchmark": "march", "title": "Ray marching", "issue": "6", "about": "What is measured.",
        "command": "OMP_NUM_THREADS=1 python benchmarks/bench_march.py --repeats 3",
        "environment": {"commit": "0123456789abcdef", "dirty": True, "changed_files": ["src/x.py"],
                        "date": "2026-11-23T20:00:00+00:00", "torch": "2.13.0", "torch_threads": 1,
                        "cpu_count": 2, "cpu": "AMD EPYC", "load_before": [1.5, 1, 1], "load_after": [2.25, 1, 1],
                        "device": "cpu"},
        "figures": {"eager": 0.05},
        "tables": [{"title": "marches", "columns": ["backend", "median ms"], "rows": [["eager", "54.5"], ["compiled", "24.0"]]}],
        "verdicts": [{"claim": "compiled is faster", "ok": True, "detail": "2.27x"},
                     {"claim": "something else", "ok": False, "detail": ""}],
        "compiled": {"the ray marcher's occupancy test": False},
        "notes": ["A caveat."],
    }


def test_a_record_renders_as_a_section_headed_by_its_command(tmp_path):
    (tmp_path / "march.json").write_text(json.dumps(_fake_record()))
    text = report.render(report.read_records(tmp_path), previous=None)
    section = text[text.index("## Ray marching — issue 6"):]
    assert section.splitlines()[2] == "`OMP_NUM_THREADS=1 python benchmarks/bench_march.py --repeats 3`"
    assert "commit `0123456789` with uncommitted changes to `src/x.py`" in section
    assert "load average 1.50 before, 2.25 after" in section
    assert "| compiled | 24.0 |" in section
    assert "ok   compiled is faster (2.27x)\nMISS something else" in section
    assert "not compiled, these figures are eager ones" in section and "A caveat." in section


def test_previous_runs_follow_under_their_own_heading(tmp_path):
    text = report.render([], previous="Run C: 32.06 dB.")
    assert text.rstrip().endswith(report.PREVIOUS_HEADING + "\n\nRun C: 32.06 dB.")


def test_records_come_in_the_order_of_the_issues_and_other_json_is_skipped(tmp_path):
    for name in ("splat", "formats", "zeta"):
        (tmp_path / f"{name}.json").write_text(json.dumps({**_fake_record(), "benchmark": name}))
    (tmp_path / "pointnet-details.json").write_text(json.dumps({"results": []}))
    assert [r["benchmark"] for r in report.read_records(tmp_path)] == ["formats", "splat", "zeta"]


def test_interleaved_alternates_the_order_of_the_contenders():
    calls = []
    timings = harness.interleaved({"ours": lambda: calls.append("ours"), "peer": lambda: calls.append("peer")},
                                  repeats=3, warmup=0)
    assert calls == ["ours", "peer", "peer", "ours", "ours", "peer"]
    assert len(timings["ours"].seconds) == 3 and timings["peer"].median >= 0


def test_a_timing_reports_its_median_and_spread():
    timing = harness.Timing((1.0, 2.0, 4.0))
    assert timing.median == 2.0 and timing.spread == pytest.approx(1.5)


def test_training_curve_excludes_evaluation_time():
    records = [
        {"step": 50, "seconds": 12.0, "evaluation_seconds": 2.0, "psnr": 21.0},
        {"step": 100, "seconds": 25.0, "evaluation_seconds": 3.0, "psnr": 26.0},
    ]
    final = {"steps": 120, "seconds": 30.0, "psnr": 27.0}
    curve = harness.training_curve(records, final)
    assert [p["training_seconds"] for p in curve] == [10.0, 20.0, 25.0]
    assert harness.time_to(curve, 25)["step"] == 100 and harness.time_to(curve, 30) is None


def test_training_curve_prefers_the_loops_training_seconds():
    records = [{"step": 50, "seconds": 12.0, "evaluation_seconds": 2.0, "training_seconds": 9.5, "psnr": 21.0}]
    assert harness.training_curve(records)[0]["training_seconds"] == 9.5


def test_a_record_is_written_with_its_conditions(tmp_path, monkeypatch):
    monkeypatch.setattr(sys, "argv", [str(BENCHMARKS / "bench_march.py"), "--repeats", "3"])
    for name in harness.ENVIRONMENT_VARIABLES:  # whatever the test process inherited (dask's nannies set some)
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    record = harness.Record("march", "Ray marching")
    record.table(["backend", "ms"], [["eager", "54.5"]])
    record.verdict("compiled is faster", True)
    assert record.finish(tmp_path) == 0
    written = json.loads((tmp_path / "march.json").read_text())
    assert written["command"] == "OMP_NUM_THREADS=1 python benchmarks/bench_march.py --repeats 3"
    environment = written["environment"]
    assert {"commit", "dirty", "torch_threads", "cpu_count", "load_before", "load_after", "date", "device"} <= set(environment)


def test_a_kernel_that_ran_eagerly_is_recorded_and_fails_the_run(tmp_path):
    import torch

    from pointfield.compiling import CompiledOrEager

    kernel = CompiledOrEager(lambda x: x + 1, "a test kernel")
    kernel("eager", torch.device("cpu"), torch.zeros(1))
    record = harness.Record("kernel", "A kernel")
    assert not record.require_compiled(kernel)
    assert record.finish(tmp_path) == 1
    assert json.loads((tmp_path / "kernel.json").read_text())["compiled"] == {"a test kernel": False}
