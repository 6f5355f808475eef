"""What one compiled call costs by its padded size: the population evaluator at its batch
sizes (16, 128, 500) and the refiner at its (2, 8), on one 8,000-sample 1-DOF record
(``pendulum``, 80 s at 100 Hz) with the README's wide function set, models with a family
(sin x) and without (a cubic spring).

    python benchmarks/bench_call_cost.py --json benchmarks/call_cost.json

Per kind: the best of ``--rounds`` calls at each size after a warm-up, and the line
seconds = a + b·rows fitted to them; a/b, a call's fixed cost in rows, is what
:data:`gpjax._coefficients.CALL_OVERHEAD_ROWS` stands for when ``padded_chunks`` weighs
one more call against padding. Prints a table and writes JSON.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

from _provenance import provenance


def _timed(call, rounds: int) -> float:
    call()  # compile or load
    best = np.inf
    for _ in range(rounds):
        began = time.perf_counter()
        call()
        best = min(best, time.perf_counter() - began)
    return best


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--json", help="write the results here")
    args = parser.parse_args(argv)

    from gpjax import GPConfig
    from gpjax._canonical import CanonicalForm
    from gpjax._config import WIDE_FUNCTIONS
    from gpjax._features import Family
    from gpjax._fitness import Fitness
    from gpjax.systems import generate, get_system

    system = dataclasses.replace(get_system("pendulum"), duration=80.0)
    measurement = generate(system, seed=0).fit.measurement()
    fitness = Fitness(measurement, GPConfig(functions=WIDE_FUNCTIONS, population=500))
    x, v, u = fitness.symbols.x, fitness.symbols.x_dot, fitness.symbols.u[0]
    sine = fitness.default_feature(Family("sin", "x"))
    kinds = {"family": lambda i: {sine: 40.0 + i, v: 1.5},
             "plain": lambda i: {x: 40.0 + i, v: 1.5, x ** 3: 0.1 * i}}
    rows = {}
    for kind, state in kinds.items():
        forms = {f"{kind}{i}": CanonicalForm(mass=1.0, state=tuple(state(i).items()),
                                             forcing=((u, 1.0),)) for i in range(16)}
        fitness.score_forms(forms)
        records = [fitness.records[k] for k in forms]
        for size in fitness.evaluator.batch_sizes:
            population = fitness.population((records * (size // len(records) + 1))[:size])
            rows.setdefault(f"evaluate, {kind}", {})[size] = _timed(
                lambda: fitness.evaluator.score(population), args.rounds)
        for size in fitness.refiner.batch_sizes:
            chosen = records[:size]
            population, held = fitness.population(chosen), fitness.held(chosen)
            rows.setdefault(f"refine, {kind}", {})[size] = _timed(
                lambda: fitness.refiner.refine(population, *held), args.rounds)
    out = {}
    print(f"{'call':<18} " + " ".join(f"{'size':>5} {'s':>6}" for _ in range(3))
          + f" {'a (s)':>7} {'b (ms/row)':>10} {'a/b rows':>8}")
    for name, seconds in rows.items():
        sizes = np.array(list(seconds), dtype=float)
        b, a = np.polyfit(sizes, np.array(list(seconds.values())), 1)
        out[name] = {"seconds": seconds, "a_s": a, "b_s_per_row": b, "overhead_rows": a / b}
        print(f"{name:<18} " + " ".join(f"{s:>5d} {t:>6.3f}" for s, t in seconds.items())
              + f" {a:>7.3f} {1e3 * b:>10.2f} {a / b:>8.1f}", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(
            {**provenance(), "samples": measurement.n_samples, "calls": out}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
