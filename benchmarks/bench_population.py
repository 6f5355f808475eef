"""Population evaluation and constant refinement on the bundled gear example: speed, basin,
the paper's protocol, scaling, and the gain from a second host device.

    XLA_FLAGS=--xla_force_host_platform_device_count=2 \\
        python benchmarks/bench_population.py --json benchmarks/population_cpu.json

Without ``XLA_FLAGS`` the script sets it itself (before JAX starts) so both cores are used;
``--devices 1`` measures one device. ``--baseline REV`` also measures the refinement rate
with the engine of git revision REV (a temporary worktree, child processes interleaved
with the current tree's). Prints a table and writes the figures as JSON.
"""

from __future__ import annotations

import argparse
import cProfile
import json
import os
import pstats
import resource
import subprocess
import sys
import time
from pathlib import Path

if "--devices" not in sys.argv or sys.argv[sys.argv.index("--devices") + 1] != "1":
    os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=2")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import lineax as lx  # noqa: E402
import numpy as np  # noqa: E402
import optimistix as optx  # noqa: E402
from scipy.integrate import solve_ivp  # noqa: E402

from _baseline import baseline_tree, in_tree  # noqa: E402
from _provenance import provenance  # noqa: E402
from gpjax import GPConfig, Identifier, Measurement, Symbols  # noqa: E402
from gpjax.engine import PopulationEvaluator  # noqa: E402
from gpjax._weak_form import WeakForm, least_squares, smoothed_derivatives  # noqa: E402
from gpjax._coefficients import Population  # noqa: E402
from gpjax._levenberg_marquardt import linear_solver as refine_linear_solver  # noqa: E402
from gpjax._refine import Refiner  # noqa: E402
from gpjax.gear import generate_gear_example, load_bundled_example  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent


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


def evaluation(measurement, truth, symbols, size, fit_initial, integrator="scan",
               devices=None):
    ev = PopulationEvaluator(measurement, symbols, max_degree=4, batch=size,
                             fit_initial_conditions=fit_initial, integrator=integrator,
                             devices=devices)
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
    """Refinement speed and basin on noise-free data from eq. 14 (the optimum is the truth).

    Speed: the GP's setting (one horizon, ``iterations`` steps) from 10 % perturbed starts,
    with the Jacobian from the variational equations in the scan (what gpjax uses) and from
    forward-mode autodiff through the scan and through ``diffrax.diffeqsolve``.
    Basin, from starts perturbed by 2, 10 and 30 %: Levenberg–Marquardt alone; with the
    short-horizon continuation (0.25, 1); and the GP's pipeline — the weak-form
    equation-error estimate competes with the given start (the lower objective wins), then
    Levenberg–Marquardt. Converged: J, K1 and K2 all within 0.1 % of the truth.
    """
    clean, start = clean_example(measurement, truth, symbols)
    ev = PopulationEvaluator(clean, symbols, max_degree=4, batch=count)
    single = Refiner(ev, iterations=iterations, batch=count, horizons=(1.0,))
    continuation = Refiner(ev, iterations=iterations, batch=count, horizons=(0.25, 1.0))
    derivatives = smoothed_derivatives(clean, ev.n_bins / (clean.n_samples * clean.dt))
    weak = WeakForm(clean, derivatives.x_dot, derivatives.window)
    mass, (k1, k2), _, _ = least_squares(weak, (symbols.x, symbols.x ** 2), (symbols.u[0],))
    u = ev.forcing_index(symbols.u[0])
    estimate = ev.empty(1)
    estimate.mass[:], estimate.state[0, :2], estimate.forcing[0, u] = mass, (k1, k2), 1.0
    estimate.y0[:] = start.y0
    estimate_objective = ev.score(estimate).objective[0]

    def converged(out):
        error = np.max(np.abs(np.stack([out.mass / truth["J"], out.state[:, 0] / truth["K1"],
                                        out.state[:, 1] / truth["K2"]]) - 1), axis=0)
        return float(np.mean(error < 1e-3))

    fixed = np.full(count, u)
    speeds = {}
    for integrator, jacobian in (("scan", "variational"), ("scan", "autodiff"),
                                 ("diffrax", "autodiff")):
        other = PopulationEvaluator(clean, symbols, max_degree=4, batch=count,
                                    integrator=integrator)
        refiner = Refiner(other, iterations=iterations, batch=count, horizons=(1.0,),
                          jacobian=jacobian)
        pop, u = population(other, truth, count, 0.1, np.random.default_rng(1))
        refiner.refine(pop, fixed)
        speeds[f"{jacobian}_{integrator}"] = count / best_of(lambda: refiner.refine(pop, fixed), 2)
    single.refine(pop, fixed)  # compiles it (compile_s)
    rows = {}
    for spread in (0.02, 0.1, 0.3):
        pop, u = population(ev, truth, count, spread, np.random.default_rng(1))
        better = ev.score(pop).objective > estimate_objective
        pipeline_start = Population(
            mass=np.where(better, estimate.mass[0], pop.mass),
            state=np.where(better[:, None], estimate.state[0], pop.state),
            forcing=pop.forcing, y0=pop.y0)
        continuation.refine(pop, fixed)
        began = time.perf_counter()
        widened = continuation.refine(pop, fixed).population
        continuation_s = time.perf_counter() - began
        rows[spread] = {
            "lm_converged": converged(single.refine(pop, fixed).population),
            "continuation_converged": converged(widened),
            "continuation_models_per_s": count / continuation_s,
            "equation_error_start_converged": converged(
                single.refine(pipeline_start, fixed).population),
            "equation_error_start_used": float(np.mean(better))}
    return {"iterations": iterations, "batch": count,
            "models_per_s": speeds["variational_scan"], "models_per_s_by_jacobian": speeds,
            "compile_s": single.compile_seconds, "lm_floor_models_per_s": lm_floor(
                clean.n_samples, single.max_free, iterations, count),
            "lm_floor_qr_models_per_s_by_width": {
                width: lm_floor(clean.n_samples, width, iterations, count, lx.QR())
                for width in (6, 7, 8, 12)},
            "equation_error_estimate_error": {
                "J": mass / truth["J"] - 1, "K1": k1 / truth["K1"] - 1, "K2": k2 / truth["K2"] - 1},
            "by_perturbation": {str(k): v for k, v in rows.items()}}


