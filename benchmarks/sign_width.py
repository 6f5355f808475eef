"""What a narrower smoothed sign costs and buys on stick–slip (``stribeck_resolved``).

gpjax searches with sign(x') as tanh(x'/ε), ε = ``SIGN_WIDTH`` × RMS x' (:mod:`gpjax._features`),
and narrows the reported model's ε until its response no longer depends on it
(:mod:`gpjax._sign_width`); this script measures that dependence on the true law.
For each seed and each width (as a fraction of RMS x'), the system's true constants are
written as a model file with that tanh and simulated from the true initial state, driven by
the measured input, by the run's fixed-step RK4 at 1, 2, 4, … steps per sample and by the
reference solve (diffrax Dopri8). Reported per width:

* the fewest RK4 steps per sample whose response is within the convergence tolerance
  (1 % of the reference's RMS residual against the data, :mod:`gpjax._convergence`), the
  cost of integrating that width — the baseline is the default width in the same run;
* the reference response's NRMS against the generator's noise-free response (exact sign,
  true input): the smoothed law's creep while the true mass sticks, on top of a floor from
  the measured input's 1 % noise that no width removes;
* with ``--refit``: the law's terms refitted to the record at that width (held) and step
  count, by gpjax's own estimator (weak-form start, Levenberg–Marquardt to convergence):
  the constants the smoothed sign biases, v_s and Fs − Fc above all.

    python benchmarks/sign_width.py --seeds 5 --json sign_width.json
    python benchmarks/sign_width.py --first-seed 1 --seeds 1 --widths 0.01,0.0025,0.000625 \
        --refit --json sign_width_refit.json
"""

from __future__ import annotations

import argparse
import json
import statistics

import numpy as np
import sympy as sp

from gpjax import GPConfig, Model
from gpjax._canonical import CanonicalForm
from gpjax._convergence import MAX_SUBSTEPS, check_model
from gpjax._features import SIGN_WIDTH
from gpjax._fitness import Fitness
from gpjax.systems import generate, get_system

from _provenance import provenance

SYSTEM = "stribeck_resolved"
TOLERANCE = 0.01


def model_file(constants: dict, width: float, y0: tuple[float, float], substeps: int) -> dict:
    """The true Stribeck law with sign(x') as tanh(x'/width), as a model file."""
    sign = f"tanh(x_dot/{width!r})"
    c = constants
    return {"variables": {"time": "t", "response": "x", "inputs": ["u"]},
            "initial_conditions": {"response": y0[0], "response_dot": y0[1]},
            "canonical": {"mass": c["m"], "forcing": [{"feature": "u", "coefficient": 1.0}],
                          "terms": [{"feature": "x", "coefficient": c["k"]},
                                    {"feature": "x_dot", "coefficient": c["c"]},
                                    {"feature": sign, "coefficient": c["Fc"]},
                                    {"feature": f"exp(-(x_dot/{c['vs']!r})**2)*{sign}",
                                     "coefficient": c["Fs"] - c["Fc"]}]},
            "simulation": {"integrator": {"method": "rk4", "substeps": substeps}}}


def measure(seed: int, record, fraction: float) -> dict:
    """Fewest converged RK4 steps per sample and creep NRMS for one seed's fit record and
    one width."""
    velocity, truth = record.velocity_true[0], record.response_true[0]
    width = fraction * float(np.sqrt(np.mean(velocity ** 2)))
    y0 = (float(truth[0]), float(velocity[0]))
    constants = get_system(SYSTEM).constants
    substeps = 1
    while True:
        model = Model.from_json(model_file(constants, width, y0, substeps))
        check, reference = check_model(model, record.measurement(), tolerance=TOLERANCE)
        if check.ratio <= TOLERANCE or substeps >= MAX_SUBSTEPS:
            break
        substeps *= 2
    creep = float(np.sqrt(np.mean((reference - truth) ** 2) / np.mean(truth ** 2)))
    return {"seed": seed, "width_fraction": fraction, "substeps": substeps,
            "ratio": check.ratio, "converged": check.ratio <= TOLERANCE, "nrms_vs_exact": creep}


