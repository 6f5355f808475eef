"""Silverbox: diagnose the linear model m·y'' + d·y' + k·y = u on measured data.

Usage: python benchmarks/silverbox_diagnose.py SILVERBOX_DIR [--out FILE.json]
       [--input-interpolation {linear,bandlimited} ...] [--exclude EFFECT ...]
       [--substeps N]

For each input interpolation asked for (default: both), runs
:func:`gpjax._diagnose.diagnose` on the estimation segment [40650:105712] (its last 25 %
held out) with the simulation reconstructing the input between samples that way
(:func:`gpjax._data.between_samples`), and simulates the starting model and every
accepted model on the test segments 'arrow full', 'arrow no extrapolation' and
'multisine' (initial state from the first 50 samples, RMS over the samples after them).
The table, beside the published figures, is printed and written as JSON.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from gpjax._canonical import Symbols
from gpjax._data import INPUT_INTERPOLATIONS
from gpjax._diagnose import diagnose
from gpjax._effects import effects
from gpjax._model import Model
from gpjax._silverbox import segment_rms, silverbox_segments

#: Published test RMS in mV (README of the data: Champneys et al. 2024).
PUBLISHED = {"linear state space": (6.96, 14.4, 6.58), "polynomial NARX": (0.640, 2.25, 0.571),
             "LSTM": (1.50, 2.68, 0.960), "GP-NARX": (0.301, 0.60, 0.259),
             "neural state-space encoder": (0.36, 1.4, 0.32)}
TESTS = ("arrow_full", "arrow_no_extrapolation", "multisine")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("directory")
    parser.add_argument("--out", default=str(Path(__file__).with_name("silverbox_diagnose.json")))
    parser.add_argument("--input-interpolation", nargs="+", choices=INPUT_INTERPOLATIONS,
                        default=list(INPUT_INTERPOLATIONS), dest="interpolations")
    parser.add_argument("--substeps", type=int, default=1, help="RK4 steps per interval")
    parser.add_argument("--exclude", nargs="*", default=[], help="effects left out of the library")
    args = parser.parse_args()
    segments = silverbox_segments(args.directory)
    library = {name: e for name, e in effects().items() if name not in args.exclude}
    runs, rows = {}, []
    for interpolation in args.interpolations:
        linear = Model(symbols=Symbols("y", "t", ("u",)), mass=1.0,
                       state={"y": 1.0, "y_dot": 1.0}, forcing={"u": 1.0},
                       input_interpolation=interpolation)
        began = time.perf_counter()
        result = diagnose(segments["estimation"], linear, substeps=args.substeps,
                          library=library)
        seconds = time.perf_counter() - began
        models = result.models()
        rms = {name: segment_rms(models, segments[name], substeps=args.substeps) * 1e3
               for name in TESTS}
        labels = ["linear (start)"] + [f"+ {name}" for name in result.effects_added]
        rows += [{"input_interpolation": interpolation, "model": label,
                  "equation": str(model.sympy()),
                  "holdout_rms_mV": fit.metrics["rms_holdout"] * 1e3,
                  **{f"{name}_rms_mV": float(rms[name][i]) for name in TESTS}}
                 for i, (label, model, fit) in enumerate(zip(labels, models, result.fits))]
        runs[interpolation] = {"effects_added": result.effects_added, "mode": result.mode,
                               "seconds": seconds, "steps": result.steps,
                               "rankings": result.rankings}
        print(f"{interpolation}: effects added {result.effects_added} ({seconds:.0f} s)")
    report = {"excluded": args.exclude, "substeps": args.substeps,
              "criterion": result.to_json()["criterion"], "runs": runs, "table": rows,
              "published_mV_multisine_arrowfull_arrownoextrap": PUBLISHED,
              "design_reference_mV": {"cubic only (DESIGN.md)": {"arrow_full": 0.96},
                                      "cubic + quadratic + offset": {
                                          "arrow_full": 0.93, "arrow_no_extrapolation": 0.74,
                                          "multisine": 0.90}}}
    Path(args.out).write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    print("| input interpolation | model | held-out (estimation) | arrow full | "
          "arrow no extrap. | multisine |")
    for row in rows:
        print(f"| {row['input_interpolation']} | {row['model']} | {row['holdout_rms_mV']:.3f} | "
              f"{row['arrow_full_rms_mV']:.3f} | {row['arrow_no_extrapolation_rms_mV']:.3f} | "
              f"{row['multisine_rms_mV']:.3f} |")
    print("published (multisine / arrow full / arrow no extrap.): " + "; ".join(
        f"{name} {' / '.join(map(str, values))}" for name, values in PUBLISHED.items()))


if __name__ == "__main__":
    main()
