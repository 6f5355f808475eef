"""Physics benchmark: synthetic systems with a known truth (gpjax.systems), gpjax with and
without local search, and peers (PySINDy, pyoperon) on the same records, all scored by
the same converged simulator.

For each system and seed: :func:`gpjax.systems.generate` makes the fit record (1 %
noise on response and input) and the extrapolation record (another input realisation,
amplitude × ``--scale``). Every method fits the fit record's measured response and
measured input. Its equation is then simulated on the extrapolation record by
:func:`gpjax.systems.simulate_equations` — scipy DOP853, rtol 1e-10, atol 1e-12, the
true input samples joined by a cubic spline (the same for every method), from the true
initial state — and compared with the true response: NRMS = RMS(error) / RMS(true).
Structure and constants by :func:`gpjax.systems.compare_structure` (constants within 2 %
after normalising by the input's coefficient; see :mod:`gpjax._scoring` for the rule).
The ``truth`` rows score the true equations: the scorer's floor. They also carry the
Cramér–Rao floor of the truth's constants on the fit record
(:func:`gpjax.systems.cramer_rao`), tabled as the least identifiable constant and the
best chance any unbiased method has of getting it within 2 %. The ``truth-refit`` rows
are the true structure with its constants refitted to the measured data
(:func:`gpjax.systems.truth_refit`: least squares through the exact integrator, driven by
the measured input): "constants within 2 %" that they miss is the data's limit, one that
they reach and gpjax misses is gpjax's.

    python benchmarks/physics_suite.py --quick --json out.json
    python benchmarks/physics_suite.py --seeds 5 --population 500 --generations 10 \\
        --peers pysindy,pyoperon --json benchmarks/physics_suite.json
    python benchmarks/physics_suite.py --rescore part1.json part2.json --json all.json
    python benchmarks/physics_suite.py ... --json benchmarks/physics_suite.json --resume  # in chunks
    python benchmarks/physics_suite.py --first-seed 5 --seeds 3 --noise 0.03 --json held_out.json
    python benchmarks/physics_suite.py --methods truth,truth-refit --json refit.json

``--first-seed`` and ``--noise`` run seeds and noise levels the suite's table never saw
(the engine's choices were made looking at seeds 0–4 at 1 %).

``--rescore`` merges the rows of earlier runs (one per system, say; a later file's row
replaces an earlier file's row of the same system, method and seed) and decides structure
and constants again from their equations with the current rule.

A failed fit or simulation is a row with its error text, not a crash of the suite.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import statistics
import sys
import time
import traceback
from pathlib import Path

import numpy as np
import sympy as sp

sys.path.insert(0, str(Path(__file__).resolve().parent))

import gpjax  # noqa: E402
from gpjax._config import WIDE_FUNCTIONS  # noqa: E402
from gpjax._scoring import TOLERANCE  # noqa: E402
from gpjax.systems import (PHYSICS_SUITE, compare_structure, cramer_rao,  # noqa: E402
                           generate, simulate_equations, nrms, truth_refit)
from _peers import PEERS, fit_peer, versions  # noqa: E402
from _provenance import provenance  # noqa: E402

QUICK = {"systems": "duffing,coulomb_viscous", "seeds": 1, "population": 100,
         "generations": 3}
#: gpjax's default function set here: eq. 10's and the unary functions of mechanics (one
#: set for every system; a user does not know the physics beforehand).
FUNCTIONS = WIDE_FUNCTIONS
#: The methods of gpjax's own (the peers are chosen with ``--peers``).
METHODS = ("truth", "truth-refit", "gpjax", "gpjax-no-local-search")
#: A simulated state beyond this multiple of the true record's largest |x| or |x'| counts
#: as diverged.
DIVERGED = 100.0


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if args.rescore:
        return _rescore(args)
    if args.quick:
        for key, value in QUICK.items():
            setattr(args, key, value)
    systems = args.systems.split(",")
    peers = [p for p in args.peers.split(",") if p]
    unknown = [p for p in peers if p not in PEERS]
    if unknown:
        raise SystemExit(f"unknown peer {unknown[0]!r}; use one of {PEERS}")
    chosen = args.methods.split(",")
    unknown = [m for m in chosen if m not in METHODS]
    if unknown:
        raise SystemExit(f"unknown method {unknown[0]!r}; use one of {','.join(METHODS)}")
    rows = []
    if args.resume:
        if not (args.json and Path(args.json).is_file()):
            raise SystemExit("--resume needs --json FILE from an earlier run of this command")
        rows = json.loads(Path(args.json).read_text(encoding="utf-8"))["rows"]
    done = {(r["system"], r["seed"], r.get("noise", 0.01), r["method"]) for r in rows}
    revision = provenance()["revision"]
    for name in systems:
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            data = generate(name, seed=seed, noise=args.noise, input_noise=args.noise,
                            extrapolation_scale=args.scale)
            methods = [("truth", lambda: data.system.truth()[0]),
                       ("truth-refit", lambda: _truth_refit(data)),
                       ("gpjax", lambda: _gpjax(data, args, seed, local_search=None)),
                       ("gpjax-no-local-search", lambda: _gpjax(data, args, seed, local_search=0))]
            methods = [(m, fit) for m, fit in methods if m in chosen]
            methods += [(peer, lambda peer=peer, name=name, seed=seed: fit_peer(
                peer, data.fit.measurement(), seed=seed,
                seconds=_budget(rows, name, seed, args))) for peer in peers]
            for method, fit in methods:
                if (name, seed, args.noise, method) in done:
                    continue
                row = _row(data, method, fit) | {"revision": revision}
                rows.append(row)
                print(f"{name} seed {seed} {method}: structure {row['structure']} "
                      f"NRMS {row['nrms']} {row['seconds']:.1f} s {row['error'] or ''}",
                      flush=True)
                _write(args, rows, systems, vars(args), quiet=True)  # resumable from here
    _write(args, rows, list(dict.fromkeys(r["system"] for r in rows)), vars(args))
    return 0


def _budget(rows: list[dict], system: str, seed: int, args) -> float:
    """A peer's time budget on a record: gpjax's seconds on it (its row of this run or of
    the resumed file), else ``--peer-seconds``."""
    spent = [r["seconds"] for r in rows if (r["system"], r["seed"], r["method"]) ==
             (system, seed, "gpjax") and r.get("noise", 0.01) == args.noise]
    return spent[-1] if spent else args.peer_seconds


def _rescore(args) -> int:
    """Merge the rows of ``args.rescore`` files; structure and constants decided again."""
    from gpjax._errors import ModelFileError
    from gpjax._expressions import parse_expression

    latest, commands = {}, []
    for path in args.rescore:  # a later file's row replaces one of the same system, method, seed
        payload = json.loads(Path(path).read_text(encoding="utf-8"))
        commands += payload["settings"].get("runs", [payload["command"]])
        latest.update({(r["system"], r["method"], r["seed"]): r for r in payload["rows"]})
    rows = list(latest.values())
    for i, row in enumerate(rows):
        if args.refit_failed and row["error"] and row["method"].startswith("gpjax"):
            data = _generate(row, args.scale)
            settings = argparse.Namespace(**json.loads(Path(args.rescore[0]).read_text(
                encoding="utf-8"))["settings"])
            local = None if row["method"] == "gpjax" else 0
            rows[i] = row = _row(data, row["method"], lambda: _gpjax(
                data, settings, row["seed"], local_search=local)) | {
                "refit_after_error": row["error"]}
        if row["equation"] is None:
            continue
        data = _generate(row, args.scale)
        names = {str(s) for s in data.system.truth()[0].free_symbols} | {"x_ddot", "t"}
        try:
            equation = (data.system.truth()[0] if row["method"] == "truth" else
                        parse_expression(row["equation"], names, allow_equation=True))
        except ModelFileError as err:  # e.g. a peer's function outside the whitelist
            row["rescore_error"] = str(err)
            continue
        verdict = compare_structure(equation, data.system.truth()[0], scales=_scales(data))
        worst = verdict["worst_constant_error"]
        row.update(verdict, worst_constant_error=worst if math.isfinite(worst) else None)
        if row["method"] == "truth" and "cramer_rao" not in row:
            row["cramer_rao"] = cramer_rao(data)
    systems = list(dict.fromkeys(r["system"] for r in rows))
    _write(args, rows, systems, {"runs": commands})
    return 0


def _generate(row: dict, scale: float):
    """The records a row was fitted on (rows before ``--noise`` existed were at 1 %)."""
    noise = row.get("noise", 0.01)
    return generate(row["system"], seed=row["seed"], noise=noise, input_noise=noise,
                    extrapolation_scale=scale)


def _scales(data) -> dict:
    """RMS-like scales of x and x' on the fit record (the structure rule's ranges)."""
    return {sp.Symbol("x"): float(np.std(data.fit.response_measured)),
            sp.Symbol("x_dot"): float(np.std(data.fit.velocity_true))}


def _write(args, rows: list[dict], systems: list[str], settings: dict, *,
           quiet: bool = False) -> None:
    """Print the table (unless ``quiet``) and write every row, with the run's revision,
    command, date and machine, to ``--json``."""
    table = _table(rows, systems)
    if not quiet:
        print(table)
    if args.json:
        payload = {**provenance(), "settings": settings, "peers": versions(),
                   "scorer": "scipy DOP853 rtol 1e-10 atol 1e-12 (Filippov sticking for "
                             "sign laws); true input samples joined by a cubic spline; true "
                             "initial state; NRMS = RMS(error)/RMS(true) on the extrapolation "
                             "record", "table": table, "rows": rows}
        Path(args.json).write_text(json.dumps(payload, indent=1, default=str) + "\n")


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--systems", default=",".join(PHYSICS_SUITE),
                        help="comma-separated names (default: the nine of the suite)")
    parser.add_argument("--seeds", type=int, default=5,
                        help="how many seeds, from --first-seed on (default 5)")
    parser.add_argument("--first-seed", type=int, default=0,
                        help="the first seed (default 0; 5 gives seeds the suite's table "
                             "never saw)")
    parser.add_argument("--noise", type=float, default=0.01,
                        help="noise σ on the response and on the measured input, as a "
                             "fraction of each one's standard deviation (default 0.01)")
    parser.add_argument("--population", type=int, default=500)
    parser.add_argument("--generations", type=int, default=10)
    parser.add_argument("--functions", default=",".join(FUNCTIONS),
                        help="gpjax's function set, the same for every system "
                             f"(default {','.join(FUNCTIONS)})")
    parser.add_argument("--max-degree", type=int, default=3)
    parser.add_argument("--scale", type=float, default=1.2,
                        help="extrapolation input amplitude ÷ fit amplitude (default 1.2)")
    parser.add_argument("--methods", default=",".join(METHODS),
                        help=f"comma-separated, from {','.join(METHODS)} (default all)")
    parser.add_argument("--peers", default="", help=f"comma-separated, from {','.join(PEERS)}")
    parser.add_argument("--peer-seconds", type=float, default=120.0,
                        help="a peer's time budget where gpjax did not run on the record "
                        "(otherwise gpjax's seconds there)")
    parser.add_argument("--json", help="write every row and the command to this file "
                        "(rewritten after every row)")
    parser.add_argument("--resume", action="store_true",
                        help="keep the rows --json already holds and run only the missing "
                        "ones (a long suite in chunks)")
    parser.add_argument("--rescore", nargs="+", metavar="JSON",
                        help="merge these runs' rows and decide structure and constants again")
    parser.add_argument("--refit-failed", action="store_true",
                        help="with --rescore: fit again the gpjax rows that failed (with the "
                             "first file's settings), marked refit_after_error")
    parser.add_argument("--quick", action="store_true",
                        help="smoke run: " + ", ".join(f"{k} {v}" for k, v in QUICK.items()))
    return parser


def _gpjax(data, args, seed: int, *, local_search: int | None) -> sp.Eq:
    config = gpjax.GPConfig(population=args.population, generations=args.generations,
                            functions=tuple(args.functions.split(",")),
                            max_degree=args.max_degree)
    if local_search is not None:
        config = config.replace(local_search=local_search)
    identifier = gpjax.Identifier(config).fit(data.fit.measurement(), seed=seed,
                                              progress=False)
    return identifier.model_.sympy()


def _truth_refit(data) -> sp.Eq:
    """The true equation with the constants :func:`truth_refit` gives on ``data``."""
    return dataclasses.replace(data.system, constants=truth_refit(data)).truth()[0]


def _row(data, method: str, fit) -> dict:
    """Fit, then score on the extrapolation record; failures become the row's error."""
    row = {"system": data.system.name, "seed": data.seed, "noise": data.noise,
           "method": method,
           "equation": None, "structure": False, "constants": False, "nrms": None,
           "seconds": 0.0, "error": None}
    began = time.perf_counter()
    try:
        equation = fit()
        row["seconds"] = time.perf_counter() - began
        row["equation"] = str(equation)
        verdict = compare_structure(equation, data.system.truth()[0], scales=_scales(data))
        worst = verdict["worst_constant_error"]
        row.update(verdict, worst_constant_error=worst if math.isfinite(worst) else None)
        record = data.extrapolation
        bound = DIVERGED * max(np.abs(record.response_true).max(),
                               np.abs(record.velocity_true).max())
        simulated = simulate_equations([equation], record.coordinates, record.time,
                                       record.input_true, state0=record.initial_state,
                                       bound=bound)
        row["nrms"] = nrms(simulated, record.response_true)
        if method == "truth":
            row["cramer_rao"] = cramer_rao(data)
    except Exception as err:  # a crashed fit or simulation is a row, not a crash
        row["seconds"] = row["seconds"] or time.perf_counter() - began
        row["error"] = f"{type(err).__name__}: {err}"
        row["traceback"] = traceback.format_exc(limit=4)
    return row


