"""The 2-DOF gear pair of eqs. 21–22 through the front door (issue 42's evidence): `gpjax fit`
with several responses and `--third-law`, several seeds, scored against the truth.

    python benchmarks/gear_front_door.py [--seeds 5] [--json benchmarks/gear_front_door.json]

Each record is :func:`gpjax.gear.two_dof_record` (1 % noise on both angles), written in
line-of-action coordinates s1 = r1·Θ1, s2 = r2·Θ2 (m), where eqs. 21–22 read
(J1/r1)·s1'' + r1·c_m·(s1' − s2') + r1·k_m·(s1 − s2) = T1 and
(J2/r2)·s2'' + r2·c_m·(s2' − s1') + r2·k_m·(s2 − s1) = −T2. It is fitted by

    gpjax fit gear.csv --time t --response s1 --response s2 --input T1 --input T2
        --third-law --input-interpolation bandlimited --seed SEED

(the torques' ripple reaches 25 kHz at 300 kHz sampling: band-limited between samples).
With the third law the mesh force is one expression in both equations, and equation 2 is
scaled so that its coupling constants equal equation 1's: its mass is J2·r1/r2² and T2's
coefficient −r1/r2. Scored:

* **structure**: equation 1 holds exactly s1 − s2 and s1' − s2' with the input T1, equation
  2 their mirrors with T2;
* **constants**: the relative error of J1/r1, r1·k_m, r1·c_m (mesh damping, one constant by
  the third law), J2·r1/r2² and −r1/r2;
* **extrapolation**: the fitted model simulated by the reference solve on a record of
  another seed with both torques 20 % larger (no noise, from rest), NRMS per coordinate
  and of the mesh deflection s1 − s2 (the coordinates themselves are dominated by the
  common rotation).

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

import numpy as np
import sympy as sp

import gpjax
from gpjax.gear import two_dof_record

sys.path.insert(0, str(Path(__file__).parent))
from _provenance import provenance  # noqa: E402

S1, S2, V1, V2, T1, T2 = sp.symbols("s1 s2 s1_dot s2_dot T1 T2")


def truth(record) -> dict:
    """The constants in the fit's normalisation (module docstring)."""
    t = record.truth
    return {"J1/r1": t["J1"] / t["r1"], "r1*k_m": t["r1"] * t["k_m"],
            "r1*c_m": t["r1"] * t["c_m"], "J2*r1/r2^2": t["J2"] * t["r1"] / t["r2"] ** 2,
            "T2 coefficient": -t["r1"] / t["r2"]}


def found(model: gpjax.Model) -> tuple[bool, dict]:
    """(structure right, the constants as :func:`truth` names them)."""
    first, second = model.system
    right = (set(first.state) == {S1 - S2, V1 - V2} and set(first.forcing) == {T1}
             and set(second.state) == {S2 - S1, V2 - V1} and set(second.forcing) == {T2})
    if not right:
        return False, {}
    scale = 1.0 / first.forcing[T1]
    return True, {"J1/r1": first.mass * scale, "r1*k_m": first.state[S1 - S2] * scale,
                  "r1*c_m": first.state[V1 - V2] * scale,
                  "J2*r1/r2^2": second.mass * scale * first.state[S1 - S2]
                  / second.state[S2 - S1] if second.state[S2 - S1] else float("nan"),
                  "T2 coefficient": second.forcing[T2] * first.state[S1 - S2]
                  / second.state[S2 - S1] * scale}


def run_one(seed: int, folder: Path) -> dict:
    record = two_dof_record(seed=seed)
    path = folder / f"gear_{seed}.csv"
    record.line_of_action().to_csv(path)
    out = folder / f"gear_{seed}"
    command = ["fit", str(path), "--time", "t", "--response", "s1", "--response", "s2",
               "--input", "T1", "--input", "T2", "--third-law", "--input-interpolation",
               "bandlimited", "--seed", str(seed), "--out", str(out)]
    began = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "gpjax", *command], capture_output=True,
                          text=True)
    seconds = time.perf_counter() - began
    row = {"seed": seed, "revision": provenance()["revision"], "seconds": seconds,
           "command": " ".join(["gpjax", "fit", "<record>", *command[2:-2]])}
    if done.returncode != 0:
        return row | {"error": done.stderr.strip()[-500:]}
    model = gpjax.Model.load(out / "model.json")
    right, constants = found(model)
    expected = truth(record)
    errors = {k: constants[k] / v - 1 for k, v in expected.items()} if right else {}
    larger = two_dof_record(seed=seed + 1000, noise=0.0, torque_scale=1.2).line_of_action()
    simulated = np.reshape(model.simulate(larger, initial_conditions=np.zeros((2, 2))),
                           larger.responses.shape)
    true = larger.responses

    def nrms(a, b):
        return float(np.sqrt(np.mean((a - b) ** 2)) / np.std(b))

    return row | {"structure_right": right, "errors": errors,
                  "max_constant_error": max(map(abs, errors.values())) if errors else None,
                  "extrapolation_nrms": [nrms(simulated[:, d], true[:, d]) for d in (0, 1)],
                  "deflection_nrms": nrms(simulated[:, 0] - simulated[:, 1],
                                          true[:, 0] - true[:, 1]),
                  "equations": [str(e) for e in model.sympy()],
                  "convergence": model.convergence}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--json", default="benchmarks/gear_front_door.json")
    args = parser.parse_args()
    path = Path(args.json)
    rows = json.loads(path.read_text())["rows"] if path.is_file() else []
    done = {r["seed"] for r in rows}
    with tempfile.TemporaryDirectory() as folder:
        for seed in range(args.seeds):
            if seed in done:
                continue
            row = run_one(seed, Path(folder))
            rows.append(row)
            print(f"gear seed {seed}: " + (f"ERROR {row['error']}" if "error" in row else
                  f"structure {'right' if row['structure_right'] else 'WRONG'}, "
                  + ("" if not row["errors"] else "errors " + ", ".join(
                      f"{k} {v:+.2%}" for k, v in row["errors"].items()) + ", ")
                  + f"deflection NRMS {row['deflection_nrms']:.2%}, {row['seconds']:.0f} s"),
                  flush=True)
            path.write_text(json.dumps({**provenance(), "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
