"""Cost of the reference solve against the record's length (it must grow linearly).

The bundled example's model (eq. 14 with the paper's constants) is simulated on records of
``--sizes`` samples (the example's sampling rate, a two-line torque) by the reference solve
(diffrax Dopri8 per sample interval, :mod:`gpjax._reference`) and, as the baseline measured
in the same run, by the model's fixed-step RK4, once for each of ``--interpolations`` (how
the input runs between samples; band-limited inputs make the solve's steps end on the
spline's knots). Each is timed after one warm-up call (so compiling is excluded). Prints a
table and writes JSON.

    python benchmarks/bench_reference.py --sizes 10000 100000 --json benchmarks/reference_cost.json
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import time
from pathlib import Path

import numpy as np

from gpjax import Measurement, Model, Symbols
from gpjax._data import INPUT_INTERPOLATIONS
from gpjax.gear import PAPER_TRUTH, load_bundled_example

from _provenance import provenance


def timed(fn) -> tuple[float, np.ndarray]:
    fn()  # compile (or load) first
    began = time.perf_counter()
    out = fn()
    return time.perf_counter() - began, out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000])
    parser.add_argument("--interpolations", nargs="+", default=list(INPUT_INTERPOLATIONS),
                        choices=INPUT_INTERPOLATIONS)
    parser.add_argument("--json", help="write the results here")
    args = parser.parse_args()
    example, _ = load_bundled_example()
    rows = []
    print("| input between samples | samples | reference s | µs per sample | RK4 s | "
          "reference / RK4 |")
    print("| --- | --- | --- | --- | --- | --- |")
    for interpolation, n in itertools.product(args.interpolations, args.sizes):
        model = Model.single(symbols=Symbols("phi", "t", ("T",)), mass=PAPER_TRUTH["J"],
                             state={"phi": PAPER_TRUTH["K1"], "phi**2": PAPER_TRUTH["K2"]},
                             forcing={"T": 1.0}, substeps=3, input_interpolation=interpolation)
        t = example.dt * np.arange(n)
        torque = 13.0 + 0.6 * np.sin(2 * np.pi * 285.0 * t) + 0.3 * np.sin(2 * np.pi * 620.0 * t)
        phi = np.full(n, 0.01) + 1e-4 * np.sin(2 * np.pi * 3.0 * t)  # only its scale is used
        record = Measurement(time=t, response=phi, inputs={"T": torque}, time_name="t",
                             response_name="phi")
        y0 = (0.0, 0.0)
        reference_s, x = timed(lambda: model.simulate(record, initial_conditions=y0))
        rk4_s, x_rk4 = timed(lambda: model.simulate(record, initial_conditions=y0,
                                                    solver="rk4"))
        row = {"input_interpolation": interpolation, "samples": n,
               "reference_s": reference_s, "rk4_s": rk4_s,
               "us_per_sample": 1e6 * reference_s / n, "ratio_to_rk4": reference_s / rk4_s,
               "finite": bool(np.all(np.isfinite(x))),
               "rk4_difference_rms_over_spread": float(np.sqrt(np.mean((x - x_rk4) ** 2))
                                                       / np.std(x))}
        rows.append(row)
        print(f"| {interpolation} | {n} | {reference_s:.2f} | {row['us_per_sample']:.1f} | "
              f"{rk4_s:.3f} | "
              f"{row['ratio_to_rk4']:.0f} |", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(
            {**provenance(), "load_average_after": os.getloadavg(), "rows": rows}, indent=1) + "\n",
            encoding="utf-8")


if __name__ == "__main__":
    main()
