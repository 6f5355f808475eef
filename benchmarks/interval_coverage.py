"""How often the 95 % intervals of the constants cover the truth (issue 44).

    python benchmarks/interval_coverage.py --seeds 40 --json benchmarks/interval_coverage.json
    python benchmarks/interval_coverage.py --seeds 40 --json benchmarks/interval_coverage.json --resume

For four systems of the catalogue, each seed a record with 1 % noise on the response(s)
*and* on the measured input (:func:`gpjax.systems.generate`): Duffing (polynomial), Duffing
under a static load (a constant force, fitted by the spectrum's zero bin alone), the
pendulum (k·sin x: a non-polynomial family with its frequency and phase refined too) and
the 2-mass chain (two coordinates, cubic coupling). For the demo's gear (eq. 14, undamped:
the initial state's free oscillation never decays, and the static balance takes nearly all
of the zero bin), the bundled generator's record on that seed
(:func:`gpjax.gear.generate_gear_example`, with its noise on φ and on the torque). Each
record's true structure is fitted from the true constants by gpjax's output-error refit
at converged integration (:func:`gpjax.refit`; :func:`gpjax.engine.fit_system` for the
chain) with band-limited input reconstruction (the records' inputs are band-limited), and
each fitted constant's interval checked against the truth. ``--interpolation linear`` measures what
linear input interpolation does to the same intervals. Rows are written after every seed;
``--resume`` skips the seeds the JSON already holds.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import sympy as sp

from _provenance import provenance

from gpjax import Model, Symbols
from gpjax import refit
from gpjax.engine import fit_system
from gpjax.gear import PAPER_TRUTH, generate_gear_example
from gpjax.systems import generate

SYSTEMS = ("duffing", "duffing_load", "pendulum", "chain2", "gear")
X, XD, U = sp.symbols("x x_dot u")


def _one_coordinate(name: str, truth: dict, interpolation: str):
    """(start model, {constant name: true value}) of a one-coordinate system."""
    duffing = {"x_dot": truth.get("c"), "x": truth.get("k"), "x**3": truth.get("k3")}
    state = {"duffing": duffing, "duffing_load": duffing,
             "pendulum": {"x_dot": truth.get("c"), "sin(x)": truth.get("k")}}[name]
    forcing = {"u": 1.0} | ({"1": -truth["f0"]} if "f0" in truth else {})
    model = Model.single(Symbols("x", "t", ("u",)), mass=truth["m"], state=state,
                         forcing=forcing, input_interpolation=interpolation)
    names = {feature: name for name, (_, _, feature) in model.constant_names().items()}
    values = {"m": truth["m"], **{names[f]: v for f, v in (state | forcing).items()
                                  if f != "u"}}
    if name == "pendulum":  # sin(θ1·x + θ2): frequency 1, phase 0
        values |= {f"{names['sin(x)']}.θ1": 1.0, f"{names['sin(x)']}.θ2": 0.0}
    return model, values


def _chain(truth: dict):
    """(structure, {(equation, feature): true value}) of the 2-mass chain; equation 2 has no
    input, so its mass is held at 1 and its constants are the truth's over m2."""
    x1, x2, v1, v2 = sp.symbols("x1 x2 x1_dot x2_dot")
    structure = (((v1, x1, x1 - x2, (x1 - x2) ** 3), {U: 1.0}),
                 ((v2, x2, x2 - x1, (x2 - x1) ** 3), {}))
    values = {(0, ""): truth["m1"]}
    for e, (state, _) in enumerate(structure):
        scale = 1.0 if e == 0 else truth["m2"]
        for feature, key in zip(state, ("c", "k", "kc", "k3")):
            values[(e, str(feature))] = truth[key] / scale
    return structure, values


def _gear(seed: int, interpolation: str):
    """(start model at the truth, {constant name: true value}, record) of eq. 14 from the
    bundled generator on ``seed``."""
    example = generate_gear_example(seed=seed)
    model = Model.single(Symbols("phi", "t", ("T",)), mass=PAPER_TRUTH["J"],
                         state={"phi": PAPER_TRUTH["K1"], "phi**2": PAPER_TRUTH["K2"]},
                         forcing={"T": 1.0}, input_interpolation=interpolation)
    values = {"m": PAPER_TRUTH["J"], "k1": PAPER_TRUTH["K1"], "k2": PAPER_TRUTH["K2"]}
    return model, values, example.measurement


