"""Cost of the feature bank (non-polynomial state features) on population evaluation, and
compiles per run.

    python benchmarks/bench_feature_bank.py --baseline 1294810 --json benchmarks/feature_bank.json

Measured in one run, on the bundled gear example (P = 500, 1,334 samples, one device):

* models/s of the polynomial population (eq. 14 models) on an evaluator without families —
  today's fast path — and on the same evaluator with every family compiled but unused;
* the same polynomial population on the engine of ``--baseline`` (a git revision before the
  bank), run from a temporary worktree in a child process, interleaved with the above;
* models/s of a population whose models use sin, x'·|x'| and tanh features, and of a
  GP-like mix: the polynomial models plus one family member each, the members taking turns;
* compiles per GP run (population evaluator and refiner shapes): the demo protocol, and a
  fit of ``gpjax.systems``' pendulum (seed 0) with sin in the function set.

Each rate is the best of several repeats (the machine is shared); ratios are to the
fast path measured in the same run. Prints a table and writes JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from _baseline import baseline_tree, in_tree
from _provenance import provenance

REPEATS = 7
ROOT = Path(__file__).resolve().parent.parent
#: The child's measurement of one evaluator's rate (run with the engine on sys.path[0]).
CHILD = r"""
import sys, time, json, numpy as np
from gpjax.gear import load_bundled_example
from gpjax import Symbols
from gpjax.engine import PopulationEvaluator
measurement, truth = load_bundled_example()
ev = PopulationEvaluator(measurement, Symbols("phi", "t", ("T",)), max_degree=4, batch=500)
rng = np.random.default_rng(0)
u = ev.forcing_index(ev.symbols.u[0])
pop = ev.empty(500)
pop.mass[:] = truth["J"] * (1 + 0.1 * rng.uniform(-1, 1, 500))
pop.state[:, 0] = truth["K1"] * (1 + 0.1 * rng.uniform(-1, 1, 500))
pop.state[:, 1] = truth["K2"] * (1 + 0.1 * rng.uniform(-1, 1, 500))
pop.forcing[:, u] = 1.0
pop.y0[:] = [truth["initial_conditions"]["phi"], truth["initial_conditions"]["phi_dot"]]
ev.score(pop)
times = []
for _ in range(int(sys.argv[1])):
    began = time.perf_counter(); ev.score(pop); times.append(time.perf_counter() - began)