def clean_example(measurement, truth, symbols):
    """The example's record with the response of eq. 14 at the true constants (noise-free:
    refinement's optimum is the truth), and that one-model population."""
    ev = PopulationEvaluator(measurement, symbols, max_degree=4, batch=8)
    start, _ = population(ev, truth, 1, 0.0, np.random.default_rng(0))
    clean = Measurement(time=measurement.time, response=ev.simulate(start)[0][0],
                        inputs=measurement.inputs, response_name="phi", time_name="t")
    return clean, start


def refinement_rate(iterations, count):
    """Child: models/s of ``refinement``'s speed setting (one horizon, the default
    Jacobian, 10 % starts), best of 3; prints JSON. Runs on any engine revision."""
    measurement, truth = load_bundled_example()
    symbols = Symbols("phi", "t", ("T",))
    clean, _ = clean_example(measurement, truth, symbols)
    ev = PopulationEvaluator(clean, symbols, max_degree=4, batch=count)
    refiner = Refiner(ev, iterations=iterations, batch=count, horizons=(1.0,))
    pop, u = population(ev, truth, count, 0.1, np.random.default_rng(1))
    fixed = np.full(count, u)
    refiner.refine(pop, fixed)
    print(json.dumps(count / best_of(lambda: refiner.refine(pop, fixed), 3)))


def baseline_refinement(revision, iterations, count, rounds=3):
    """Refinement models/s of the engine at git ``revision`` and of this tree, each in
    fresh processes, alternating ``rounds`` times (the machine is shared); best of each."""
    with baseline_tree(revision) as tree:
        rates = [(child("refinement_rate", iterations, count, path=tree),
                  child("refinement_rate", iterations, count, path=ROOT))
                 for _ in range(rounds)]
    baseline, current = (max(r) for r in zip(*rates))
    return {"revision": revision, "models_per_s": baseline, "current_models_per_s": current,
            "current_over_baseline": current / baseline}


