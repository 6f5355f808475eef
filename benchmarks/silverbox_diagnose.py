"""Silverbox: diagnose the linear model m·y'' + d·y' + k·y = u on measured data.

Usage: python benchmarks/silverbox_diagnose.py SILVERBOX_DIR [--out FILE.json]
       [--exclude EFFECT ...] [--substeps N] [--factor K]

1. Runs :func:`gpjax._diagnose.diagnose` on the estimation segment [40650:105712] (its last
   25 % held out); the simulation interpolates the input linearly between samples.
2. Refits every accepted model's structure (:func:`gpjax._diagnose.refit`, same split) on
   the record reconstructed at K times its sample rate by band-limited interpolation
   (:func:`gpjax._silverbox.upsample`; K = 1 skips this).

Every model of both stages is simulated on the test segments 'arrow full', 'arrow no
extrapolation' and 'multisine' (initial state from the first 50 samples, RMS over the
original samples after them); the table, beside the published figures, is written as JSON.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from gpjax._canonical import Symbols
from gpjax._diagnose import diagnose, refit
from gpjax._effects import effects
from gpjax._model import Model
from gpjax._silverbox import silverbox_segments, segment_rms

#: Published test RMS in mV (README of the data: Champneys et al. 2024).
PUBLISHED = {"linear state space": (6.96, 14.4, 6.58), "polynomial NARX": (0.640, 2.25, 0.571),
             "LSTM": (1.50, 2.68, 0.960), "GP-NARX": (0.301, 0.60, 0.259),
             "neural state-space encoder": (0.36, 1.4, 0.32)}
TESTS = ("arrow_full", "arrow_no_extrapolation", "multisine")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("directory")
    parser.add_argument("--out", default=str(Path(__file__).with_name("silverbox_diagnose.json")))
    parser.add_argument("--substeps", type=int, default=1, help="RK4 steps per interval")
    parser.add_argument("--factor", type=int, default=4,
                        help="refit on the record reconstructed at this multiple of the rate")
    parser.add_argument("--exclude", nargs="*", default=[], help="effects left out of the library")
    args = parser.parse_args()
    segments = silverbox_segments(args.directory)
    linear = Model(symbols=Symbols("y", "t", ("u",)), mass=1.0, state={"y": 1.0, "y_dot": 1.0},
                   forcing={"u": 1.0})
    began = time.perf_counter()
    library = {name: e for name, e in effects().items() if name not in args.exclude}
    result = diagnose(segments["estimation"], linear, substeps=args.substeps, library=library)
    seconds = time.perf_counter() - began
    models = [fit.model(linear.symbols, {}) for fit in result.fits]
    stages = {"diagnosis": (segments, models, 1)}
    if args.factor > 1:
        fine = silverbox_segments(args.directory, factor=args.factor)
        began = time.perf_counter()
        refits = refit(fine["estimation"], models, substeps=args.substeps)
        stages["reconstructed"] = (fine, [f.model(linear.symbols, {}) for f in refits],
                                   args.factor)
        seconds_refit = time.perf_counter() - began
    labels = ["linear (start)"] + [f"+ {name}" for name in result.effects_added]
    rows = []
    for stage, (data, fitted, factor) in stages.items():
        rms = {name: segment_rms(fitted, data[name], substeps=args.substeps, factor=factor) * 1e3
               for name in TESTS}
        rows += [{"stage": stage, "model": label, "equation": str(model.sympy()),
                  **{f"{name}_rms_mV": float(rms[name][i]) for name in TESTS}}
                 for i, (label, model) in enumerate(zip(labels, fitted))]
    for row, fit in zip(rows, result.fits):
        row["holdout_rms_mV"] = fit.metrics["rms_holdout"] * 1e3
    report = {"effects_added": result.effects_added, "excluded": args.exclude, "mode": result.mode,
              "factor": args.factor, "substeps": args.substeps,
              "criterion": result.to_json()["criterion"], "seconds_diagnosis": seconds,
              "seconds_refit": seconds_refit if args.factor > 1 else None,
              "steps": result.steps, "rankings": result.rankings, "table": rows,
              "published_mV_multisine_arrowfull_arrownoextrap": PUBLISHED,
              "design_reference_mV": {"cubic only (DESIGN.md)": {"arrow_full": 0.96},
                                      "cubic + quadratic + offset": {
                                          "arrow_full": 0.93, "arrow_no_extrapolation": 0.74,
                                          "multisine": 0.90}}}
    Path(args.out).write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    print(f"effects added: {result.effects_added}  ({seconds:.0f} s)")
    print("| stage | model | arrow full | arrow no extrap. | multisine |")
    for row in rows:
        print(f"| {row['stage']} | {row['model']} | {row['arrow_full_rms_mV']:.3f} | "
              f"{row['arrow_no_extrapolation_rms_mV']:.3f} | {row['multisine_rms_mV']:.3f} |")


if __name__ == "__main__":
    main()