print(json.dumps(500 / min(times)))
"""


def child_rate(path: Path, repeats: int) -> float:
    """models/s of the polynomial population with the engine at ``path``."""
    out = subprocess.run([sys.executable, "-c", CHILD, str(repeats)], check=True,
                         capture_output=True, text=True, **in_tree(path, JAX_PLATFORMS="cpu"))
    return float(out.stdout.strip().splitlines()[-1])


def protocol_compiles(functions: tuple[str, ...] | None) -> dict:
    """A GP run's compiles and seconds: the demo protocol (``None``) or a pendulum fit with
    ``functions``."""
    import gpjax
    from gpjax.gear import load_bundled_example

    if functions is None:
        measurement, _ = load_bundled_example()
        config = gpjax.GPConfig.paper()
    else:
        from gpjax.systems import generate

        measurement = generate("pendulum", seed=0).fit.measurement()
        config = gpjax.GPConfig(population=200, generations=5, max_degree=3, functions=functions)
    identifier = gpjax.Identifier(config).fit(measurement, seed=0)
    t = identifier.timings_
    return {"compiles": t["compiles"], "compile_s": t["compile_s"], "total_s": t["total_s"],
            "generations": t["generations"], "equation": str(identifier.model_.sympy())}


def bank_rates(repeats: int) -> dict:
    """models/s: polynomial population without and with the bank, and a bank population."""
    import sympy as sp

    from gpjax import Symbols
    from gpjax._coefficients import Coefficients, to_population
    from gpjax._features import families_for
    from gpjax.engine import PopulationEvaluator
    from gpjax.gear import load_bundled_example

    measurement, truth = load_bundled_example()
    symbols = Symbols("phi", "t", ("T",))
    families = families_for(("sin", "cos", "tanh", "exp", "abs"), ("x", "x_dot"), 4)
    rng = np.random.default_rng(0)
    x, v, u = symbols.x, symbols.x_dot, symbols.u[0]
    y0 = (truth["initial_conditions"]["phi"], truth["initial_conditions"]["phi_dot"])

    def spread(value):
        return value * (1 + 0.1 * rng.uniform(-1, 1))

    polynomial = [Coefficients(mass=spread(truth["J"]), state={x: spread(truth["K1"]),
                                                               x ** 2: spread(truth["K2"])},
                               forcing={u: 1.0}, y0=y0) for _ in range(500)]
    # the same stiffness as a sine of a scaled angle, plus drag and smoothed friction terms
    bank = [Coefficients(mass=spread(truth["J"]),
                         state={sp.sin(spread(1.0) * x): spread(truth["K1"]),
                                v * sp.Abs(v): spread(1e-6), sp.tanh(spread(50.0) * v): 1e-4},
                         forcing={u: 1.0}, y0=y0) for _ in range(500)]
    # a GP population's mix: the polynomial stiffness plus one family member each, the
    # members taking turns (each model uses another family than its neighbours)
    members = [sp.sin(x), sp.cos(x), sp.tanh(50.0 * v), v * sp.Abs(v), x * sp.Abs(x),
               sp.exp(x), sp.sinh(x), sp.cosh(x), sp.exp(-v ** 2) * sp.tanh(50.0 * v)]
    mixed = [model.replace(state={**model.state, members[i % len(members)]: spread(1e-6)})
             for i, model in enumerate(polynomial)]
    rates = {}
    for name, fams, models in (("polynomial_fast_path", (), polynomial),
                               ("polynomial_with_bank", families, polynomial),
                               ("bank_population", families, bank),
                               ("bank_mixed", families, mixed)):
        ev = PopulationEvaluator(measurement, symbols, max_degree=4, batch=500, families=fams,
                                 devices=None)
        pop = to_population(models, ev)
        ev.score(pop)
        times = []
        for _ in range(repeats):
            began = time.perf_counter()
            ev.score(pop)
            times.append(time.perf_counter() - began)
        rates[name] = {"models_per_s": 500 / min(times), "compile_s": ev.compile_seconds}
    return rates


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", help="git revision of the engine before the bank")
    parser.add_argument("--json", help="write the results here")
    parser.add_argument("--repeats", type=int, default=REPEATS)
    args = parser.parse_args()
    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    result = {**provenance(), "P": 500}
    result["rates"] = bank_rates(args.repeats)
    fast = result["rates"]["polynomial_fast_path"]["models_per_s"]
    if args.baseline:
        with baseline_tree(args.baseline) as tree:
            baseline = [child_rate(tree, args.repeats) for _ in range(2)]
            current = [child_rate(ROOT, args.repeats) for _ in range(2)]
        result["baseline"] = {"revision": args.baseline, "models_per_s": max(baseline),
                              "current_models_per_s": max(current),
                              "current_over_baseline": max(current) / max(baseline)}
    result["compiles"] = {"demo_protocol": protocol_compiles(None),
                          "pendulum_sin": protocol_compiles(("add", "sub", "mul", "sin"))}
    print(f"{'quantity':<58} {'value':>12}")
    for name, row in result["rates"].items():
        print(f"{name + ' models/s (ratio to fast path)':<58} {row['models_per_s']:>9.0f} "
              f"{row['models_per_s'] / fast:>5.2f}")
    if "baseline" in result:
        b = result["baseline"]
        print(f"{'baseline ' + b['revision'] + ' models/s, current/baseline (child)':<58} "
              f"{b['models_per_s']:>9.0f} {b['current_over_baseline']:>5.2f}")
    for name, row in result["compiles"].items():
        print(f"{'compiles per run, ' + name + ' (compile s / total s)':<58} "
              f"{row['compiles']:>5} {row['compile_s']:>5.1f} {row['total_s']:>5.1f}")
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