def lm_floor(samples, width, iterations, count, linear_solver=None):
    """Models/s of optimistix Levenberg–Marquardt alone, vmapped like the refiner, on a
    residual as long as the record and as wide as the refiner's Jacobian, but costing
    almost nothing to evaluate: the ceiling the solver's own per-step work sets (with the
    refiner's linear solver; ``lineax.QR()``, optimistix's default, shows XLA's slow QR)."""
    matrices = jnp.asarray(np.random.default_rng(0).normal(size=(count, samples, width)))
    linear_solver = refine_linear_solver() if linear_solver is None else linear_solver

    def one(matrix):
        def residuals(delta, _):
            return jnp.tanh(matrix @ delta) - 0.3
        solver = optx.LevenbergMarquardt(rtol=1e-9, atol=1e-9, linear_solver=linear_solver)
        return optx.least_squares(residuals, solver, jnp.zeros(width), max_steps=iterations,
                                  throw=False).value

    run = jax.jit(jax.vmap(one))
    jax.block_until_ready(run(matrices))
    return count / best_of(lambda: jax.block_until_ready(run(matrices)), 3)


def protocol():
    """The paper's protocol (P = 500, 10 generations forced by ε = 0, refinement on), each
    run in a fresh process as a user meets it (cold caches, compile included): one for wall
    and compile time, one under cProfile for where the time goes."""
    plain = child("protocol_child", 0)
    profiled = child("protocol_child", 1)
    return {**plain, "profile_s": profiled.get("profile_s", {})}


def protocol_child(profiled):
    measurement, _ = load_bundled_example()

    def run():
        return Identifier(GPConfig.paper(epsilon=0.0)).fit(measurement, seed=0, progress=False)

    began = time.perf_counter()
    if not profiled:
        identifier = run()
        print(json.dumps({"wall_s": time.perf_counter() - began,
                          "compile_s": identifier.timings_["compile_s"],
                          "generations": identifier.timings_["generations"],
                          "generation_s": [h["seconds"] for h in identifier.history_]}))
        return
    profiler = cProfile.Profile()
    profiler.runcall(run)
    stats = pstats.Stats(profiler).stats
    parts = {"structure checks (sympy)": ("_canonical.py", "check_tree"),
             "equation-error least squares": ("_weak_form.py", "least_squares"),
             "population evaluation (compiled)": ("_evaluator.py", "_call"),
             "refinement (compiled)": ("_refine.py", "refine"),
             "final model selection": ("_estimator.py", "_select"),
             "total": ("_estimator.py", "fit")}
    print(json.dumps({"profile_s": {
        name: sum(row[3] for (path, _, function), row in stats.items()
                  if path.endswith(suffix) and function == wanted)
        for name, (suffix, wanted) in parts.items()}}))


def child(function, *args, path=None):
    """Run ``function(*args)`` of this script in a fresh Python (with the engine at
    ``path`` first on ``PYTHONPATH`` when given); its last stdout line is JSON."""
    code = (f"import sys; sys.argv=['x']; sys.path.insert(0, {os.path.dirname(__file__)!r});"
            f"import bench_population as b; b.{function}(*{args!r})")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=False, **in_tree(path))
    if out.returncode:
        return {"error": f"exit {out.returncode}: {out.stderr.strip()[-300:]}"}
    return json.loads(out.stdout.strip().splitlines()[-1])


