"""``--max-time`` is the wall clock of the whole command; every run ends with its record; errors use the caller's words.

The commands run through :func:`pointfield.cli.main` in this process, so the interpreter's own
start and torch's import (done by the suite already) are outside what is measured, as the issue
that asked for it says; the clock is the one the command reports (``metrics.json``'s
``wall_seconds``, the closing line's seconds), never the test's own stopwatch.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import time

import pytest
import torch

import pointfield
from pointfield.cli import main
from pointfield.cli.training_options import CPU_DEFAULT_MAX_TIME, training_budget
from pointfield.fields.train import train as train_field
from pointfield.scenes import heldout, synthetic_scene
from pointfield.splats.train import train as train_splats
from pointfield.training import RunDirectory
from pointfield.training.budget import FINAL_SHARE, FINISHING_SECONDS, MEASURED_FINAL_SHARE, TimeBudget

BUDGET = 30
TOLERANCE = 8
"""The issue's: ``--max-time 30`` returns within 38 s (at least one step and one held-out view are
always done, and the last of them may end past the mark)."""
TINY_CUBE = {"cube_views": 12, "cube_size": 12, "device": "cpu", "steps": 1000, "eval_every": 500, "max_time": 1e-3,
             "progress": False}


def strict(text: str):
    """``text`` parsed as strict JSON: NaN, Infinity and -Infinity are refused."""
    def refuse(constant: str):
        raise ValueError(f"not strict JSON: {constant}")

    return json.loads(text, parse_constant=refuse)


@pytest.mark.parametrize("group", ["nerf", "splat"])
def test_max_time_30_on_lego_returns_within_the_budget_with_metrics_and_curves(shared_data, tmp_path, capsys, group):
    out = tmp_path / group
    code = main([group, "train", str(shared_data / "nerf" / "lego_blender"), "--downscale", "8",
                 "--holdout-every", "10", "--max-time", str(BUDGET), "--out", str(out)])
    closing = capsys.readouterr().out.strip().splitlines()[-1]
    assert code == 0
    for name in ("metrics.jsonl", "metrics.json", "training_curves.png"):
        assert (out / name).is_file(), name
    metrics = strict((out / "metrics.json").read_text())
    history = [strict(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert history and pointfield.load_run(out, device="cpu").history == history
    assert history[-1]["step"] == metrics["steps"] >= 1
    assert 1 <= metrics["views"] <= metrics["heldout_views"] == 10
    if metrics["wall_seconds"] > BUDGET + TOLERANCE and metrics["steps"] == metrics["views"] == 1:
        pytest.skip(f"the machine is too busy to measure: start-up took {metrics['startup_seconds']:.0f} s and one "
                    f"step and one view (the least a run does) ended at {metrics['wall_seconds']:.0f} s")
    assert metrics["wall_seconds"] <= BUDGET + TOLERANCE
    reported = float(re.search(r"steps? in (\d+) s\)", closing).group(1))
    assert reported <= BUDGET + TOLERANCE
    assert metrics["training_seconds"] <= metrics["wall_seconds"] - metrics["startup_seconds"]


def test_metrics_files_are_strict_json_with_null_where_a_score_does_not_exist(tmp_path):
    run = RunDirectory(tmp_path)
    run.create(resume=False)
    run.write_final_metrics({"psnr": 21.5, "opacity_error": math.nan, "ssim": math.inf, "per_class": [0.5, -math.inf]})
    run.write_metrics_log([{"epoch": 1, "psnr": math.nan}])
    assert strict(run.final_metrics.read_text()) == {"psnr": 21.5, "opacity_error": None, "ssim": None,
                                                     "per_class": [0.5, None]}
    assert strict(run.metrics_log.read_text()) == {"epoch": 1, "psnr": None}


def test_a_budget_keeps_a_share_for_the_final_evaluation_until_its_cost_is_measured():
    budget = TimeBudget(100.0)
    assert budget.reserve(None) == FINAL_SHARE * 100.0  # not measured yet
    assert budget.reserve(1.0) == 1.0 + FINISHING_SECONDS  # cheap: all of it
    assert budget.reserve(30.0) == 30.0 + FINISHING_SECONDS  # over a fifth: every view is still scored
    assert budget.reserve(500.0) == MEASURED_FINAL_SHARE * 100.0  # dear: fewer views instead
    assert TimeBudget().reserve(500.0) == 0.0 and TimeBudget().left() == math.inf


def test_the_final_evaluation_scores_only_the_views_the_budget_has_room_for(monkeypatch):
    scene = synthetic_scene("cube", views=12, size=12)
    frames = list(range(6))  # any views with images
    clock = [0.0]
    monkeypatch.setattr(heldout.time, "perf_counter", lambda: clock[0])

    def render(cameras):  # two seconds a view
        clock[0] += 2.0
        return [{"rgb": torch.zeros(12, 12, 3), "depth": torch.zeros(12, 12), "opacity": torch.ones(12, 12)}]

    scores, _ = heldout.heldout_scores(render, scene, frames, until=7.0)
    # Views end at 2, 4 and 6 s; a fourth would end at 8 s, past 7.
    assert (scores["views"], scores["heldout_views"]) == (3, len(frames)) and len(frames) > 3
    scores, _ = heldout.heldout_scores(render, scene, frames, until=0.0)
    assert scores["views"] == 1  # always one


@pytest.mark.parametrize("train", [
    lambda out: train_field(out=out, model="tiny", batch_rays=128, model_options={"samples": 8}, **TINY_CUBE),
    lambda out: train_splats(out=out, initial_splats=200, **TINY_CUBE),
], ids=["nerf", "splat"])
def test_a_run_stopped_before_its_first_evaluation_ends_with_its_record_curves_and_scores(train, tmp_path):
    out = tmp_path / "run"
    metrics = train(out)  # max_time runs out at the first step, long before the first evaluation at step 500
    assert metrics["steps"] == 1 and metrics["views"] == 1
    history = pointfield.load_run(out, device="cpu").history
    assert len(history) == 1 and history[0]["partial"] is True and history[0]["step"] == 1
    assert (out / "training_curves.png").is_file()
    assert strict((out / "metrics.json").read_text())["views"] == 1


def test_the_exercise_over_an_old_one_says_out_to_python_and_dash_dash_out_to_the_command_line(tmp_path, capsys):
    from pointfield.exercises.tinynerf import exercise

    (tmp_path / "run").mkdir()
    with pytest.raises(pointfield.PointfieldError, match="choose another out$"):
        exercise(tmp_path)
    assert main(["nerf", "exercise", "--out", str(tmp_path)]) == 1
    assert capsys.readouterr().err.strip().endswith("choose another --out")


def blank_renderer(clock: list[float] | None = None, seconds_at_128: float = 0.0):
    """``(sizes, render)``: a renderer of blank views that appends each view's width to ``sizes`` and,
    given a mocked ``clock``, advances it by ``seconds_at_128`` per 128 x 128 pixels (a render's cost
    in proportion to its pixels)."""
    sizes = []

    def render(cameras):
        width, height = int(cameras.width[0]), int(cameras.height[0])
        sizes.append(width)
        if clock is not None:
            clock[0] += seconds_at_128 * width * height / 128**2
        return [{"rgb": torch.zeros(height, width, 3), "depth": torch.zeros(height, width),
                 "opacity": torch.ones(height, width)}]

    return sizes, render


def test_a_final_evaluation_that_cannot_fit_one_view_scores_smaller_views(monkeypatch):
    scene = synthetic_scene("cube", views=12, size=128)
    clock = [0.0]
    monkeypatch.setattr(heldout.time, "perf_counter", lambda: clock[0])
    sizes, render = blank_renderer(clock, seconds_at_128=16.0)

    evaluation = heldout.HeldoutEvaluation(scene, [0, 1, 2], [0])
    evaluation.during(render)  # measures 16 s a view at full size
    scores, renders = evaluation.final(render, TimeBudget(16.0 + 5.0 + heldout.WRITING_SECONDS, started=0.0))
    # 5 s left: a full-size view (16 s) does not fit, a half-size one (4 s) does, and a second would not.
    assert scores["evaluation_downscale"] == 2 and sizes[1:] == [64] and scores["views"] == 1
    assert renders[0][1]["rgb"].shape == (64, 64, 3) == renders[0][2].shape


def test_a_run_stopped_before_any_evaluation_times_a_small_view_before_its_final_one(monkeypatch):
    """No view cost measured (training stopped before its first round ended): a full-size first view
    of an untrained field can take minutes on a CPU, past --max-time (docs/photos.md took 184 s
    under --max-time 5). One view at the smallest size is timed first and the rest sized from it."""
    scene = synthetic_scene("cube", views=12, size=128)
    clock = [0.0]
    monkeypatch.setattr(heldout.time, "perf_counter", lambda: clock[0])
    sizes, render = blank_renderer(clock, seconds_at_128=16.0)

    evaluation = heldout.HeldoutEvaluation(scene, [0, 1, 2], [0])
    scores, _ = evaluation.final(render, TimeBudget(6.0 + heldout.WRITING_SECONDS, started=0.0))
    # the probe: 32 x 32 in 1 s, so 16 s at full size; 5 s left then: one half-size view (4 s) fits.
    assert sizes == [32, 64] and scores["evaluation_downscale"] == 2 and scores["views"] == 1
    assert clock[0] <= 6.0


def test_without_a_time_budget_the_final_evaluation_renders_no_probe():
    scene = synthetic_scene("cube", views=12, size=64)
    sizes, render = blank_renderer()

    scores, _ = heldout.HeldoutEvaluation(scene, [0, 1], [0]).final(render, TimeBudget(None))
    assert sizes == [64, 64] and scores["views"] == 2 and "evaluation_downscale" not in scores


@pytest.mark.parametrize(("given", "budget"), [
    ({}, CPU_DEFAULT_MAX_TIME),
    ({"steps": 100}, None),
    ({"max_time": 60.0}, 60.0),
])
def test_a_cpu_training_without_steps_or_max_time_stops_within_ten_minutes(capsys, given, budget):
    args = argparse.Namespace(**{"max_time": None, "steps": None, "device": "cpu", **given})
    args.started = time.perf_counter()
    left = training_budget(args)
    said = capsys.readouterr().out
    if budget is None:
        assert left is None and said == ""
    else:
        assert budget - 1 < left <= budget
    assert ("--max-time 540" in said) == (not given)
