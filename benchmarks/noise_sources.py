"""Where a constant's error comes from: the true structure refitted on the suite's records.

For each system and seed of the physics suite (:mod:`physics_suite`), the *true* structure
is fitted by gpjax's own estimator — the weak-form least-squares start, then
Levenberg–Marquardt on the simulated response to convergence (``Fitness.refine``) — on
three versions of the fit record that share every random draw but the noise they keep:

* ``both``: response and input noise (the suite's record);
* ``response``: response noise only (the measured input is the true one);
* ``input``: input noise only (the response is exact).

The worst constant error of each refit is the floor of what any search that finds the
structure reports on that record: a suite row whose constants match the ``both`` refit
missed 2 % because of the record, not the search. The two one-source columns split it,
next to the Cramér–Rao σ (:func:`gpjax.systems.cramer_rao`), which knows only the response
noise. An error that scales with the noise level (compare ``--noise``) is the noise
realisation's, not a bias.

Usage::

    python benchmarks/noise_sources.py --systems softening_spring --seeds 4 --noise 0.03 \\
        --json softening_noise_sources.json
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _provenance import provenance  # noqa: E402
import gpjax  # noqa: E402
from gpjax._canonical import check_structure  # noqa: E402
from gpjax._fitness import Fitness  # noqa: E402
from gpjax.systems import PHYSICS_SUITE, compare_structure, cramer_rao, generate  # noqa: E402
from physics_suite import FUNCTIONS, _scales  # noqa: E402

#: (label, keeps response noise, keeps input noise)
SOURCES = (("both", True, True), ("response", True, False), ("input", False, True))


def refit_truth(data, *, max_degree: int = 3) -> tuple[object, float]:
    """The true structure of ``data``'s system fitted to convergence on its fit record:
    (sympy equation, objective)."""
    measurement = data.fit.measurement()
    config = gpjax.GPConfig(population=8, generations=1, functions=FUNCTIONS,
                            max_degree=max_degree)
    fitness = Fitness(measurement, config)
    check = check_structure(data.system.truth()[0], fitness.symbols, bank=True)
    if not check.valid:
        raise ValueError(f"{data.system.name}: the truth is not a bank structure "
                         f"({check.reason})")
    key = "truth"
    fitness.score_forms({key: fitness._bank_form(check.canonical)})
    record = fitness.records[key]
    fitness.refine([record], to_convergence=True)
    return record.coefficients.canonical().equation(fitness.symbols), record.objective


def row(system: str, seed: int, noise: float) -> dict:
    out = {"system": system, "seed": seed, "noise": noise}
    for label, response, inputs in SOURCES:
        data = generate(system, seed=seed, noise=noise if response else 0.0,
                        input_noise=noise if inputs else 0.0)
        equation, objective = refit_truth(data)
        verdict = compare_structure(equation, data.system.truth()[0], scales=_scales(data))
        out[label] = {"worst_constant_error": verdict["worst_constant_error"],
                      "objective": objective, "equation": str(equation)}
        if label == "both":
            out["cramer_rao"] = cramer_rao(data)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--systems", nargs="+", default=list(PHYSICS_SUITE))
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--noise", type=float, default=0.01)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    rows = []
    print("| system | seed | worst constant error: both | response noise only | "
          "input noise only | largest Cramér–Rao σ |")
    print("| --- | --- | --- | --- | --- | --- |")
    for system in args.systems:
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            r = row(system, seed, args.noise)
            rows.append(r)
            cells = [f"{100 * r[label]['worst_constant_error']:.2f} %"
                     if math.isfinite(r[label]["worst_constant_error"]) else "no match"
                     for label, _, _ in SOURCES]
            print(f"| {system} | {seed} | " + " | ".join(cells)
                  + f" | {100 * max(r['cramer_rao'].values()):.2f} % |", flush=True)
    if args.json:
        args.json.write_text(json.dumps({**provenance(), "noise": args.noise,
                                         "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
