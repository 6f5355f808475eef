"""benchmarks/coverage.py runs at this revision: one seed of each of its systems names every
true constant by the fitted model's own constant names and checks its interval."""

import importlib.util
import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def _coverage():
    sys.path.insert(0, str(BENCHMARKS))  # the script imports its sibling _provenance
    try:
        spec = importlib.util.spec_from_file_location("coverage_benchmark",
                                                      BENCHMARKS / "coverage.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(BENCHMARKS))
    return module


@pytest.mark.slow
@pytest.mark.parametrize("system", ["duffing_load", "pendulum", "chain2"])
def test_one_seed_of_each_system_scores_every_true_constant(system):
    row = _coverage().run_seed(system, 0, "bandlimited")
    assert row["converged"] and row["constants"]
    for name, constant in row["constants"].items():
        assert constant["low"] <= constant["value"] <= constant["high"], name
        assert abs(constant["value"] - constant["truth"]) < 5 * constant["se"], name
