"""Recovery of eq. 14 on the bundled gear example with and without the memetic steps.

    python benchmarks/gear_recovery.py --seeds 5 --json benchmarks/gear_recovery.json

Four modes over seeds 0 … S−1, the paper's protocol otherwise (population 500, ≤ 10
generations, ε = 0.01): least-squares coefficients with and without ``local_search``, and
the paper's tree-constant mode with the gear geometry's stiffness intervals (notebook 02:
K1 from the mesh's torsional stiffness range, K2 from it over the static twist) with and
without ``local_search``. Recovered: the structure J·φ'' + K1·φ + K2·φ² = T with J, K1, K2
within 2 % of the truth. Prints a table and writes every run as JSON.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import sympy as sp

from gpjax import GPConfig, Identifier
from gpjax.gear import GearPair, load_bundled_example, stiffness_report

from _provenance import provenance

TOLERANCE = 0.02


def geometry_intervals() -> dict:
    """K1, K2 intervals from the gear geometry (as notebook 02 derives them)."""
    torsion = stiffness_report(GearPair.paper())["torsional_N_m_per_deg"]
    k1 = (torsion["min"], torsion["max"])
    static = 13.0 / torsion["mean"]
    return {"K1": (k1,), "K2": ((k1[0] / static, k1[1] / static),)}


def recovered(model, truth) -> tuple[bool, bool, float]:
    """(right structure, constants within TOLERANCE, largest relative constant error)."""
    phi, T = sp.Symbol("phi"), sp.Symbol("T")
    c = model.coefficients
    right = set(c.state) == {phi, phi ** 2} and set(c.forcing) == {T}
    if not right:
        return False, False, float("nan")
    errors = [abs(found / truth[name] - 1) for found, name in
              ((c.mass, "J"), (c.state[phi], "K1"), (c.state[phi ** 2], "K2"))]
    return True, max(errors) <= TOLERANCE, max(errors)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--json", help="write the runs here")
    args = parser.parse_args()
    measurement, truth = load_bundled_example()
    intervals = geometry_intervals()
    modes = {
        "least squares, local search": GPConfig.paper(),
        "least squares, no local search": GPConfig.paper(local_search=0),
        "tree, geometry intervals, local search": GPConfig.paper(
            coefficients="tree", interval_constants=intervals),
        "tree, geometry intervals, no local search": GPConfig.paper(
            coefficients="tree", interval_constants=intervals, local_search=0),
    }
    runs = []
    for name, config in modes.items():
        for seed in range(args.seeds):
            began = time.perf_counter()
            identifier = Identifier(config).fit(measurement, seed=seed)
            right, within, error = recovered(identifier.model_, truth)
            runs.append({"mode": name, "seed": seed, "right_structure": right,
                         "recovered": within, "max_constant_error": error,
                         "generations": identifier.timings_["generations"],
                         "seconds": time.perf_counter() - began,
                         "equation": str(identifier.model_.sympy())})
            print(f"{name:<44} seed {seed}: {'recovered' if within else 'not recovered'} "
                  f"({runs[-1]['seconds']:.1f} s)", flush=True)
    print(f"\n{'mode':<44} {'structure':>9} {'recovered':>9} {'median s':>9}")
    for name in modes:
        rows = [r for r in runs if r["mode"] == name]
        seconds = sorted(r["seconds"] for r in rows)[len(rows) // 2]
        print(f"{name:<44} {sum(r['right_structure'] for r in rows):>4}/{len(rows):<4} "
              f"{sum(r['recovered'] for r in rows):>4}/{len(rows):<4} {seconds:>9.1f}")
    if args.json:
        Path(args.json).write_text(json.dumps({
            **provenance(), "intervals": intervals, "truth": {k: truth[k] for k in ("J", "K1", "K2")},
            "runs": runs}, indent=2) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
