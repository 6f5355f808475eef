"""Systems through the front door (issue 42's evidence): `gpjax fit` with the documented
options on records written by the catalogue, several seeds, scored against the truth.

    python benchmarks/systems_front_door.py [--systems chain2,chain2_free,...] [--seeds 5]
        [--json benchmarks/systems_front_door.json]

Each record (:func:`gpjax.systems.generate`: 1 % noise on every response and on the input,
an extrapolation record with a 20 % larger input) is written as CSV and fitted by a
separate ``gpjax fit … --response x1 --response x2 …`` process with the defaults, plus
``--functions add,sub,mul,sign`` where the truth has dry friction (``--functions``: this set
for every fit, e.g. the README's wide one). Scored:

* **structure**: every equation's terms, each read as (kind, variable) — a power k of
  x_i, x_i − x_j, x_i' or x_i' − x_j', or a bank kind of one (:mod:`gpjax._system_bank`;
  the smoothed sign matches the truth's sign whatever its width) — equal the truth's;
* **constants**: the largest relative error of a term's coefficient and of each mass,
  in the fit's normalisation (equation 1 by its input, the others by their mass);
* **extrapolation NRMS** per coordinate: the fitted model, simulated by the reference solve
  from the true initial state with the true input, against the true response.

Resumable: rows already in ``--json`` (same system and seed) are kept and skipped. The
JSON records the revision, command, date and machine of the last run
(:mod:`benchmarks._provenance`), and each row the revision it ran at.

``--baseline REV`` fits every record a second time with the code of git revision ``REV``
(a temporary worktree), in the same run, and adds to its row ``baseline``: that fit's
revision, seconds, seconds compiling, stages, whether its equations are this tree's, and
its own structure, constant error and extrapolation NRMS, scored as this tree's.
Each tree compiles into its own fresh program cache, so the first record of a run compiles
cold under both and later ones find their programs.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import sympy as sp

import gpjax
from gpjax._system_bank import match_bank, system_variables
from gpjax.systems import generate, get_system, write_csv

sys.path.insert(0, str(Path(__file__).parent))
from _baseline import baseline_tree, in_tree, same_model  # noqa: E402
from _provenance import provenance  # noqa: E402
from bench_new_record import STAGES, SUMMARIES  # noqa: E402
from bench_systems import scored  # noqa: E402
from report import front_door_rows  # noqa: E402

SYSTEMS = ("chain2", "chain2_free", "chain3", "chain3_free", "chain2_friction",
           "chain2_driven_free_end", "torsion2_stiff", "chain3_light_middle")
#: The function set given where the truth has a term beyond add, sub, mul.
FUNCTIONS = {"chain2_friction": "add,sub,mul,sign"}


def label(feature: sp.Expr, variables: list[sp.Expr]) -> tuple[tuple, float] | None:
    """((kind, position[, power]), sign) of a state feature of one equation: the sign is
    −1 where the feature is the negative of the labelled one (sympy writes
    tanh(θ·(x2' − x1')) as −tanh(θ·(x1' − x2'))); ``None`` for any other feature."""
    for sign, signed in ((1.0, feature), (-1.0, -feature)):
        base, power = signed.as_base_exp()
        if power.is_Integer and power > 0 and base in variables:
            return ("power", variables.index(base), int(power)), sign
        found = match_bank(signed, variables)
        if found is not None:
            return (found[0], found[1]), sign
    return None


def truth_terms(system, i: int) -> dict:
    """Equation ``i``'s true terms: label -> coefficient, and "mass", normalised as fitted."""
    variables = system_variables(system.coordinates)[i]
    constants = {sp.Symbol(k): v for k, v in system.constants.items()}
    equation = system.equations[i]
    out = {}
    for term in sp.Add.make_args(equation.lhs):
        factors = sp.Mul.make_args(term)
        coefficient = sp.Mul(*[f for f in factors if f.free_symbols <= set(constants)])
        feature = sp.Mul(*[f for f in factors if not f.free_symbols <= set(constants)])
        value, feature = float(coefficient.subs(constants)), feature.subs(constants)
        if feature == sp.Symbol(f"{system.coordinates[i]}_ddot"):
            out["mass"] = value
            continue
        found = label(feature, variables)
        out[found[0]] = out.get(found[0], 0.0) + found[1] * value
    scale = 1.0 if equation.rhs != 0 else out["mass"]
    gain = float(equation.rhs.coeff(sp.Symbol("u")).subs(constants))
    if i > 0 and gain != 0:  # the input in an equation past the first, as found_terms has it
        out["forcing u"] = gain
    return {k: v / scale for k, v in out.items()}


def found_terms(model: gpjax.Model, i: int) -> dict:
    """The fitted equation ``i``'s terms as :func:`truth_terms` labels them (an unknown
    feature keeps its text as its label)."""
    variables = system_variables(model.coordinates)[i]
    equation = model.system[i]
    out = {"mass": equation.mass}
    for feature, value in equation.state.items():
        found = label(feature, variables)
        key, sign = found if found is not None else (str(feature), 1.0)
        out[key] = out.get(key, 0.0) + sign * value
    inputs = [f for f in equation.forcing if f != sp.Symbol("u")]
    for feature in inputs:
        out[f"forcing {feature}"] = equation.forcing[feature]
    if sp.Symbol("u") in equation.forcing and i > 0:
        out["forcing u"] = equation.forcing[sp.Symbol("u")]
    return out