def refit(record, width: float, substeps: int) -> dict:
    """The law's terms (x, x', the sign, the Stribeck member) fitted to ``record`` with the
    sign held at ``width`` (m/s), RK4 at ``substeps``: the constants per unit mass and the
    objective."""
    x, v, u = sp.symbols("x x_dot u")
    fitness = Fitness(record.measurement(), GPConfig(
        population=8, generations=1, functions=("add", "mul", "tanh", "exp")),
        substeps=substeps)
    c = get_system(SYSTEM).constants
    sign = sp.tanh(v / width)
    bump = sp.exp(-(v / c["vs"]) ** 2) * sign
    held = (fitness.evaluator.inner_of(sign)[0].start,
            fitness.evaluator.inner_of(bump)[0].start + 1)
    form = CanonicalForm(mass=c["m"], state=((x, c["k"]), (v, c["c"]), (sign, c["Fc"]),
                                             (bump, c["Fs"] - c["Fc"])), forcing=((u, 1.0),))
    fitness.score_forms({"law": form}, {"law": held})
    law = fitness.records["law"]
    fitness.refine([law], to_convergence=True)
    k = law.coefficients
    per_mass = {f: value / k.mass for f, value in k.state.items()}
    member, = [f for f in per_mass if f.has(sp.exp)]
    friction, = [f for f in per_mass if f.func == sp.tanh]
    scale, = [a for a in member.args if a.func == sp.exp]
    return {"objective": law.objective, "m": k.mass, "k": per_mass[x], "c": per_mass[v],
            "Fc": per_mass[friction], "Fs-Fc": per_mass[member],
            "vs": float(1.0 / sp.sqrt(-scale.args[0] / v ** 2))}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=5, help="how many seeds (default 5)")
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--refit", action="store_true",
                        help="also refit the law's constants at each width (slow)")
    parser.add_argument("--widths", default=f"{SIGN_WIDTH},{SIGN_WIDTH / 4},{SIGN_WIDTH / 16}",
                        help="sign widths as fractions of RMS x' (the first is the baseline)")
    parser.add_argument("--json", help="write the rows and the summary to this file")
    args = parser.parse_args(argv)
    fractions = [float(w) for w in args.widths.split(",")]
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    records = {seed: generate(SYSTEM, seed=seed).fit for seed in seeds}
    rows = [measure(seed, records[seed], f) for f in fractions for seed in seeds]
    if args.refit:
        print("| seed | ε / RMS x' | RK4 steps | v_s | Fs − Fc | Fc | c | k | objective |\n"
              "| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
        for row in rows:
            velocity = records[row["seed"]].velocity_true[0]
            width = row["width_fraction"] * float(np.sqrt(np.mean(velocity ** 2)))
            row["refit"] = fitted = refit(records[row["seed"]], width, row["substeps"])
            print(f"| {row['seed']} | {row['width_fraction']:g} | {row['substeps']} | "
                  + " | ".join(f"{fitted[k]:.4f}" for k in ("vs", "Fs-Fc", "Fc", "c", "k"))
                  + f" | {fitted['objective']:.5f} |", flush=True)
    base = statistics.median(r["substeps"] for r in rows if r["width_fraction"] == fractions[0])
    summary = []
    print("| ε / RMS x' | RK4 steps per sample (seeds) | cost vs default | "
          "NRMS vs exact sign, median |\n| --- | --- | --- | --- |")
    for f in fractions:
        mine = [r for r in rows if r["width_fraction"] == f]
        steps = [r["substeps"] for r in mine]
        line = {"width_fraction": f, "substeps": steps,
                "cost_ratio": statistics.median(steps) / base,
                "nrms_vs_exact_median": statistics.median(r["nrms_vs_exact"] for r in mine)}
        summary.append(line)
        print(f"| {f:g} | {', '.join(map(str, steps))} | {line['cost_ratio']:.1f}× | "
              f"{100 * line['nrms_vs_exact_median']:.3f} % |")
    if args.json:
        with open(args.json, "w") as out:
            json.dump({**provenance(), "system": SYSTEM, "tolerance": TOLERANCE, "rows": rows,
                       "summary": summary}, out, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
