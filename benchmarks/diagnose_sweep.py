"""Diagnosis sweep on held-out seeds: effects × seeds × measured-torque noise levels, and
controls.

Usage: python benchmarks/diagnose_sweep.py [--json FILE] [--seeds S ...] [--noise K ...]
       [--effects NAME ...] [--no-controls] [--resume] [--rescore] [--merge FILE ...]
       python benchmarks/diagnose_sweep.py --nearest [--seeds S ...] [--json FILE]

Rows are written to ``--json`` as each case ends, each with the revision it ran at, so a run
cut short is still evidence; ``--resume`` keeps the rows of ``--json`` that record a revision
and runs only the other cases (a row of an earlier file without one is replaced when its
case runs again); ``--merge`` joins the files of runs made in parts, a case's row from a
later file replacing an earlier file's.

Runs :func:`gpjax.diagnose` on the cases of :func:`gpjax.gear.undeclared_effect_case`
(every library effect, the effects outside the library of :data:`gpjax.gear.OUTSIDE`, and
the control, which adds nothing), with the recorded torque's noise 1×, 4× and 10× the
bundled example's. Seeds are named apart (:mod:`gpjax.gear._undeclared`): ``TUNING_SEEDS``
are every seed the method was developed or tested on, ``REPORTING_SEEDS`` were never looked
at before the method was fixed — the sweep refuses to report on a tuning seed. Per case:
the effects added, whether the right one (outside the library: one of the nearest,
``NEAREST``) came first,
the final RMS against the true model's (simulated by the same engine on the torque the
diagnosis simulates with) and seconds. A case passes: a control adds nothing; a library
effect is named first and the final RMS ≤ 1.5 × the true model's; an outside effect adds
only nearest effects, and either reaches 1.5 × the true model's RMS or the report says that
the residual stays unexplained (and describes it).

``--nearest`` checks the ``NEAREST`` table itself, without any diagnosis: per effect outside
the library and seed, the share of the undeclared force each library effect removes
(:meth:`gpjax.gear.UndeclaredEffectCase.missing_force_shares`), best first.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from gpjax import diagnose
from gpjax.gear import (EFFECTS, NEAREST, NOISE_LEVELS, NOISE_PHI, OUTSIDE, REPORTING_SEEDS,
                        TUNING_SEEDS, undeclared_effect_case)

from _provenance import provenance


def run(name: str, seed: int, torque_noise: float) -> dict:
    """One case: the diagnosis, what it added and whether it passes (module docstring)."""
    case = undeclared_effect_case(name, seed=seed, torque_noise=torque_noise)
    began = time.perf_counter()
    result = diagnose(case.measurement, case.start, frequencies=(285.0,))
    seconds = time.perf_counter() - began
    return score({"effect": name, "seed": seed, "torque_noise": torque_noise,
                  "added": result.effects_added,
                  "rms_after_sigma": result.after.metrics["rms"] / NOISE_PHI,
                  "truth_rms_sigma": case.truth_rms(result.measurement,
                                                    settings=result.settings) / NOISE_PHI,
                  "substeps": result.settings["substeps"],
                  "truth_rms_measured_torque_sigma": case.truth_rms() / NOISE_PHI,
                  "p_values": [s["test"]["p_adjusted"] for s in result.steps],
                  "unexplained": result.unexplained is not None,
                  "noise_floor_ratio": (result.noise.get("after") or {}).get("ratio"),
                  "seconds": seconds, "revision": provenance()["revision"]})


def score(row: dict) -> dict:
    """``row`` with ``kind``, ``named_first``, ``spurious`` and ``passed`` (module
    docstring)."""
    name, added = row["effect"], row["added"]
    row["kind"] = "control" if name == "control" else "outside" if name in OUTSIDE else "library"
    allowed = NEAREST.get(name, (name,))
    row["named_first"] = bool(added) and added[0] in allowed
    row["spurious"] = added if name == "control" else [a for a in added if a not in allowed]
    within = row["rms_after_sigma"] <= 1.5 * row["truth_rms_sigma"]
    if name == "control":
        row["passed"] = added == []
    elif name in NEAREST:
        row["passed"] = not row["spurious"] and (within or row["unexplained"])
    else:
        row["passed"] = row["named_first"] and within
    return row


def totals(rows: list[dict]) -> dict:
    """Pass rates by kind (control, library effect, outside effect) and noise level."""
    out = {}
    for kind, keep in (("control", lambda r: r["effect"] == "control"),
                       ("library", lambda r: r["effect"] in EFFECTS),
                       ("outside", lambda r: r["effect"] in OUTSIDE)):
        for noise in sorted({r["torque_noise"] for r in rows}):
            chosen = [r for r in rows if keep(r) and r["torque_noise"] == noise]
            if chosen:
                out[f"{kind}@{noise:g}x"] = {
                    "cases": len(chosen), "passed": sum(r["passed"] for r in chosen),
                    "named_first": sum(r["named_first"] for r in chosen),
                    "with_spurious": sum(bool(r["spurious"]) for r in chosen),
                    "within_1.5x_truth": sum(r["rms_after_sigma"] <= 1.5 * r["truth_rms_sigma"]
                                             for r in chosen),
                    "seeds": sorted({r["seed"] for r in chosen})}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", help="output (default: diagnose_sweep.json, with --nearest "
                                       "diagnose_nearest.json, beside this script)")
    parser.add_argument("--seeds", nargs="+", type=int, default=list(REPORTING_SEEDS))
    parser.add_argument("--noise", nargs="+", type=float, default=list(NOISE_LEVELS))
    parser.add_argument("--effects", nargs="*", default=list(EFFECTS + OUTSIDE))
    parser.add_argument("--no-controls", action="store_true")
    parser.add_argument("--resume", action="store_true",
                        help="keep the rows of --json that record a revision; run the rest")
    parser.add_argument("--rescore", action="store_true",
                        help="re-score the rows of --json with this version's criteria")
    parser.add_argument("--merge", nargs="+", metavar="FILE",
                        help="write the rows of these sweep files, re-scored, into --json")
    parser.add_argument("--nearest", action="store_true",
                        help="the share of each outside effect's force each library effect "
                             "removes (no diagnosis)")
    args = parser.parse_args()
    if args.nearest:
        _nearest(args.seeds, args.json or str(Path(__file__).with_name("diagnose_nearest.json")))
        return
    args.json = args.json or str(Path(__file__).with_name("diagnose_sweep.json"))
    if args.rescore or args.merge:
        files = args.merge or [args.json]
        cases = {_case(r): score(r) for f in files
                 for r in json.loads(Path(f).read_text())["rows"]}
        rows = list(cases.values())
        _write(args.json, rows)
        print(json.dumps(totals(rows), indent=1))
        return
    tuning = sorted(set(args.seeds) & set(TUNING_SEEDS))
    if tuning:
        parser.error(f"seeds {tuning} were used for tuning; report on {REPORTING_SEEDS}")
    # controls first, then seed by seed, so that a cut-short run covers every effect
    order = [("control", noise, seed) for noise in args.noise for seed in args.seeds
             if not args.no_controls]
    order += [(name, noise, seed) for seed in args.seeds for noise in args.noise
              for name in args.effects]
    resumed = args.resume and Path(args.json).exists()
    rows = json.loads(Path(args.json).read_text())["rows"] if resumed else []
    done = {_case(r) for r in rows if r.get("revision")}
    order = [case for case in order if case not in done]
    print("| effect | seed | torque noise | added | first? | after / σ | true model / σ | "
          "passed | s |")
    for name, noise, seed in order:
        rows = [r for r in rows if _case(r) != (name, noise, seed)] + [run(name, seed, noise)]
        _print(rows[-1])
        _write(args.json, rows)
    print(json.dumps(totals(rows), indent=1))


def _case(row: dict) -> tuple:
    return row["effect"], row["torque_noise"], row["seed"]


def _nearest(seeds: list[int], path: str) -> None:
    """Print and write, per outside effect and seed, the library effects' shares of the
    undeclared force, best first, and whether the best is in ``NEAREST``."""
    rows = []
    print("| effect | seed | best (share) | second | third | best in NEAREST |")
    for name in OUTSIDE:
        for seed in seeds:
            shares = undeclared_effect_case(name, seed=seed).missing_force_shares()
            ranked = sorted(shares.items(), key=lambda item: -item[1])
            rows.append({"effect": name, "seed": seed, "shares": dict(ranked),
                         "best_in_nearest": ranked[0][0] in NEAREST[name]})
            print(f"| {name} | {seed} | " + " | ".join(f"{k} ({v:.3f})" for k, v in ranked[:3])
                  + f" | {'yes' if rows[-1]['best_in_nearest'] else 'no'} |", flush=True)
    Path(path).write_text(json.dumps({**provenance(), "nearest": NEAREST, "rows": rows}, indent=2) + "\n",
                          encoding="utf-8")


def _write(path: str, rows: list[dict]) -> None:
    Path(path).write_text(json.dumps({**provenance(), "tuning_seeds": TUNING_SEEDS,
                                      "reporting_seeds": REPORTING_SEEDS,
                                      "totals": totals(rows), "rows": rows}, indent=2) + "\n",
                          encoding="utf-8")


def _print(row: dict) -> None:
    print(f"| {row['effect']} | {row['seed']} | {row['torque_noise']:g} | "
          f"{', '.join(row['added'])} | {'yes' if row['named_first'] else 'no'} | "
          f"{row['rms_after_sigma']:.2f} | {row['truth_rms_sigma']:.2f} | "
          f"{'yes' if row['passed'] else 'no'} | {row['seconds']:.0f} |", flush=True)


if __name__ == "__main__":
    main()
