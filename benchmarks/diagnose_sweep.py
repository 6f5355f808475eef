"""Diagnosis sweep: each library effect undeclared in gear data, over seeds and strengths.

Usage: python benchmarks/diagnose_sweep.py [--json FILE] [--cases SEED:STRENGTH ...]
       [--controls SEED ...]

Runs :func:`gpjax.diagnose` on every case of :func:`gpjax.gear.undeclared_effect_case`
(the same cases as ``pytest -m sweep``) and prints, per case, the effects added, whether
the missing effect was named first, the RMS before the first step (loop fit) and after
(final structure refitted on the whole record) and of the generating model (true
constants, simulated by the same engine on the noisy measured torque) in units of the noise
σ = 2e-5 deg, and the seconds taken; with the first step's fitted nonlinear parameters and
the truth, the table and the totals are written as JSON. A case passes as in the tests:
named first, visible (> 3σ before), and after ≤ max(1.5σ, the generating model's RMS).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from gpjax import diagnose
from gpjax.gear import EFFECTS, NOISE_PHI, undeclared_effect_case

CASES = ("21:0.7", "22:1.4", "23:1.0", "24:1.2")
CONTROLS = (31, 32, 33, 34)


def run(name: str, seed: int, strength: float) -> dict:
    case = undeclared_effect_case(name, seed=seed, strength=strength)
    began = time.perf_counter()
    result = diagnose(case.measurement, case.start, frequencies=(285.0,))
    seconds = time.perf_counter() - began
    first = result.steps[0] if result.steps else None
    truth_sigma = case.truth_rms() / NOISE_PHI
    row = {"effect": name, "seed": seed, "strength": strength,
           "added": result.effects_added, "named_first": result.effects_added[:1] == [name],
           "rms_before_sigma": (first["rms_before"] if first else
                                result.before.metrics["rms"]) / NOISE_PHI,
           "rms_after_sigma": result.after.metrics["rms"] / NOISE_PHI,
           "truth_rms_sigma": truth_sigma,
           "truth": case.truth, "parameters": first["parameters"] if first else {},
           "seconds": seconds}
    row["passed"] = (row["added"] == [] if name == "control" else
                     row["named_first"] and row["rms_before_sigma"] > 3
                     and row["rms_after_sigma"] <= max(1.5, truth_sigma))
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", default=str(Path(__file__).with_name("diagnose_sweep.json")))
    parser.add_argument("--cases", nargs="+", default=list(CASES))
    parser.add_argument("--controls", nargs="*", type=int, default=list(CONTROLS))
    args = parser.parse_args()
    rows = []
    print("| effect | seed | strength | added | first? | RMS before / σ | after / σ | "
          "true model / σ | s |")
    for text in args.cases:
        seed, strength = int(text.split(":")[0]), float(text.split(":")[1])
        for name in EFFECTS:
            rows.append(run(name, seed, strength))
            _print(rows[-1])
    for seed in args.controls:
        rows.append(run("control", seed, 1.0))
        _print(rows[-1])
    effects_rows = [r for r in rows if r["effect"] != "control"]
    totals = {"cases": len(effects_rows),
              "named_first": sum(r["named_first"] for r in effects_rows),
              "passed": sum(r["passed"] for r in effects_rows),
              "controls_clean": sum(r["passed"] for r in rows if r["effect"] == "control"),
              "controls": len(args.controls),
              "worst_rms_after_sigma": max(r["rms_after_sigma"] for r in effects_rows),
              "seconds_total": sum(r["seconds"] for r in rows)}
    print(json.dumps(totals))
    Path(args.json).write_text(json.dumps({"totals": totals, "rows": rows}, indent=2) + "\n",
                               encoding="utf-8")


def _print(row: dict) -> None:
    print(f"| {row['effect']} | {row['seed']} | {row['strength']} | {', '.join(row['added'])} "
          f"| {'yes' if row['named_first'] else 'no'} | {row['rms_before_sigma']:.2f} | "
          f"{row['rms_after_sigma']:.2f} | {row['truth_rms_sigma']:.2f} | {row['seconds']:.0f} |",
          flush=True)


if __name__ == "__main__":
    main()
