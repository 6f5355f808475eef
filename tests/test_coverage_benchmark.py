"""The coverage benchmarks run at this revision: one seed of each of
``interval_coverage.py``'s systems names every true constant by the fitted model's own
constant names and checks its interval, and one seed of ``band_coverage.py`` draws a
prediction band."""

import importlib.util
import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def _script(name: str):
    """The benchmark script ``benchmarks/<name>.py`` as a module (it imports its siblings)."""
    sys.path.insert(0, str(BENCHMARKS))
    try:
        spec = importlib.util.spec_from_file_location(f"{name}_benchmark",
                                                      BENCHMARKS / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(BENCHMARKS))
    return module


@pytest.mark.slow
@pytest.mark.parametrize("system", ["duffing_load", "pendulum", "chain2"])
def test_one_seed_of_each_system_scores_every_true_constant(system):
    row = _script("interval_coverage").run_seed(system, 0, "bandlimited")
    assert row["converged"] and row["constants"]
    for name, constant in row["constants"].items():
        assert constant["low"] <= constant["value"] <= constant["high"], name
        assert abs(constant["value"] - constant["truth"]) < 5 * constant["se"], name


@pytest.mark.slow
def test_one_seed_of_the_band_coverage_benchmark_covers_the_true_response():
    row = _script("band_coverage").run_seed("pendulum", 0)
    assert "no_band" not in row and row["coverage"] > 0.5 and row["diverged"] == 0
