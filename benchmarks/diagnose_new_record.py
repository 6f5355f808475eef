"""The one-coordinate diagnosis on a record it has not seen, this tree against a baseline.

Usage: python benchmarks/diagnose_new_record.py --baseline REV [--seen 204] [--new 217]
       [--effects NAME,...] [--json FILE]

Per tree, in one fresh process with a fresh cache folder: :func:`gpjax.diagnose` on the
gear's undeclared-effect cases (:func:`gpjax.gear.undeclared_effect_case`, 1× torque noise,
``frequencies=(285.0,)`` as ``benchmarks/diagnose_sweep.py``) of seed ``--seen`` (they
compile the programs of their shapes), then on the same effects of seed ``--new``: records
of the same length the process has not seen. Prints a table and writes ``--json`` with
each case's seconds, effects added and constants for both trees; "same" compares the
effects added and every constant to 1e-3 (relative).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _baseline import baseline_tree, in_tree  # noqa: E402
from _provenance import provenance  # noqa: E402

#: Default cases: effects whose numbers come from the record (a sign's scale, a line's
#: frequency, a backlash's edges), one without, and the control.
EFFECTS = ("viscous_damping", "coulomb_friction", "mesh_stiffness_variation", "backlash",
           "control")

CHILD = """
import json, sys, time
from gpjax import diagnose
from gpjax.gear import undeclared_effect_case
effects, seeds = sys.argv[1].split(","), [int(s) for s in sys.argv[2].split(",")]
rows = []
for seed in seeds:
    for name in effects:
        case = undeclared_effect_case(name, seed=seed, torque_noise=1.0)
        began = time.perf_counter()
        result = diagnose(case.measurement, case.start, frequencies=(285.0,))
        c = result.model().coefficients
        rows.append({"effect": name, "seed": seed, "seconds": time.perf_counter() - began,
                     "added": list(result.effects_added),
                     "constants": [c.mass, *c.state.values(), *c.forcing.values()]})
print(json.dumps(rows))
"""


def run(tree: Path | None, effects: list[str], seeds: list[int]) -> list[dict]:
    """The child's rows, run on ``tree`` (this one when ``None``) with a fresh cache."""
    with tempfile.TemporaryDirectory() as cache:
        out = subprocess.run([sys.executable, "-c", CHILD, ",".join(effects),
                              ",".join(map(str, seeds))], check=True, capture_output=True,
                             text=True, **in_tree(tree, JAX_PLATFORMS="cpu",
                                                  GPJAX_CACHE_DIR=cache))
    return json.loads(out.stdout.strip().splitlines()[-1])


def same(a: dict, b: dict) -> bool:
    return a["added"] == b["added"] and len(a["constants"]) == len(b["constants"]) and all(
        abs(x - y) <= 1e-3 * abs(x) for x, y in zip(a["constants"], b["constants"]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", required=True)
    parser.add_argument("--seen", type=int, default=204)
    parser.add_argument("--new", type=int, default=217)
    parser.add_argument("--effects", default=",".join(EFFECTS))
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    effects, seeds = args.effects.split(","), [args.seen, args.new]
    with baseline_tree(args.baseline) as tree:
        before = run(tree, effects, seeds)
    after = run(None, effects, seeds)
    rows = [{"effect": a["effect"], "seed": a["seed"], "record": "seen" if a["seed"] ==
             args.seen else "new", "baseline_s": a["seconds"], "current_s": b["seconds"],
             "baseline_added": a["added"], "added": b["added"], "same": same(a, b),
             "baseline_constants": a["constants"], "constants": b["constants"]}
            for a, b in zip(before, after)]
    totals = {kind: {"baseline_s": sum(r["baseline_s"] for r in rows if r["record"] == kind),
                     "current_s": sum(r["current_s"] for r in rows if r["record"] == kind)}
              for kind in ("seen", "new")}
    print(f"| effect | record | {args.baseline} s | this tree s | ratio | added | same |")
    print("| --- | --- | ---: | ---: | ---: | --- | --- |")
    for r in rows:
        print(f"| {r['effect']} | {r['record']} (seed {r['seed']}) | {r['baseline_s']:.1f} | "
              f"{r['current_s']:.1f} | {r['baseline_s'] / r['current_s']:.2f} | "
              f"{', '.join(r['added']) or 'none'} | {'yes' if r['same'] else 'no'} |")
    for kind, t in totals.items():
        print(f"all {kind}: {t['baseline_s']:.1f} s -> {t['current_s']:.1f} s "
              f"({t['baseline_s'] / t['current_s']:.2f}x)")
    if args.json:
        Path(args.json).write_text(json.dumps(
            provenance() | {"baseline": args.baseline, "rows": rows, "totals": totals},
            indent=1) + "\n")


if __name__ == "__main__":
    main()
