"""The diagnosis of a system through the front door (issue 42's evidence), on records
written by the catalogue with known truth (1 % noise on every response and on the input).

    python benchmarks/system_diagnosis.py [--clean-seeds 10] [--friction-seeds 3]
        [--json benchmarks/system_diagnosis.json]

* **Clean control** (``chain2``, seeds 0 … ``--clean-seeds`` − 1): the truth's structure,
  written as a model file, is diagnosed by ``gpjax diagnose … --response x1 --response x2``.
  Nothing may be added: each seed is a chance of at most α = 0.05 for a spurious effect.
* **Undeclared friction** (``chain2_friction_x2``: chain2 with F·tanh(x2'/v0) on mass 2,
  seeds 100 …): ``gpjax fit … --diagnose`` with the defaults (polynomial functions, which
  cannot write the friction). The first effect added must be ``coulomb_friction`` on x2,
  equation 2; the friction force per unit mass F/m2 of the result is compared with the
  truth's (the fit normalises equation 2 by its mass).

Resumable: rows already in ``--json`` are kept and skipped. The JSON records the revision,
command, date and machine (:mod:`benchmarks._provenance`), and each row its revision.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import sympy as sp

import gpjax
from gpjax._coefficients import Coefficients
from gpjax.systems import generate, get_system

sys.path.insert(0, str(Path(__file__).parent))
from _provenance import provenance  # noqa: E402

NAMES = ("x1", "x2")


def truth_model(name: str) -> gpjax.Model:
    """The truth of a catalogue system as a model, its terms as written (not expanded):
    each left-hand term is a product of constants and one feature."""
    system = get_system(name)
    values = {sp.Symbol(k): v for k, v in system.constants.items()}
    equations = []
    for i, eq in enumerate(system.equations):
        mass, state = 0.0, {}
        for term in sp.Add.make_args(eq.lhs):
            constants = [f for f in sp.Mul.make_args(term) if f in values]
            feature = sp.Mul(*[f for f in sp.Mul.make_args(term) if f not in values])
            value = float(sp.Mul(*constants).subs(values))
            if feature == sp.Symbol(f"{NAMES[i]}_ddot"):
                mass = value
            else:
                state[feature] = value
        forcing = {f: 1.0 for f in sp.Add.make_args(eq.rhs) if f != 0}
        equations.append(Coefficients(mass, state, forcing))
    return gpjax.Model.from_equations(NAMES, "t", ("u",), equations, substeps=2)


def _run(args: list[str], folder: Path) -> tuple[float, str]:
    began = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "gpjax", *args], cwd=folder, capture_output=True,
                          text=True)
    if done.returncode:
        raise SystemExit(f"gpjax {' '.join(args)} failed:\n{done.stderr[-2000:]}")
    return time.perf_counter() - began, done.stdout


def case(kind: str, seed: int) -> dict:
    """One record: write it, diagnose it through the CLI, read the report."""
    name = "chain2" if kind == "clean" else "chain2_friction_x2"
    responses = ["--response", "x1", "--response", "x2", "--input", "u"]
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        generate(name, seed=seed).fit.system_measurement().to_csv(folder / "fit.csv")
        if kind == "clean":
            truth_model("chain2").save(folder / "model.json")
            seconds, _ = _run(["diagnose", "fit.csv", "--model", "model.json", "--time", "t",
                               *responses, "--out", "diagnosis"], folder)
        else:
            seconds, _ = _run(["fit", "fit.csv", "--time", "t", *responses, "--seed", "7",
                               "--diagnose", "--out", "run"], folder)
        report_folder = folder / ("diagnosis" if kind == "clean" else "run/diagnosis")
        report = json.loads((report_folder / "report.json").read_text())
        model = gpjax.Model.load(report_folder / "model.json")
    steps = report["steps"]
    row = {"kind": kind, "system": name, "seed": seed, "seconds": round(seconds, 1),
           "added": [f"{s['effect']} on {s['acts_on']}" for s in steps],
           "first": steps[0]["effect"] if steps else None,
           "first_equations": steps[0]["equations"] if steps else None,
           "nrms": {k: v["nrms"] for k, v in report["residuals"].items()},
           "noise_ratio": {k: (v["noise"] or {}).get("ratio")
                           for k, v in report["residuals"].items()}}
    if kind == "friction":
        truth = get_system(name).constants
        equation = model.system[1]
        sign = [v for f, v in equation.state.items() if f.has(sp.tanh)
                and f.free_symbols == {sp.Symbol("x2_dot")}]
        found = sign[0] / equation.mass if sign else None
        row |= {"F_per_m2": found, "F_per_m2_truth": truth["F"] / truth["m2"],
                "F_error": None if found is None else found / (truth["F"] / truth["m2"]) - 1}
        row["named_first"] = row["first"] == "coulomb_friction" and row["first_equations"] == [2]
    return row


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clean-seeds", type=int, default=10)
    parser.add_argument("--friction-seeds", type=int, default=3)
    parser.add_argument("--json", default="benchmarks/system_diagnosis.json")
    args = parser.parse_args()
    path = Path(args.json)
    rows = json.loads(path.read_text())["rows"] if path.exists() else []
    done = {(r["kind"], r["seed"]) for r in rows}
    plan = ([("clean", s) for s in range(args.clean_seeds)]
            + [("friction", 100 + s) for s in range(args.friction_seeds)])
    here = provenance()
    for kind, seed in plan:
        if (kind, seed) in done:
            continue
        row = case(kind, seed) | {"revision": here["revision"]}
        rows.append(row)
        print(f"{kind:9s} seed {seed:3d}: added {row['added'] or 'nothing'}, "
              f"{row['seconds']} s" + (f", F/m2 error {row['F_error']:+.2%}"
                                      if row.get("F_error") is not None else ""), flush=True)
        path.write_text(json.dumps({**here, "rows": rows}, indent=2) + "\n")
    clean = [r for r in rows if r["kind"] == "clean"]
    friction = [r for r in rows if r["kind"] == "friction"]
    print(f"clean chain: {sum(not r['added'] for r in clean)}/{len(clean)} add nothing; "
          f"friction on x2: {sum(r['named_first'] for r in friction)}/{len(friction)} named "
          "first on equation 2")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