def scaling_point(size, samples):
    """Seconds per evaluation (IC fit on) and peak RSS, in a fresh process."""
    row = child("scaling_child", size, samples)
    if "error" in row:
        row.update(P=size, N=samples, seconds=float("nan"), peak_rss_gb=float("nan"))
    return row


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
    parser.add_argument("--baseline", help="git revision whose refinement rate to compare")
    args = parser.parse_args()
    measurement, truth = load_bundled_example()
    symbols = Symbols("phi", "t", ("T",))
    result = {**provenance(),
              "devices": len(jax.devices()), "N": measurement.n_samples, "P": 500}
    rate, compile_s = evaluation(measurement, truth, symbols, 500, False)
    rate_ic, _ = evaluation(measurement, truth, symbols, 500, True)
    rate_diffrax, _ = evaluation(measurement, truth, symbols, 500, False, "diffrax")
    one = PopulationEvaluator(measurement, symbols, max_degree=4, batch=500,
                              devices=jax.devices()[:1])
    pop, _ = population(one, truth, 500, 0.1, np.random.default_rng(0))
    one.score(pop)
    rate_one = 500 / best_of(lambda: one.score(pop), 5)
    arrays = [jnp.asarray(a) for a in (pop.mass, pop.state, pop.forcing, pop.y0)]
    forcing_matrix = jnp.asarray(one._forcing_basis) @ arrays[2].T
    solve = jax.jit(lambda m, c, y: one.scan_solve(m, c, forcing_matrix, y))
    jax.block_until_ready(solve(arrays[0], arrays[1], arrays[3]))
    scan_share = best_of(lambda: jax.block_until_ready(solve(arrays[0], arrays[1], arrays[3])),
                         5) * rate_one / 500
    large = 5000
    speedup_large = (evaluation(measurement, truth, symbols, large, False)[0]
                     / evaluation(measurement, truth, symbols, large, False,
                                  devices=jax.devices()[:1])[0])
    scipy_rate = scipy_loop(measurement, truth, 20)
    result.update(gpjax_models_per_s=rate, gpjax_fit_ic_models_per_s=rate_ic,
                  diffrax_models_per_s=rate_diffrax, one_device_models_per_s=rate_one,
                  device_speedup=rate / rate_one, device_speedup_p5000=speedup_large,
                  one_device_integration_share=scan_share, scipy_models_per_s=scipy_rate,
                  ratio=rate / scipy_rate, compile_s=compile_s)
    result["refinement"] = refinement(symbols, truth, measurement, 10, 64)
    if args.baseline:
        result["refinement"]["baseline"] = baseline_refinement(args.baseline, 10, 64)
    result["protocol"] = protocol()
    if not args.skip_scaling:
        result["scaling"] = [scaling_point(p, 1334) for p in (100, 500, 2000, 10000)]
        result["scaling"] += [scaling_point(500, n) for n in (1000, 10000, 100000)]
    print(f"{'quantity':<52} {'value':>12}")
    for key in ("gpjax_models_per_s", "gpjax_fit_ic_models_per_s", "diffrax_models_per_s",
                "one_device_models_per_s", "device_speedup", "device_speedup_p5000",
                "one_device_integration_share",
                "scipy_models_per_s", "ratio",
                "compile_s"):
        print(f"{key:<52} {result[key]:>12.4g}")
    r = result["refinement"]
    print(f"{'refine models/s (10 iterations), LM-alone floor':<52} {r['models_per_s']:>6.4g} "
          f"{r['lm_floor_models_per_s']:>6.4g}")
    for name, rate in r["models_per_s_by_jacobian"].items():
        print(f"{'refine models/s, jacobian ' + name:<52} {rate:>6.4g}")
    if "baseline" in r:
        b = r["baseline"]
        print(f"{'refine models/s: baseline ' + b['revision'] + ', this tree, ratio':<52} "
              f"{b['models_per_s']:>6.4g} {b['current_models_per_s']:>6.4g} "
              f"{b['current_over_baseline']:>5.2f}")
    for spread, row in r["by_perturbation"].items():
        print(f"{'converged from ' + spread + ': LM, continuation, EE start':<52} "
              f"{row['lm_converged']:>5.2f} {row['continuation_converged']:>5.2f} "
              f"{row['equation_error_start_converged']:>5.2f}")
    p = result["protocol"]
    print(f"{'protocol wall s, compile s, gens':<52} {p['wall_s']:>6.3g} {p['compile_s']:>5.3g} "
          f"{p['generations']:>3}")
    for name, seconds in p["profile_s"].items():
        print(f"{'  profile: ' + name:<52} {seconds:>6.3g}")
    for row in result.get("scaling", []):
        print(f"{'scaling P=' + str(row['P']) + ' N=' + str(row['N']) + ' s, GB':<52} "
              f"{row['seconds']:>6.3g} {row['peak_rss_gb']:>5.2f}")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as handle:
            json.dump(result, handle, indent=2)


if __name__ == "__main__":
    main()
