"""Population evaluation and constant refinement on the bundled gear example: speed, basin,
the paper's protocol, scaling, and the gain from a second host device.

    XLA_FLAGS=--xla_force_host_platform_device_count=2 \\
        python benchmarks/bench_population.py --json benchmarks/population_cpu.json

Without ``XLA_FLAGS`` the script sets it itself (before JAX starts) so both cores are used;
``--devices 1`` measures one device. Prints a table and writes the figures as JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import time

if "--devices" not in sys.argv or sys.argv[sys.argv.index("--devices") + 1] != "1":
    os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=2")

import jax  # noqa: E402
import numpy as np  # noqa: E402
from scipy.integrate import solve_ivp  # noqa: E402

from gpjax import GPConfig, Identifier, Measurement, PopulationEvaluator, Symbols  # noqa: E402
from gpjax._refine import Refiner  # noqa: E402
from gpjax.gear import generate_gear_example, load_bundled_example  # noqa: E402


def population(evaluator, truth, count, spread, rng):
    """Eq. 14 models with constants perturbed uniformly by ±spread (relative)."""
    u = evaluator.forcing_index(evaluator.symbols.u[0])
    pop = evaluator.empty(count)
    pop.mass[:] = truth["J"] * (1 + spread * rng.uniform(-1, 1, count))
    pop.state[:, 0] = truth["K1"] * (1 + spread * rng.uniform(-1, 1, count))
    pop.state[:, 1] = truth["K2"] * (1 + spread * rng.uniform(-1, 1, count))
    pop.forcing[:, u] = 1.0
    pop.y0[:] = [truth["initial_conditions"]["phi"], truth["initial_conditions"]["phi_dot"]]
    return pop, u


def best_of(fn, repeats):
    """Smallest wall time of ``repeats`` calls (the machine is shared)."""
    times = []
    for _ in range(repeats):
        began = time.perf_counter()
        fn()
        times.append(time.perf_counter() - began)
    return min(times)


def evaluation(measurement, truth, symbols, size, fit_initial, integrator="scan"):
    ev = PopulationEvaluator(measurement, symbols, max_degree=4, batch=size,
                             fit_initial_conditions=fit_initial, integrator=integrator)
    pop, _ = population(ev, truth, size, 0.1, np.random.default_rng(0))
    ev.score(pop)
    return size / best_of(lambda: ev.score(pop), 5), ev.compile_seconds


def scipy_loop(measurement, truth, count):
    t, u = measurement.time, measurement.inputs["T"]
    rng = np.random.default_rng(0)
    began = time.perf_counter()
    for _ in range(count):
        j, k1, k2 = (truth[k] * (1 + 0.1 * rng.uniform(-1, 1)) for k in ("J", "K1", "K2"))

        def field(time_, y, j=j, k1=k1, k2=k2):
            return [y[1], (np.interp(time_, t, u) - k1 * y[0] - k2 * y[0] ** 2) / j]
        x = solve_ivp(field, (t[0], t[-1]), [truth["initial_conditions"]["phi"],
                      truth["initial_conditions"]["phi_dot"]], t_eval=t, rtol=1e-6).y[0]
        np.abs(np.fft.rfft(x))
    return count / (time.perf_counter() - began)


def refinement(symbols, truth, measurement, iterations, count):
    """Noise-free data from eq. 14 with the true constants, so the optimum is the truth."""
    ev0 = PopulationEvaluator(measurement, symbols, max_degree=4, batch=8)
    start, u = population(ev0, truth, 1, 0.0, np.random.default_rng(0))
    clean = Measurement(time=measurement.time, response=ev0.simulate(start)[0][0],
                        inputs=measurement.inputs, response_name="phi", time_name="t")
    ev = PopulationEvaluator(clean, symbols, max_degree=4, batch=count)
    refiner = Refiner(ev, iterations=iterations, batch=count)
    rows = {}
    for spread in (0.02, 0.1, 0.3):
        pop, u = population(ev, truth, count, spread, np.random.default_rng(1))
        refiner.refine(pop, np.full(count, u))
        began = time.perf_counter()
        out = refiner.refine(pop, np.full(count, u)).population
        seconds = time.perf_counter() - began
        error = np.max(np.abs(np.stack([out.mass / truth["J"], out.state[:, 0] / truth["K1"],
                                        out.state[:, 1] / truth["K2"]]) - 1), axis=0)
        rows[spread] = {"models_per_s": count / seconds,
                        "converged_fraction": float(np.mean(error < 1e-3))}
    return rows, refiner.compile_seconds


def protocol():
    measurement, _ = load_bundled_example()
    began = time.perf_counter()
    identifier = Identifier(GPConfig.paper(epsilon=0.0)).fit(measurement, seed=0, progress=False)
    seconds = [h["seconds"] for h in identifier.history_]
    return {"wall_s": time.perf_counter() - began, "compile_s": identifier.timings_["compile_s"],
            "generations": identifier.timings_["generations"], "generation_s": seconds}


def scaling_point(size, samples):
    """Seconds per evaluation (IC fit on) and peak RSS, in a fresh process."""
    code = (f"import sys; sys.argv=['x']; sys.path.insert(0, {os.path.dirname(__file__)!r});"
            f"import bench_population as b; b.scaling_child({size}, {samples})")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=os.environ, check=False)
    if out.returncode:
        return {"P": size, "N": samples, "seconds": float("nan"), "peak_rss_gb": float("nan"),
                "error": f"exit {out.returncode}: {out.stderr.strip()[-300:]}"}
    return json.loads(out.stdout.strip().splitlines()[-1])


def scaling_child(size, samples):
    revolutions = samples / 1334
    example = generate_gear_example(revolutions=revolutions)
    measurement = example.measurement
    truth = load_bundled_example()[1]
    symbols = Symbols("phi", "t", ("T",))
    ev = PopulationEvaluator(measurement, symbols, max_degree=4, batch=min(size, 2000),
                             fit_initial_conditions=True)
    pop, _ = population(ev, truth, size, 0.1, np.random.default_rng(0))
    began = time.perf_counter()
    ev.score(pop)
    first = time.perf_counter() - began
    seconds = best_of(lambda: ev.score(pop), 2)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 ** 2
    print(json.dumps({"P": size, "N": measurement.n_samples, "seconds": seconds,
                      "first_call_s": first, "peak_rss_gb": peak}))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", help="write the results here")
    parser.add_argument("--devices", type=int, default=2)
    parser.add_argument("--skip-scaling", action="store_true")
    args = parser.parse_args()
    measurement, truth = load_bundled_example()
    symbols = Symbols("phi", "t", ("T",))
    result = {"machine": platform.platform(), "cpus": os.cpu_count(),
              "devices": len(jax.devices()), "N": measurement.n_samples, "P": 500}
    rate, compile_s = evaluation(measurement, truth, symbols, 500, False)
    rate_ic, _ = evaluation(measurement, truth, symbols, 500, True)
    rate_diffrax, _ = evaluation(measurement, truth, symbols, 500, False, "diffrax")
    one = PopulationEvaluator(measurement, symbols, max_degree=4, batch=500,
                              devices=jax.devices()[:1])
    pop, _ = population(one, truth, 500, 0.1, np.random.default_rng(0))
    one.score(pop)
    rate_one = 500 / best_of(lambda: one.score(pop), 5)
    scipy_rate = scipy_loop(measurement, truth, 20)
    result.update(gpjax_models_per_s=rate, gpjax_fit_ic_models_per_s=rate_ic,
                  diffrax_models_per_s=rate_diffrax, one_device_models_per_s=rate_one,
                  device_speedup=rate / rate_one, scipy_models_per_s=scipy_rate,
                  ratio=rate / scipy_rate, compile_s=compile_s)
    rows, refine_compile = refinement(symbols, truth, measurement, 10, 64)
    result["refinement"] = {"iterations": 10, "batch": 64, "compile_s": refine_compile,
                            "by_perturbation": {str(k): v for k, v in rows.items()}}
    result["protocol"] = protocol()
    if not args.skip_scaling:
        result["scaling"] = [scaling_point(p, 1334) for p in (100, 500, 2000, 10000)]
        result["scaling"] += [scaling_point(500, n) for n in (1000, 10000, 100000)]
    print(f"{'quantity':<52} {'value':>12}")
    for key in ("gpjax_models_per_s", "gpjax_fit_ic_models_per_s", "diffrax_models_per_s",
                "one_device_models_per_s", "device_speedup", "scipy_models_per_s", "ratio",
                "compile_s"):
        print(f"{key:<52} {result[key]:>12.4g}")
    for spread, row in rows.items():
        print(f"{'refine ' + str(spread) + ' models/s, converged':<52} "
              f"{row['models_per_s']:>6.4g} {row['converged_fraction']:>5.2f}")
    p = result["protocol"]
    print(f"{'protocol wall s, compile s, gens':<52} {p['wall_s']:>6.3g} {p['compile_s']:>5.3g} "
          f"{p['generations']:>3}")
    for row in result.get("scaling", []):
        print(f"{'scaling P=' + str(row['P']) + ' N=' + str(row['N']) + ' s, GB':<52} "
              f"{row['seconds']:>6.3g} {row['peak_rss_gb']:>5.2f}")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as handle:
            json.dump(result, handle, indent=2)


if __name__ == "__main__":
    main()
