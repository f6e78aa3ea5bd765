"""Mutated real and generated files give a cloud or a FormatError naming the file: nothing else.

A few thousand inputs here; `make bench-fuzz` runs a longer campaign and reports the slowest.
"""

from __future__ import annotations

import sys
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from fuzzing import cases, generated_seeds, real_seeds, run_case

CASES_PER_SEED = 60


def _campaign(seeds, tmp_path, seed):
    outcomes = Counter()
    for i, (origin, description, data) in enumerate(cases(seeds, CASES_PER_SEED, seed)):
        path = tmp_path / f"case{i}{origin.suffix}"
        path.write_bytes(data)
        try:
            outcome, _ = run_case(path)
        except Exception as error:
            raise AssertionError(
                f"{origin.name} mutated by {description!r} (seed {seed}, case {i}) raised "
                f"{type(error).__name__}: {error}"
            ) from error
        outcomes[outcome] += 1
        path.unlink()
    return outcomes


def test_mutated_real_files_read_or_raise_format_error(shared_data, tmp_path):
    outcomes = _campaign(real_seeds(shared_data), tmp_path, seed=1)
    assert outcomes["FormatError"] > 0 and outcomes["cloud"] > 0


def test_mutated_generated_files_read_or_raise_format_error(tmp_path):
    seeds_dir = tmp_path / "seeds"
    seeds_dir.mkdir()
    outcomes = _campaign(generated_seeds(seeds_dir), tmp_path, seed=2)
    assert outcomes["FormatError"] > 0 and outcomes["cloud"] > 0