def _table(rows: list[dict], systems: list[str]) -> str:
    lines = ["| system | method | structure right | constants within 2 % | "
             "median extrap. NRMS | median s | failed |", "| --- | --- | --- | --- | --- | --- | --- |"]
    present = list(dict.fromkeys(r["method"] for r in rows))
    methods = [m for m in METHODS if m in present] + [m for m in present if m not in METHODS]
    for name in systems:
        for method in methods:
            chosen = [r for r in rows if r["system"] == name and r["method"] == method]
            if not chosen:
                continue
            errors = [r["nrms"] if r["nrms"] is not None else math.inf for r in chosen]
            median = statistics.median(errors)
            lines.append(
                f"| {name} | {method} | {sum(r['structure'] for r in chosen)}/{len(chosen)} | "
                f"{sum(r['constants'] for r in chosen)}/{len(chosen)} | "
                f"{'diverged/failed' if math.isinf(median) else f'{median:.2%}'} | "
                f"{statistics.median(r['seconds'] for r in chosen):.1f} | "
                f"{sum(r['error'] is not None for r in chosen)} |")
    floor = _floor_table(rows, systems)
    return "\n".join(lines) + ("\n\n" + floor if floor else "")


def _floor_table(rows: list[dict], systems: list[str]) -> str:
    """Per system, the constant with the largest Cramér–Rao relative σ on the fit record
    (median over seeds) and the chance that an efficient unbiased estimator has it within
    the 2 % tolerance, P(|e| ≤ 2 %) = erf(0.02 / (σ·√2)): an upper bound for any method.
    Empty where no row carries the floor (no truth rows)."""
    lines = ["| system | least identifiable constant | Cramér–Rao σ (median) | "
             "P(within 2 %) at best |", "| --- | --- | --- | --- |"]
    for name in systems:
        floors = [r["cramer_rao"] for r in rows if r["system"] == name and "cramer_rao" in r]
        if not floors:
            continue
        sigma = {k: statistics.median(f[k] for f in floors) for k in floors[0]}
        worst = max(sigma, key=sigma.get)
        chance = math.erf(TOLERANCE / (sigma[worst] * math.sqrt(2.0)))
        lines.append(f"| {name} | {worst} | {sigma[worst]:.2%} | {chance:.2f} |")
    return "\n".join(lines) if len(lines) > 2 else ""


if __name__ == "__main__":
    sys.exit(main())
