"""The drifting stage on held-out seeds: the diagnosis of a positioning stage measured in
position only, its constants drawn per seed, with and without noise on the measured force.

Usage: python benchmarks/stage_diagnose.py [--seeds S ...] [--input-noise K ...] [--json FILE]

Per seed the stage of :mod:`gpjax.systems` (m·x'' + c·x' + F·sign(x') + f0 = u in its PD
loop, position read by a 1 µm encoder, nothing else measured) gets constants drawn with
that seed: m 0.5–5 kg, c 1–10 N·s/m, F 0.5–4 N, f0 −1…1 N. The diagnosis starts from
m·x'' + c·x' = u (equation-error mode: the free mass drifts in open-loop simulation). A
case passes when Coulomb friction is among the effects added and the refitted m and c are
within 10 % of the truth; F and f0 are reported beside. Rows are written as each
case ends.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from gpjax import Measurement, Model, Symbols, diagnose
from gpjax.systems import generate, get_system

from _provenance import provenance

SYMBOLS = Symbols("x", "t", ("u",))
#: Seeds whose stages were examined while the equation-error mode was improved: 201–210
#: for the pair search (201, 203, 205 failed before it; the slow test uses 203), 301–310
#: for the consensus refit (306 and 310 missed the mass before it). Never reported.
DEVELOPMENT_SEEDS = tuple(range(201, 211)) + tuple(range(301, 311))
#: Seeds of the reported run.
REPORTING_SEEDS = tuple(range(401, 411))


def draw_stage(seed: int):
    """The stage with constants drawn by ``seed`` (module docstring)."""
    rng = np.random.default_rng(seed)
    constants = {"m": rng.uniform(0.5, 5.0), "c": rng.uniform(1.0, 10.0),
                 "F": rng.uniform(0.5, 4.0), "f0": rng.uniform(-1.0, 1.0)}
    return dataclasses.replace(get_system("stage"), constants=constants)


def run(seed: int, input_noise: float) -> dict:
    """One case: what the diagnosis added and the refitted constants against the truth."""
    system = draw_stage(seed)
    record = generate(system, seed=seed, noise=0.0, input_noise=input_noise).fit
    data = Measurement(time=record.time, response=record.response_measured[0],
                       inputs={"u": record.input_measured}, time_name="t", response_name="x")
    start = Model.single(SYMBOLS, mass=1.0, state={"x_dot": 1.0}, forcing={"u": 1.0},
                  input_interpolation="hold")
    began = time.perf_counter()
    result = diagnose(data, start)
    seconds = time.perf_counter() - began
    c = result.after.coefficients
    truth = system.constants
    friction = [float(v) for k, v in c.state.items() if k.has(SYMBOLS.x_dot) and k.func.__name__
                == "tanh"]
    offset = [-float(v) for k, v in c.forcing.items() if k == 1]
    row = {"seed": seed, "input_noise": input_noise, "truth": truth, "mode": result.mode,
           "added": result.effects_added, "m": float(c.mass),
           "c": float(c.state.get(SYMBOLS.x_dot, np.nan)),
           "F": friction[0] if friction else None, "f0": offset[0] if offset else None,
           "seconds": seconds}
    row["m_error"] = row["m"] / truth["m"] - 1
    row["c_error"] = row["c"] / truth["c"] - 1
    row["passed"] = bool("coulomb_friction" in row["added"]
                         and abs(row["m_error"]) <= 0.1 and abs(row["c_error"]) <= 0.1)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", nargs="+", type=int, default=list(REPORTING_SEEDS))
    parser.add_argument("--input-noise", nargs="+", type=float, default=[0.0, 0.02],
                        help="noise on the measured force, × its std")
    parser.add_argument("--json", default=str(Path(__file__).with_name("stage_diagnose.json")))
    args = parser.parse_args()
    examined = sorted(set(args.seeds) & set(DEVELOPMENT_SEEDS))
    if examined:
        parser.error(f"seeds {examined} were examined during development; report on "
                     f"{REPORTING_SEEDS}")
    rows = []
    print("| seed | force noise | added | m (truth) | c (truth) | F (truth) | f0 (truth) | "
          "passed | s |")
    for seed in args.seeds:
        for noise in args.input_noise:
            row = run(seed, noise)
            rows.append(row)
            t = row["truth"]
            print(f"| {seed} | {noise:g} | {', '.join(row['added'])} | {row['m']:.3f} "
                  f"({t['m']:.3f}) | {row['c']:.3f} ({t['c']:.3f}) | "
                  f"{row['F'] if row['F'] is None else round(row['F'], 3)} ({t['F']:.3f}) | "
                  f"{row['f0'] if row['f0'] is None else round(row['f0'], 3)} ({t['f0']:.3f}) | "
                  f"{'yes' if row['passed'] else 'no'} | {row['seconds']:.0f} |", flush=True)
            Path(args.json).write_text(json.dumps(
                {**provenance(), "passed": sum(r["passed"] for r in rows), "cases": len(rows), "rows": rows},
                indent=2) + "\n", encoding="utf-8")
    print(f"passed {sum(r['passed'] for r in rows)} of {len(rows)}")


if __name__ == "__main__":
    main()