def timed_fit(command: list[str], child: dict) -> tuple:
    """(completed process, whole seconds, the summary's figures: ``compile_s``,
    ``programs`` and its stages) of one ``gpjax fit`` process, run with ``child``'s
    ``subprocess.run`` options (:func:`_baseline.in_tree`)."""
    began = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, **child)
    seconds = time.perf_counter() - began
    found = next((m for m in (p.search(done.stdout) for p in SUMMARIES) if m), None)
    figures = {"compile_s": float(found[2]) if found else None,
               "programs": int(found[3]) if found else None}
    figures |= {k: (float(m[1]) if (m := p.search(done.stdout)) else None)
                for k, p in STAGES.items()}
    return done, seconds, figures


def run_one(name: str, seed: int, folder: Path, baseline: tuple | None = None,
            functions: str | None = None) -> dict:
    """One record fitted and scored; ``baseline`` = (revision, its tree) fits it again
    with that code (module docstring); ``functions``: every fit's function set (default
    :data:`FUNCTIONS`, else gpjax's)."""
    data = generate(name, seed=seed)
    system = data.system
    path = folder / f"{name}_{seed}.csv"
    write_csv(data.fit, path)
    responses = [word for c in system.coordinates for word in ("--response", c)]
    functions = functions or FUNCTIONS.get(name)
    extra = ["--functions", functions] if functions else []

    def fit_command(out: Path) -> list[str]:
        return [sys.executable, "-m", "gpjax", "fit", str(path), "--time", "t", *responses,
                "--input", "u", "--out", str(out), "--seed", str(seed), *extra]

    command = fit_command(folder / f"{name}_{seed}")
    cache = {} if baseline is None else {"GPJAX_COMPILATION_CACHE": "on",
                                         "GPJAX_CACHE_DIR": str(folder / "cache-tree")}
    done, seconds, figures = timed_fit(command, in_tree(None, **cache))
    if done.returncode != 0:
        return {"system": name, "seed": seed, "revision": provenance()["revision"],
                "error": done.stderr.strip()[-500:], "seconds": seconds}
    model = gpjax.Model.load(folder / f"{name}_{seed}" / "model.json")
    truth = [truth_terms(system, i) for i in range(len(system.coordinates))]

    def score(fitted: gpjax.Model) -> tuple:
        found = [found_terms(fitted, i) for i in range(len(truth))]
        return found, *scored(fitted, found, truth, data.extrapolation)

    compared = {}
    if baseline is not None:
        revision, tree = baseline
        out = folder / f"{name}_{seed}_baseline"
        old, old_seconds, old_figures = timed_fit(fit_command(out), in_tree(
            tree, GPJAX_COMPILATION_CACHE="on", GPJAX_CACHE_DIR=str(folder / "cache-baseline")))
        scores = {}
        if old.returncode == 0:
            old_model = gpjax.Model.load(out / "model.json")
            _, right, worst, spread = score(old_model)
            scores = {"same_equations": same_model(old_model, model), "structure_right": right,
                      "max_constant_error": worst, "extrapolation_nrms": spread.tolist()}
        compared = {"baseline": {"revision": revision, "seconds": old_seconds,
                                 "same_equations": False, **scores, **old_figures}}
    found, structure, error, nrms = score(model)
    return {"system": name, "seed": seed, "revision": provenance()["revision"],
            "command": " ".join(["gpjax", "fit", "<record>"] + command[5:]),
            "structure_right": structure, "max_constant_error": error,
            "extrapolation_nrms": nrms.tolist(), "seconds": seconds,
            "equations": [str(e) for e in model.sympy()],
            "found": [{str(k): v for k, v in f.items()} for f in found],
            "truth": [{str(k): v for k, v in t.items()} for t in truth], **figures,
            **compared}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--systems", default=",".join(SYSTEMS))
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--json", default="benchmarks/systems_front_door.json")
    parser.add_argument("--baseline", help="git revision to time against in the same run")
    parser.add_argument("--functions", help="every fit's function set (default: gpjax's, or "
                        "add,sub,mul,sign where the truth has dry friction)")
    args = parser.parse_args()
    path = Path(args.json)
    rows = json.loads(path.read_text())["rows"] if path.is_file() else []
    done = {(r["system"], r["seed"]) for r in rows}
    with tempfile.TemporaryDirectory() as folder, (
            baseline_tree(args.baseline) if args.baseline else contextlib.nullcontext()) as tree:
        baseline = (args.baseline, tree) if args.baseline else None
        for name in args.systems.split(","):
            get_system(name)
            for seed in range(args.seeds):
                if (name, seed) in done:
                    continue
                row = run_one(name, seed, Path(folder), baseline, args.functions)
                rows.append(row)
                old = row.get("baseline")
                print(f"{name} seed {seed}: " + (f"ERROR {row['error']}" if "error" in row else
                      f"structure {'right' if row['structure_right'] else 'WRONG'}, max "
                      f"constant error {row['max_constant_error']:.2%}, extrapolation NRMS "
                      + ", ".join(f"{e:.2%}" for e in row["extrapolation_nrms"])
                      + f", {row['seconds']:.0f} s"
                      + (f" ({old['seconds']:.0f} s at {old['revision']}, same equations: "
                         f"{old['same_equations']})" if old else "")), flush=True)
                path.write_text(json.dumps({**provenance(), "rows": rows}, indent=1))
    print(front_door_rows({"rows": rows}))


if __name__ == "__main__":
    main()
