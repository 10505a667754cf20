"""``bench``: benchmarks/bench_estimate.py loaded as a module (its synthetic studies are the
tests' ground truth)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location(
        "bench_estimate", ROOT / "benchmarks" / "bench_estimate.py"
    )
    mod = importlib.util.module_from_spec(spec)
    sys.modules["bench_estimate"] = mod
    spec.loader.exec_module(mod)
    return mod
