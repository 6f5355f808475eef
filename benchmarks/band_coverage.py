"""How often the 95 % prediction band of ``gpjax simulate --band`` covers the true response.

    python benchmarks/band_coverage.py --seeds 20 --json benchmarks/band_coverage.json

For Duffing and the pendulum (as in ``benchmarks/interval_coverage.py``): the true structure
fitted to a record with 1 % noise on the response and on the measured input (:func:`gpjax.refit`,
band-limited input reconstruction), then its band (:func:`gpjax.prediction_band`) on the
extrapolation record (another input realisation, 20 % larger), from the initial state the
true model fits on that record. The truth is the true model's reference response to the
same measured input from the same state: what the band claims to hold at each sample with
probability 0.95, the constants being the only unknowns. Per seed: the fraction of samples
inside the band, and the band's median half-width over the response's standard deviation;
a fit with a constant the record cannot bound (no finite standard error) has no band, and
is counted as such.
Rows are written after every seed; ``--resume`` skips the seeds the JSON already holds.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from _provenance import provenance
from interval_coverage import _one_coordinate

from gpjax import UserInputError, prediction_band, refit
from gpjax.systems import generate

SYSTEMS = ("duffing", "pendulum")


def run_seed(system: str, seed: int) -> dict:
    """One record: the band's pointwise coverage of the true response and its width."""
    from gpjax._model import fitted_initial_state, measurement_scale
    from gpjax._weak_form import estimate_initial_conditions

    synthetic = generate(system, seed=seed, noise=0.01, input_noise=0.01)
    truth, _ = _one_coordinate(system, synthetic.truth, "bandlimited")
    fitted = refit(truth, synthetic.fit.measurement())
    record = synthetic.extrapolation.measurement()
    start = tuple(fitted_initial_state(truth, record, estimate_initial_conditions(record)))
    scale = measurement_scale(record)
    true = truth.simulate_inputs(record.time, record.inputs, start, scale=scale)
    began = time.perf_counter()
    try:
        band = prediction_band(fitted, record.time, record.inputs, start, scale=scale,
                               seed=seed)
    except UserInputError as refused:  # a constant without a finite standard error
        return {"system": system, "seed": seed, "revision": provenance()["revision"],
                "no_band": str(refused)}
    seconds = time.perf_counter() - began
    inside = (band.low <= true) & (true <= band.high)
    return {"system": system, "seed": seed, "revision": provenance()["revision"],
            "coverage": float(np.mean(inside)), "diverged": band.diverged,
            "draws": band.draws, "constants": list(band.constants),
            "median_half_width_over_std": float(np.median(band.high - band.low) / 2
                                                / np.std(true)),
            "band_seconds": seconds}


def summary(rows: list[dict]) -> list[dict]:
    """Per system: seeds, mean pointwise coverage, the fraction of seeds whose coverage is
    at least 90 %, the median relative half-width and the median seconds per band."""
    out = []
    for system in sorted({r["system"] for r in rows}):
        every = [r for r in rows if r["system"] == system]
        group = [r for r in every if "no_band" not in r] or [{
            "coverage": float("nan"), "median_half_width_over_std": float("nan"),
            "diverged": 0, "band_seconds": float("nan"), "revision": every[0]["revision"]}]
        coverage = [r["coverage"] for r in group]
        out.append({"system": system, "seeds": len(every),
                    "without_band": sum("no_band" in r for r in every),
                    "revisions": sorted({r["revision"] for r in every}),
                    "mean_coverage": float(np.mean(coverage)),
                    "seeds_at_least_90": float(np.mean(np.array(coverage) >= 0.9)),
                    "median_half_width_over_std": float(np.median(
                        [r["median_half_width_over_std"] for r in group])),
                    "diverged_draws": int(sum(r["diverged"] for r in group)),
                    "median_band_seconds": float(np.median([r["band_seconds"]
                                                            for r in group]))})
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--systems", default=",".join(SYSTEMS))
    parser.add_argument("--json", required=True)
    parser.add_argument("--resume", action="store_true")
    args = parser.parse_args()
    path = Path(args.json)
    rows = json.loads(path.read_text())["rows"] if args.resume and path.is_file() else []
    done = {(r["system"], r["seed"]) for r in rows}
    for system in args.systems.split(","):
        for seed in range(args.seeds):
            if (system, seed) in done:
                continue
            row = run_seed(system, seed)
            rows.append(row)
            print(f"{system} seed {seed}: " + (f"no band ({row['no_band']})" if "no_band" in row
                  else f"coverage {row['coverage']:.3f}, half-width "
                  f"{row['median_half_width_over_std']:.4f} std, {row['band_seconds']:.1f} s"),
                  flush=True)
            path.write_text(json.dumps({**provenance(), "rows": rows,
                                        "summary": summary(rows)}, indent=1) + "\n")
    print(f"{'system':<10} {'seeds':>5} {'mean coverage':>14} {'seeds >= 90 %':>14} "
          f"{'half-width/std':>15}")
    for s in summary(rows):
        print(f"{s['system']:<10} {s['seeds']:>5} {s['mean_coverage']:>14.1%} "
              f"{s['seeds_at_least_90']:>14.0%} {s['median_half_width_over_std']:>15.4f}")


if __name__ == "__main__":
    sys.exit(main())
