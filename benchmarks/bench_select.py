"""The final model selection's cost: gpjax fits of physics-suite cases with this tree and with
git revision ``--baseline`` (a temporary worktree), each fit in a fresh child process, the
two alternating case by case, at the suite's settings (1 % noise on response and input,
population 200, 5 generations, its function set), with the compilation cache off (each
fit compiles as a first run does).

    python benchmarks/bench_select.py --baseline 7480e1b --json benchmarks/select_cost.json

Per case: models refined in the whole fit (one Levenberg–Marquardt round each; counted in
the child by wrapping ``Fitness._refine_round``), seconds of the whole fit with each tree
(the fastest of ``--rounds`` fits, the trees alternating: the machine's speed drifts
between minutes) and their ratio, the final selection's seconds with this tree
(``timings_["selection_s"]``; a baseline without that timing shows none), and whether
both report the same model (the same equation text with every number equal to 1e-6
relative). Prints a table and writes JSON.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

from _baseline import ROOT, baseline_tree, run_child
from _provenance import provenance

CASES = ("saturating_spring:3", "softening_spring:0", "coulomb_viscous:1", "coulomb_viscous:2",
         "quadratic_drag:0", "stribeck_resolved:0")
CHILD = """
import json, sys, time
sys.path.insert(0, "benchmarks")
import gpjax
from gpjax import _fitness
from gpjax.systems import generate
from physics_suite import FUNCTIONS
refined, one_round = [0], _fitness.Fitness._refine_round
def counted(self, records):  # models refined, the run's whole
    refined[0] += len(records)
    return one_round(self, records)
_fitness.Fitness._refine_round = counted
system, seed = sys.argv[1], int(sys.argv[2])
data = generate(system, seed=seed, noise=0.01, input_noise=0.01, extrapolation_scale=1.2)
config = gpjax.GPConfig(population=200, generations=5, functions=FUNCTIONS, max_degree=3)
began = time.perf_counter()
identifier = gpjax.Identifier(config).fit(data.fit.measurement(), seed=seed, progress=False)
print(json.dumps({"seconds": time.perf_counter() - began,
                  "selection_s": identifier.timings_.get("selection_s"),
                  "refined": refined[0],
                  "equation": str(identifier.model_.sympy())}))
"""
NUMBER = re.compile(r"-?\d+\.?\d*(?:e-?\d+)?")


def fit(path: Path, case: str) -> dict:
    """One case fitted with the tree at ``path`` in a fresh process; raises
    ``subprocess.CalledProcessError`` when the fit fails."""
    return run_child(path, CHILD, *case.split(":"))


def same_model(a: str, b: str) -> bool:
    """Whether two printed equations differ only in numbers within 1e-6 relative."""
    if NUMBER.sub("#", a) != NUMBER.sub("#", b):
        return False
    return all(abs(float(x) - float(y)) <= 1e-6 * max(abs(float(x)), abs(float(y)))
               for x, y in zip(NUMBER.findall(a), NUMBER.findall(b)))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--baseline", required=True, help="git revision to compare with")
    parser.add_argument("--cases", default=",".join(CASES),
                        help="comma-separated system:seed pairs of the physics suite")
    parser.add_argument("--rounds", type=int, default=2,
                        help="fits per case and tree, alternating; the fastest counts")
    parser.add_argument("--json", help="write the results here")
    args = parser.parse_args(argv)
    rows = []
    print(f"{'case':<22} {'base s':>8} {'now s':>8} {'ratio':>6} {'select s':>8} "
          f"{'refined':>11} {'same':>5}")
    with baseline_tree(args.baseline) as tree:
        for case in args.cases.split(","):
            fits = [(fit(tree, case), fit(ROOT, case)) for _ in range(args.rounds)]
            baseline, current = (min(runs, key=lambda f: f["seconds"]) for runs in zip(*fits))
            r = {"case": case, "baseline_s": baseline["seconds"],
                 "current_s": current["seconds"],
                 "rounds_s": [[b["seconds"], c["seconds"]] for b, c in fits],
                 "baseline_over_current": baseline["seconds"] / current["seconds"],
                 "baseline_selection_s": baseline["selection_s"],
                 "current_selection_s": current["selection_s"],
                 "baseline_refined": baseline["refined"], "current_refined": current["refined"],
                 "same_model": all(same_model(b["equation"], c["equation"])
                                   for b, c in fits),
                 "baseline_equation": baseline["equation"], "equation": current["equation"]}
            rows.append(r)
            print(f"{case:<22} {r['baseline_s']:>8.1f} {r['current_s']:>8.1f} "
                  f"{r['baseline_over_current']:>6.2f} {r['current_selection_s']:>8.1f} "
                  f"{r['baseline_refined']:>5}/{r['current_refined']:<5} "
                  f"{'yes' if r['same_model'] else 'NO':>5}", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(
            {**provenance(), "baseline": args.baseline, "rows": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