def run_seed(system: str, seed: int, interpolation: str) -> dict:
    """One record's fit: per constant its value, standard error, interval and truth."""
    if system == "gear":
        model, values, record = _gear(seed, interpolation)
    else:
        synthetic = generate(system, seed=seed, noise=0.01, input_noise=0.01)
        if system != "chain2":
            model, values = _one_coordinate(system, synthetic.truth, interpolation)
            record = synthetic.fit.measurement()
    began = time.perf_counter()
    if system == "chain2":
        structure, values = _chain(synthetic.truth)
        fit = fit_system(synthetic.fit.system_measurement(), structure,
                         input_interpolation=interpolation)
        uncertainty, converged = fit.uncertainty, fit.checks[-1].converged
        names = {(e, feature): name for name, (e, _, feature)
                 in fit.model.constant_names().items()}
        values = {names[key]: true for key, true in values.items()}
    else:
        fitted = refit(model, record)
        uncertainty, converged = fitted.uncertainty, fitted.convergence["converged"]
    seconds = time.perf_counter() - began
    constants = {}
    for name, true in values.items():
        low, high = uncertainty.interval(name)
        value = float(uncertainty.values[uncertainty.names.index(name)])
        constants[name] = {"truth": true, "value": value,
                           "se": uncertainty.standard_errors[name],
                           "dof": float(uncertainty.dof[uncertainty.names.index(name)]),
                           "low": low, "high": high, "covered": bool(low <= true <= high)}
    return {"system": system, "seed": seed, "interpolation": interpolation,
            "revision": provenance()["revision"],
            "converged": bool(converged), "seconds": seconds, "constants": constants}


def summary(rows: list[dict]) -> list[dict]:
    """Per system and interpolation: seeds, coverage per constant and over all constants,
    the mean |z| and the median interval half-width relative to the truth."""
    out = []
    for key in sorted({(r["system"], r["interpolation"]) for r in rows}):
        group = [r for r in rows if (r["system"], r["interpolation"]) == key]
        names = list(group[0]["constants"])
        per = {n: float(np.mean([r["constants"][n]["covered"] for r in group])) for n in names}
        z = [abs(c["value"] - c["truth"]) / c["se"] for r in group
             for c in r["constants"].values()]
        half = [(c["high"] - c["low"]) / 2 / abs(c["truth"]) for r in group
                for c in r["constants"].values() if c["truth"] != 0]
        out.append({"system": key[0], "interpolation": key[1], "seeds": len(group),
                    "revisions": sorted({r.get("revision", "?") for r in group}),
                    "coverage": float(np.mean([c["covered"] for r in group
                                               for c in r["constants"].values()])),
                    "coverage_per_constant": per, "mean_abs_z": float(np.mean(z)),
                    "median_relative_half_width": float(np.median(half)),
                    "median_seconds": float(np.median([r["seconds"] for r in group]))})
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=40)
    parser.add_argument("--systems", default=",".join(SYSTEMS))
    parser.add_argument("--interpolation", default="bandlimited",
                        choices=("bandlimited", "linear"))
    parser.add_argument("--json", required=True)
    parser.add_argument("--resume", action="store_true")
    args = parser.parse_args()
    path = Path(args.json)
    rows = json.loads(path.read_text())["rows"] if args.resume and path.is_file() else []
    done = {(r["system"], r["seed"], r["interpolation"]) for r in rows}
    for system in args.systems.split(","):
        for seed in range(args.seeds):
            if (system, seed, args.interpolation) in done:
                continue
            row = run_seed(system, seed, args.interpolation)
            rows.append(row)
            missed = [n for n, c in row["constants"].items() if not c["covered"]]
            print(f"{system} seed {seed} ({args.interpolation}): {row['seconds']:.1f} s, "
                  f"missed {missed or 'none'}", flush=True)
            path.write_text(json.dumps({**provenance(), "rows": rows,
                                        "summary": summary(rows)}, indent=1) + "\n")
    print(f"{'system':<10} {'input':<12} {'seeds':>5} {'coverage':>9} {'mean |z|':>9}  per constant")
    for s in summary(rows):
        per = ", ".join(f"{n} {c:.0%}" for n, c in s["coverage_per_constant"].items())
        print(f"{s['system']:<10} {s['interpolation']:<12} {s['seeds']:>5} {s['coverage']:>9.1%} "
              f"{s['mean_abs_z']:>9.2f}  {per}")


if __name__ == "__main__":
    sys.exit(main())
