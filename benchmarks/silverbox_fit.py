"""Silverbox through the front door: ``gpjax fit --diagnose`` scored by an independent solver.

Usage: python benchmarks/silverbox_fit.py SILVERBOX_DIR [--out FILE.json] [--work DIR]
       [--input-interpolation {linear,bandlimited,hold}] [--reuse] [--baseline REV]

Writes the estimation segment [40650:105712] as CSV, runs ``gpjax fit est.csv --time t
--response V2 --input V1 --diagnose --input-interpolation bandlimited`` as a separate
process (defaults otherwise), and scores the GP's model and the diagnosis' final model on
the test segments 'arrow full', 'arrow no extrapolation' and 'multisine' with scipy's
DOP853 (rtol 1e-10, atol 1e-13, at most one sample interval per step; the input as the same
continuous-time function gpjax uses), which shares no code with gpjax's integrators. The
initial state comes from the first 50 samples of each segment; the RMS is taken over the
samples after them. Prints a table beside the published results and writes JSON.

``--baseline REV`` runs the same command with the code of git revision ``REV`` (a temporary
worktree, its own empty compilation cache folder, as this tree's run has where
``GPJAX_CACHE_DIR`` names an empty one) right after this tree's, and records its seconds,
peak RSS, the ratio and whether both found the same models.
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
from scipy.integrate import solve_ivp

from gpjax._data import Measurement, bandlimited_spline
from gpjax._model import Model
from gpjax._weak_form import estimate_initial_conditions
from gpjax._silverbox import SEGMENTS, WARMUP, silverbox_segments

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _baseline import baseline_tree, in_tree, same_model  # noqa: E402
from _provenance import provenance  # noqa: E402

#: Published test RMS in mV (multisine, arrow full, arrow no extrapolation), from the data's
#: README (Champneys et al. 2024).
PUBLISHED = {"linear state space": (6.96, 14.4, 6.58), "polynomial NARX": (0.640, 2.25, 0.571),
             "LSTM": (1.50, 2.68, 0.960), "GP-NARX": (0.301, 0.60, 0.259),
             "neural state-space encoder": (0.36, 1.4, 0.32)}
#: Hand fit of m·y'' + c·y' + k1·y + k2·y² + k3·y³ + offset = u, converged RK4 (DESIGN.md).
HAND_FIT = {"arrow_full": 0.93, "arrow_no_extrapolation": 0.74, "multisine": 0.90}
TESTS = ("arrow_full", "arrow_no_extrapolation", "multisine")


def input_function(values: np.ndarray, t0: float, dt: float, method: str):
    """u(t) for scipy, reconstructed between samples as gpjax does."""
    if method == "bandlimited":
        spline = bandlimited_spline(values)
        return lambda t: float(spline((t - t0) / dt))
    if method == "hold":
        return lambda t: float(values[min(int(np.floor((t - t0) / dt + 1e-9)), values.size - 1)])
    grid = t0 + dt * np.arange(values.size)
    return lambda t: float(np.interp(t, grid, values))


def dop853_rms(model: Model, segment) -> float:
    """RMS simulation error (V) of ``model`` on a test segment, by scipy DOP853."""
    names = model.symbols
    equation = model.sympy()
    acceleration = sp.solve(sp.Eq(equation.lhs - equation.rhs, 0), names.x_ddot)[0]
    rhs = sp.lambdify((names.x, names.x_dot, names.t, *names.u), acceleration, modules="math")
    u = input_function(segment.inputs[names.inputs[0]], segment.time[0], segment.dt,
                       model.input_interpolation)
    y0 = estimate_initial_conditions(segment.segment(0, WARMUP + 1))
    solution = solve_ivp(lambda t, y: (y[1], rhs(y[0], y[1], t, u(t))),
                         (segment.time[0], segment.time[-1]), y0, method="DOP853",
                         t_eval=segment.time, rtol=1e-10, atol=1e-13, max_step=segment.dt)
    if not solution.success:
        return float("inf")
    error = segment.response[WARMUP:] - solution.y[0][WARMUP:]
    return float(np.sqrt(np.mean(error ** 2)))


def _csv_names(segment: Measurement) -> Measurement:
    """A segment with the CSV's column names (V1 input, V2 response)."""
    return Measurement(time=segment.time, response=segment.response,
                       inputs={"V1": segment.inputs["u"]}, time_name="t", response_name="V2")


