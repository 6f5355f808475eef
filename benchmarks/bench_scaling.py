"""How ``gpjax fit`` scales with the record length: peak memory and time per generation.

Writes synthetic records of a forced Duffing-like oscillator,
``m·x'' + c·x' + k·x + k3·x³ = u`` (m = 1, 5 Hz, 5 % damping, the cubic term ~20 % of the
linear one at the RMS response), driven by band-limited (0–20 Hz) Gaussian noise and
sampled at 1 kHz, with 1 % noise on response and input. Each record is the first N samples
of one RK4 simulation (one step per sample, input linear between samples). For each N,
``python -m gpjax fit FILE --time t --response x --input u --generations 2 --population P``
runs as a child of a fresh wrapper process, whose ``RUSAGE_CHILDREN`` gives the peak
resident memory of that run alone.

    python benchmarks/bench_scaling.py --sizes 10000 100000 1000000 --population 24 \\
        --json benchmarks/bench_scaling.json
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from _provenance import provenance

FS_HZ = 1000.0
MASS, FREQUENCY_HZ, DAMPING_RATIO, BAND_HZ = 1.0, 5.0, 0.05, 20.0
STIFFNESS = MASS * (2 * np.pi * FREQUENCY_HZ) ** 2
DAMPING = 2 * DAMPING_RATIO * np.sqrt(STIFFNESS * MASS)
INPUT_RMS = 10.0
NOISE = 0.01  # of each signal's RMS

#: Wrapper run in a fresh Python: runs the command, prints the child's peak RSS in KiB.
_WRAPPER = ("import resource, subprocess, sys; code = subprocess.call(sys.argv[1:]); "
            "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss); sys.exit(code)")


def band_limited_input(n: int, rng: np.random.Generator) -> np.ndarray:
    """Gaussian noise with its spectrum cut above :data:`BAND_HZ`, RMS :data:`INPUT_RMS`."""
    spectrum = np.fft.rfft(rng.standard_normal(n))
    spectrum[np.fft.rfftfreq(n, 1 / FS_HZ) > BAND_HZ] = 0
    u = np.fft.irfft(spectrum, n)
    return INPUT_RMS * u / np.std(u)


def simulate(u: np.ndarray, cubic: float) -> np.ndarray:
    """x at the samples: classical RK4, one step per sample, u linear between samples."""
    dt = 1 / FS_HZ

    def rates(x, v, force):
        return v, (force - DAMPING * v - STIFFNESS * x - cubic * x ** 3) / MASS

    x = np.empty(u.size)
    xi, vi = 0.0, 0.0
    for i in range(u.size):
        x[i] = xi
        if i + 1 == u.size:
            break
        u0, u1 = float(u[i]), float(u[i + 1])
        um = 0.5 * (u0 + u1)
        k1x, k1v = rates(xi, vi, u0)
        k2x, k2v = rates(xi + 0.5 * dt * k1x, vi + 0.5 * dt * k1v, um)
        k3x, k3v = rates(xi + 0.5 * dt * k2x, vi + 0.5 * dt * k2v, um)
        k4x, k4v = rates(xi + dt * k3x, vi + dt * k3v, u1)
        xi += dt / 6 * (k1x + 2 * k2x + 2 * k3x + k4x)
        vi += dt / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
    return x


def records(n_max: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, measured x, measured u) of :data:`n_max` samples."""
    rng = np.random.default_rng(seed)
    u = band_limited_input(n_max, rng)
    linear_rms = np.std(simulate(u[: min(n_max, 20_000)], 0.0))
    x = simulate(u, 0.2 * STIFFNESS / linear_rms ** 2)
    x_measured = x + NOISE * np.std(x) * rng.standard_normal(n_max)
    u_measured = u + NOISE * INPUT_RMS * rng.standard_normal(n_max)
    return np.arange(n_max) / FS_HZ, x_measured, u_measured


def write_csv(path: Path, t: np.ndarray, x: np.ndarray, u: np.ndarray) -> None:
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["t", "x", "u"])
        writer.writerows(zip(np.char.mod("%.6f", t), np.char.mod("%.9g", x),
                             np.char.mod("%.9g", u)))


def run(path: Path, out: Path, population: int) -> dict:
    """One ``gpjax fit`` in its own process: peak RSS, wall time, seconds per generation."""
    command = [sys.executable, "-m", "gpjax", "fit", str(path), "--time", "t", "--response",
               "x", "--input", "u", "--generations", "2", "--population", str(population),
               "--out", str(out)]
    began = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", _WRAPPER, *command], capture_output=True,
                          text=True, env=os.environ, check=False)
    wall = time.perf_counter() - began
    result = {"wall_s": wall, "exit": done.returncode,
              "peak_rss_mb": int(done.stdout.strip().splitlines()[-1]) / 1024}
    if done.returncode:
        result["error"] = done.stderr.strip()[-500:]
        return result
    with open(out / "history.csv") as handle:
        seconds = [float(row["seconds"]) for row in csv.DictReader(handle)]
    simulation = json.loads((out / "model.json").read_text())["simulation"]
    result.update(generation_s=seconds, equation=done.stdout.strip().splitlines()[0][:200],
                  substeps=simulation["integrator"]["substeps"],
                  convergence_ratio=simulation["convergence"]["ratio"])
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    parser.add_argument("--population", type=int, default=24)
    parser.add_argument("--json", default=str(Path(__file__).with_name("bench_scaling.json")))
    args = parser.parse_args()
    t, x, u = records(max(args.sizes))
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for n in args.sizes:
            path = Path(folder) / f"record_{n}.csv"
            write_csv(path, t[:n], x[:n], u[:n])
            row = {"n_samples": n, "population": args.population,
                   **run(path, Path(folder) / f"run_{n}", args.population)}
            rows.append(row)
            print(json.dumps(row), flush=True)
    print("\n| N | peak RSS (MB) | s / generation | total (s) | RK4 steps / sample | "
          "RK4 vs reference |\n|---:|---:|---:|---:|---:|---:|")
    for row in rows:
        per_generation = ", ".join(f"{s:.1f}" for s in row.get("generation_s", []))
        print(f"| {row['n_samples']:,} | {row['peak_rss_mb']:.0f} | {per_generation or 'failed'}"
              f" | {row['wall_s']:.1f} | {row.get('substeps', '')} | "
              f"{row.get('convergence_ratio', float('nan')):.2%} |")
    with open(args.json, "w") as handle:
        json.dump({**provenance(), "rows": rows}, handle, indent=1)
        handle.write("\n")


if __name__ == "__main__":
    main()
