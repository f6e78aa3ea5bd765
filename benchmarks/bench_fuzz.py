"""A longer fuzzing campaign than the test suite's: every outcome a cloud or a FormatError.

Reports how many inputs were tried, the outcomes, and the slowest inputs (the claim: none takes
more than a second). Uses the same seeds and mutations as tests/clouds/formats/test_fuzz.py.

Run: ``make bench-fuzz`` (or ``python benchmarks/bench_fuzz.py --per-seed 1000``).
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

from fuzzing import cases, generated_seeds, real_seeds, run_case  # noqa: E402

SHARED_DATA = ROOT.parent / "shared" / "data"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--per-seed", type=int, default=600)
    parser.add_argument("--seed", type=int, default=12345)
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        seeds = generated_seeds(folder)
        if SHARED_DATA.is_dir():
            seeds += real_seeds(SHARED_DATA)
        else:
            print(f"note: {SHARED_DATA} is absent; fuzzing generated files only")
        outcomes: Counter[str] = Counter()
        slowest: list[tuple[float, str]] = []
        failures = 0
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
            slowest.append((seconds, f"{origin.name}: {description}"))
            slowest = sorted(slowest, reverse=True)[:5]

    print(f"{total:,} inputs from {len(seeds)} seeds: {dict(outcomes)}, {failures} failures")
    print("slowest inputs:")
    for seconds, what in slowest:
        print(f"  {seconds * 1000:8.1f} ms  {what}")
    over = [s for s, _ in slowest if s > 1.0]
    print(f"inputs over 1 s: {len(over)}")
    return 1 if failures or over else 0


if __name__ == "__main__":
    sys.exit(main())