def timed_fit(command: list[str], tree: Path | None = None,
              **variables: str) -> tuple[float, float]:
    """Run ``command`` (the code at ``tree``, default this one) as one process: its wall
    seconds and peak RSS (MB, ``/usr/bin/time``)."""
    with tempfile.NamedTemporaryFile(suffix=".txt") as peak:
        began = time.perf_counter()
        subprocess.run(["/usr/bin/time", "-o", peak.name, "-f", "%M", *command], check=True,
                       **in_tree(tree, **variables))
        seconds = time.perf_counter() - began
        return seconds, float(Path(peak.name).read_text().split()[-1]) / 1024


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("directory")
    parser.add_argument("--out", default=str(Path(__file__).with_name("silverbox_fit.json")))
    parser.add_argument("--work", default="silverbox-run", help="folder for the CSV and the run")
    parser.add_argument("--input-interpolation", default="bandlimited", dest="interpolation")
    parser.add_argument("--reuse", action="store_true", help="score an existing run in --work")
    parser.add_argument("--baseline", help="git revision timed in the same run")
    args = parser.parse_args()
    work = Path(args.work).resolve()
    work.mkdir(parents=True, exist_ok=True)
    segments = silverbox_segments(args.directory)
    run = work / "run"
    command = [sys.executable, "-m", "gpjax", "fit", str(work / "estimation.csv"), "--time",
               "t", "--response", "V2", "--input", "V1", "--diagnose",
               "--input-interpolation", args.interpolation, "--out", str(run)]
    seconds = peak_rss_mb = None
    if not args.reuse:
        estimation = segments["estimation"]
        np.savetxt(work / "estimation.csv", np.column_stack(
            [estimation.time, estimation.inputs["u"], estimation.response]), delimiter=",",
            header="t,V1,V2", comments="", fmt="%.10g")
        seconds, peak_rss_mb = timed_fit(command)
    baseline = None
    if args.baseline:
        before = work / "baseline-run"
        with baseline_tree(args.baseline) as tree, tempfile.TemporaryDirectory() as cache:
            baseline_s, baseline_mb = timed_fit(command[:-1] + [str(before)], tree,
                                                GPJAX_CACHE_DIR=cache)
        same = all(same_model(Model.load(run / name), Model.load(before / name))
                   for name in ("model.json", "diagnosis/model.json"))
        baseline = {"revision": args.baseline, "seconds": baseline_s,
                    "peak_rss_mb": baseline_mb, "same_models": same,
                    "ratio_seconds": seconds / baseline_s if seconds else None}
    rows = []
    for label, path in (("gpjax fit (GP)", run / "model.json"),
                        ("gpjax fit --diagnose (final)", run / "diagnosis" / "model.json")):
        model = Model.load(path)
        rms = {name: 1e3 * dop853_rms(model, _csv_names(segments[name])) for name in TESTS}
        check = model.convergence or {}
        rows.append({"model": label, "equation": str(model.sympy()),
                     "substeps": model.substeps, "convergence_ratio": check.get("ratio"),
                     "estimation_rms_reference_mV": 1e3 * check.get("rms_reference", np.nan),
                     **{f"{name}_rms_mV": rms[name] for name in TESTS}})
    report = {**provenance(), "fit_command": " ".join(command[1:]), "seconds": seconds,
              "peak_rss_mb": peak_rss_mb, "baseline": baseline,
              "input_interpolation": args.interpolation, "segments": SEGMENTS,
              "scorer": "scipy solve_ivp DOP853, rtol 1e-10, atol 1e-13, max_step = dt",
              "table": rows, "published_mV_multisine_arrowfull_arrownoextrap": PUBLISHED,
              "hand_fit_mV": HAND_FIT}
    Path(args.out).write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    print("| model | substeps | RK4 vs reference | arrow full | arrow no extrap. | multisine |")
    print("| --- | --- | --- | --- | --- | --- |")
    for row in rows:
        print(f"| {row['model']} | {row['substeps']} | {row['convergence_ratio']:.2%} | "
              f"{row['arrow_full_rms_mV']:.3f} | {row['arrow_no_extrapolation_rms_mV']:.3f} | "
              f"{row['multisine_rms_mV']:.3f} |")
    for name, (multisine, full, no_extrapolation) in PUBLISHED.items():
        print(f"| {name} (published) | | | {full} | {no_extrapolation} | {multisine} |")
    print(f"| hand fit, converged RK4 (DESIGN.md) | | | {HAND_FIT['arrow_full']} | "
          f"{HAND_FIT['arrow_no_extrapolation']} | {HAND_FIT['multisine']} |")
    if seconds is not None:
        print(f"gpjax fit --diagnose took {seconds:.0f} s, peak RSS {peak_rss_mb:.0f} MB")
    if baseline:
        print(f"{args.baseline}: {baseline['seconds']:.0f} s, peak RSS "
              f"{baseline['peak_rss_mb']:.0f} MB; ratio {baseline['ratio_seconds']:.2f}, "
              f"{'the same' if baseline['same_models'] else 'other'} models")


if __name__ == "__main__":
    main()
