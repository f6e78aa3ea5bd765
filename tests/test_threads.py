"""``import pointfield`` shortens OpenMP's spin before torch loads, and keeps a user's own waiting policy.

Why: benchmarks/bench_threads.py (a training step with another program busy on a core runs many
times slower while libgomp's threads spin). libgomp reads the variables once, when torch loads it,
so they are checked in a fresh interpreter.
"""

from __future__ import annotations

import subprocess
import sys

CODE = ("import os, sys, pointfield; "
        "print(os.environ.get('GOMP_SPINCOUNT'), os.environ.get('OMP_WAIT_POLICY'), 'torch' in sys.modules)")


def policy_after_import(checkout_environment: dict[str, str], **variables: str) -> str:
    environment = {k: v for k, v in checkout_environment.items() if k not in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")}
    result = subprocess.run([sys.executable, "-c", CODE], capture_output=True, text=True,
                            env={**environment, **variables}, check=True, timeout=120)
    return result.stdout.strip()


def test_importing_pointfield_shortens_openmps_spin_before_torch_is_loaded(checkout_environment):
    assert policy_after_import(checkout_environment) == "10000 None False"


def test_a_waiting_policy_or_spin_count_the_user_set_is_kept(checkout_environment):
    assert policy_after_import(checkout_environment, OMP_WAIT_POLICY="ACTIVE") == "None ACTIVE False"
    assert policy_after_import(checkout_environment, GOMP_SPINCOUNT="300000") == "300000 None False"
