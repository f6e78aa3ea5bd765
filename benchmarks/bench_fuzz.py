"""A longer fuzzing campaign than the test suite's: every outcome a cloud or a FormatError.

Reports how many inputs were tried, the outcomes, and the slowest inputs (the claim: none takes
more than a second). Uses the same seeds and mutations as tests/clouds/formats/test_fuzz.py.

Run: ``make bench-fuzz`` (or ``python benchmarks/bench_fuzz.py --per-seed 1000``); the record goes
to ``benchmarks/records/fuzz.json``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import traceback
from collections import Counter
from pathlib import Path

from tqdm import tqdm

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from fuzzing import cases, generated_seeds, real_seeds, run_case  # noqa: E402 (tests/ is on the path from here on)
from harness import Record  # noqa: E402

SHARED_DATA = ROOT.parent / "shared" / "data"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--per-seed", type=int, default=600)
    parser.add_argument("--seed", type=int, default=12345)
    args = parser.parse_args()

    record = Record(
        "fuzz", "Fuzzing the readers", issue="2",
        about=f"{args.per_seed} mutations (random seed {args.seed}) of each seed file: small real files from "
              "../shared/data, files pointfield wrote in every format and encoding (PTX included), a two-scan "
              "Leica PTX file with a transform and a LAZ file as LASzip 1.2r0 wrote them (read by the LASzip "
              "backend), the same seeds and mutations as tests/clouds/formats/test_fuzz.py. Every input must give "
              "a cloud or a FormatError, within a second.")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        seeds = generated_seeds(folder)
        if SHARED_DATA.is_dir():
            seeds += real_seeds(SHARED_DATA)
        else:
            record.note(f"{SHARED_DATA} was absent: generated files only were fuzzed.")
        outcomes: Counter[str] = Counter()
        slowest: list[tuple[float, str]] = []
        failures = over = 0
        total = len(seeds) * args.per_seed
        for i, (origin, description, data) in enumerate(
            tqdm(cases(seeds, args.per_seed, args.seed), total=total, unit="input")
        ):
            path = folder / f"case{origin.suffix}"
            path.write_bytes(data)
            try:
                outcome, seconds = run_case(path)
            except Exception:  # noqa: BLE001 - a finding to report, not to stop at
                failures += 1
                print(f"\nFAIL {origin.name} mutated by {description!r} (case {i}):")
                traceback.print_exc()
                continue
            outcomes[outcome] += 1
            over += seconds > 1.0
            slowest.append((seconds, f"{origin.name}: {description}"))
            slowest = sorted(slowest, reverse=True)[:5]

    record.figures.update({"inputs": total, "seeds": len(seeds), "outcomes": dict(outcomes), "failures": failures,
                           "slowest": [{"milliseconds": seconds * 1000, "input": what} for seconds, what in slowest]})
    record.table(["outcome", "inputs"], [[name, f"{count:,}"] for name, count in outcomes.most_common()]
                 + [["failure (any other exception)", f"{failures:,}"]],
                 title=f"{total:,} inputs from {len(seeds)} seeds")
    record.table(["slowest inputs", "ms"], [[what, f"{seconds * 1000:.1f}"] for seconds, what in slowest])
    record.verdict("every input gives a cloud or a FormatError", failures == 0, f"{failures} failures")
    record.verdict("no input takes more than 1 s", not over, f"{over} over 1 s")
    return max(record.finish(), 1 if failures or over else 0)


if __name__ == "__main__":
    sys.exit(main())
