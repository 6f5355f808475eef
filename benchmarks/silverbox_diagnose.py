"""Silverbox: diagnose the linear model m·y'' + d·y' + k·y = u on measured data.

Usage: python benchmarks/silverbox_diagnose.py SILVERBOX_DIR [--out FILE.json]
       [--exclude EFFECT ...] [--substeps N]

Runs :func:`gpjax._diagnose.diagnose` on the estimation segment [40650:105712] (its last
25 % held out), then simulates every accepted model on the test segments 'arrow full',
'arrow no extrapolation' and 'multisine' (initial state from the first 50 samples, RMS
over the rest) and writes the table, beside the published figures, as JSON.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from gpjax._canonical import Symbols
from gpjax._diagnose import diagnose
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
    parser.add_argument("--substeps", type=int, default=1)
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
    rms = {name: segment_rms(models, segments[name], substeps=args.substeps) * 1e3
           for name in TESTS}
    labels = ["linear (start)"] + [f"+ {name}" for name in result.effects_added]
    rows = [{"model": label, "equation": str(model.sympy()),
             "estimation_rms_mV": fit.metrics["rms"] * 1e3,
             "holdout_rms_mV": fit.metrics["rms_holdout"] * 1e3,
             **{f"{name}_rms_mV": float(rms[name][i]) for name in TESTS}}
            for i, (label, model, fit) in enumerate(zip(labels, models, result.fits))]
    report = {"effects_added": result.effects_added, "excluded": args.exclude, "mode": result.mode,
              "criterion": result.to_json()["criterion"], "seconds": seconds,
              "steps": result.steps, "rankings": result.rankings, "table": rows,
              "published_mV_multisine_arrowfull_arrownoextrap": PUBLISHED,
              "design_reference_mV": {"cubic only (DESIGN.md)": {"arrow_full": 0.96},
                                      "cubic + quadratic + offset": {
                                          "arrow_full": 0.93, "arrow_no_extrapolation": 0.74,
                                          "multisine": 0.90}}}
    Path(args.out).write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    print(f"effects added: {result.effects_added}  ({seconds:.0f} s)")
    print("| model | arrow full | arrow no extrap. | multisine | holdout |")
    for row in rows:
        print(f"| {row['model']} | {row['arrow_full_rms_mV']:.3f} | "
              f"{row['arrow_no_extrapolation_rms_mV']:.3f} | {row['multisine_rms_mV']:.3f} | "
              f"{row['holdout_rms_mV']:.3f} |")


if __name__ == "__main__":
    main()
