"""Systems of several degrees of freedom (issue 14): identification evidence and speed.

    python benchmarks/bench_systems.py chains [--seeds 5] [--search] [--third-law]
        [--systems chain2,chain3] [--json benchmarks/systems_chains.json]
    python benchmarks/bench_systems.py gear [--json benchmarks/systems_gear.json]
    python benchmarks/bench_systems.py speed [--json benchmarks/systems_speed.json]

``chains``: ``chain2`` and ``chain3`` of :mod:`gpjax.systems` (cubic coupling springs, 1 %
noise on every response and on the input), every coordinate measured. The structure is
given (the truth's), or with ``--search`` found by the system GP
(:meth:`gpjax.Identifier.fit`, ``--population`` 100, ``--generations`` 3,
max_degree 4, seed = the record's seed); the
constants and initial states come from :func:`gpjax.engine.fit_system` (weak-form start,
Levenberg–Marquardt over all coordinates, converged integration). Constants: equation 1 is
normalised by the input (coefficient 1), the others, which have no input, by their mass, so
they are compared with the truth divided by that mass. NRMS per coordinate on the
extrapolation record (another input realisation, amplitude × 1.2), simulated by scipy's
DOP853 from the true initial state with the true input (:func:`gpjax.systems.simulate_equations`).
With ``--third-law`` each coupling force is one expression shared by its two equations
(:mod:`gpjax._system_couplings`): every equation is then in equation 1's units, so the
constants are compared with the truth as it is (no division by a mass).

``gear``: the paper's 2-DOF gear pair (eqs. 21–22), :func:`gpjax.gear.two_dof_record`:
pinion J1 = 7.918e-5 kg·m² (eq. 14), a geometrically similar gear J2 = J1·(z2/z1)⁴, base radii
of the paper's pair, the mean mesh stiffness k_m, mesh damping c_m for 5 % of critical; input
torque T1 = 13 N·m plus a 1 N·m RMS random-phase multisine (2–25 kHz), load T2 =
(r2/r1)·13 N·m plus a 0.5 N·m multisine, both applied at t = 0 to gears at rest; both
angles measured (1 % noise), 300 kHz, 2,001 samples. Three fits, the structure given: the
angles, and the line-of-action displacements r1·Θ1, r2·Θ2 with and without the third law
(the structure searched through ``gpjax fit``: ``benchmarks/gear_front_door.py``). In the
angles, eq. 21 is
J1Θ1'' + a·Θ1' + b·(Θ1' − Θ2') + A·Θ1 + B·(Θ1 − Θ2) = T1 with B = r1·r2·k_m,
A = r1·(r1 − r2)·k_m (likewise b, a with c_m), eq. 22 J2Θ2'' + … = −T2.

``speed``: one population of 500 (max_degree 3, 2,001 samples): the 1-DOF evaluator on
``chain2``'s x1 against the 2-DOF evaluator on ``chain2`` and the 3-DOF one on ``chain3``,
each model a perturbed truth, with and without the initial-state Gauss–Newton step; the
best of 10 ``score`` calls of each after a warm-up, the six interleaved (a shared machine's
load hits them alike), in wall-clock and in the process's CPU time (all threads; less
disturbed by other work on the machine).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np
import sympy as sp

from gpjax import GPConfig, Identifier, Symbols
from gpjax._coefficients import Coefficients, to_population, to_system_population
from gpjax.engine import PopulationEvaluator, fit_system
from gpjax.systems import generate, get_system, simulate_equations

sys.path.insert(0, str(Path(__file__).parent))
from _provenance import provenance  # noqa: E402


def chain_structure(n: int):
    """The truth's features: own x_i', x_i, and per neighbour (x_i − x_j), (x_i − x_j)³."""
    x = [sp.Symbol(f"x{i + 1}") for i in range(n)]
    v = [sp.Symbol(f"x{i + 1}_dot") for i in range(n)]
    out = []
    for i in range(n):
        state = [v[i], x[i]]
        for j in (i - 1, i + 1):
            if 0 <= j < n:
                state += [x[i] - x[j], (x[i] - x[j]) ** 3]
        out.append((tuple(state), {sp.Symbol("u"): 1.0} if i == 0 else {}))
    return tuple(out)


def chain_truth(n: int, constants: dict, third_law: bool = False) -> list[dict]:
    """Per equation the true coefficient of every feature, normalised as fitted (with the
    third law every equation is in equation 1's units: no division by the mass)."""
    truth = []
    for i, (state, _) in enumerate(chain_structure(n)):
        scale = 1.0 if i == 0 or third_law else constants[f"m{i + 1}"]
        values = {state[0]: constants["c"], state[1]: constants["k"]}
        for d, d3 in zip(state[2::2], state[3::2]):
            values |= {d: constants["kc"], d3: constants["k3"]}
        truth.append({"mass": constants[f"m{i + 1}"] / scale,
                      **{str(f): v / scale for f, v in values.items()}})
    return truth


def scored(model, found: list[dict], truth: list[dict], record) -> tuple:
    """(structure right, largest relative constant error, NRMS per coordinate on the
    extrapolation ``record``) of a fitted system: ``found`` and ``truth`` map each
    equation's terms (and "mass") to their constants; the model is simulated by DOP853 from
    the true initial state with the true input."""
    right = all(set(f) == set(t) for f, t in zip(found, truth))
    error = max(abs(f.get(k, 0.0) / t[k] - 1) for f, t in zip(found, truth) for k in t)
    simulated = simulate_equations(model.sympy(), record.coordinates, record.time,
                                   record.input_true, state0=record.initial_state)
    nrms = np.sqrt(np.mean((simulated - record.response_true) ** 2, axis=1)
                   / np.mean(record.response_true ** 2, axis=1))
    return right, error, nrms


def chains(seeds: int, search: bool, population: int, generations: int,
           third_law: bool = False, systems=("chain2", "chain3")) -> list[dict]:
    rows = []
    for name in systems:
        n = len(get_system(name).coordinates)
        for seed in range(seeds):
            data = generate(name, seed=seed)
            measurement = data.fit.system_measurement()
            began = time.perf_counter()
            if search:
                config = GPConfig(population=population, generations=generations,
                                  third_law=third_law)
                model = Identifier(config).fit(measurement, seed=seed).model_
            else:
                model = fit_system(measurement, chain_structure(n), third_law=third_law).model
            seconds = time.perf_counter() - began
            truth = chain_truth(n, data.system.constants, third_law)
            found = [{"mass": e.mass, **{str(f): v for f, v in e.state.items()}}
                     for e in model.system]
            structure_ok, error, nrms = scored(model, found, truth, data.extrapolation)
            rows.append({"system": name, "seed": seed, "structure_right": structure_ok,
                         "max_constant_error": error, "nrms": nrms.tolist(),
                         "seconds": seconds, "found": found, "truth": truth,
                         "substeps": model.substeps})
            print(f"{name} seed {seed}: structure {'right' if structure_ok else 'WRONG'}, "
                  f"max constant error {error:.3%}, extrapolation NRMS "
                  f"{', '.join(f'{e:.3%}' for e in nrms)}, {seconds:.1f} s", flush=True)
    return rows


def gear(seed: int = 0) -> dict:
    """The paper's 2-DOF gear with its structure given: the constants' errors in angles and
    on the line of action, with and without the third law (the structure found by a search
    is ``gear_front_door.py``'s, through ``gpjax fit``)."""
    from gpjax.gear import two_dof_record

    record = two_dof_record(seed=seed)
    t = record.truth
    args = (t["r1"], t["r2"], t["J1"], t["J2"], t["k_m"], t["c_m"])
    return {"angles": _gear_angles(record.measurement, *args),
            "line_of_action": _gear_line(record.line_of_action(), *args),
            "line_of_action_third_law": _gear_line(record.line_of_action(), *args,
                                                   third_law=True),
            "truth": t}


def _report(fit, found, truth, seconds):
    errors = {k: found[k] / truth[k] - 1 for k in truth}
    for k in truth:
        print(f"  {k:<26} found {found[k]:.6g}  truth {truth[k]:.6g}  ({errors[k]:+.3%})")
    print(f"  {seconds:.1f} s; {fit.model.substeps} RK4 steps per sample, reference check "
          f"ratio {fit.checks[-1].ratio:.3%}")
    return {"found": found, "truth": truth, "errors": errors, "seconds": seconds,
            "substeps": fit.model.substeps, "convergence": fit.checks[-1].to_json(),
            "equations": [str(e) for e in fit.model.sympy()]}


def _gear_angles(measurement, r1, r2, j1, j2, k_m, c_m):
    """Both angles as measured: eqs. 21–22 need own and relative terms per equation."""
    print("gear, angles Θ1, Θ2 measured, structure given:")
    x1, x2, v1, v2 = sp.symbols("th1 th2 th1_dot th2_dot")
    T1, T2 = sp.symbols("T1 T2")
    structure = (((v1, v1 - v2, x1, x1 - x2), {T1: 1.0}),
                 ((v2, v2 - v1, x2, x2 - x1), {T2: -1.0}))
    began = time.perf_counter()
    fit = fit_system(measurement, structure, input_interpolation="bandlimited")
    seconds = time.perf_counter() - began
    first, second = fit.model.system
    found = {"J1": first.mass, "J2": second.mass,
             "k_m (eq. 21)": first.state[x1 - x2] / (r1 * r2),
             "k_m (eq. 22)": second.state[x2 - x1] / (r1 * r2),
             "c_m (eq. 21)": first.state[v1 - v2] / (r1 * r2),
             "c_m (eq. 22)": second.state[v2 - v1] / (r1 * r2),
             "A/(r1(r1-r2)) (eq. 21)": first.state[x1] / (r1 * (r1 - r2)),
             "A/(r2(r2-r1)) (eq. 22)": second.state[x2] / (r2 * (r2 - r1)),
             "a/(r1(r1-r2)) (eq. 21)": first.state[v1] / (r1 * (r1 - r2)),
             "a/(r2(r2-r1)) (eq. 22)": second.state[v2] / (r2 * (r2 - r1))}
    truth = {"J1": j1, "J2": j2, "k_m (eq. 21)": k_m, "k_m (eq. 22)": k_m,
             "c_m (eq. 21)": c_m, "c_m (eq. 22)": c_m, "A/(r1(r1-r2)) (eq. 21)": k_m,
             "A/(r2(r2-r1)) (eq. 22)": k_m, "a/(r1(r1-r2)) (eq. 21)": c_m,
             "a/(r2(r2-r1)) (eq. 22)": c_m}
    return _report(fit, found, truth, seconds)


def _gear_line(measurement, r1, r2, j1, j2, k_m, c_m, *, third_law: bool = False):
    """The line-of-action displacements s1 = r1·Θ1, s2 = r2·Θ2
    (:meth:`gpjax.gear.TwoDofRecord.line_of_action`), structure given; with
    ``third_law`` the mesh force is given once (in eq. 21) and T2's coefficient is free."""
    print("gear, line-of-action displacements r1·Θ1, r2·Θ2, structure given"
          f"{', third law' if third_law else ''}:")
    x1, x2, v1, v2 = sp.symbols("s1 s2 s1_dot s2_dot")
    T1, T2 = sp.symbols("T1 T2")
    structure = ((((v1 - v2, x1 - x2), {T1: 1.0}), ((), {T2: None})) if third_law else
                 (((v1 - v2, x1 - x2), {T1: 1.0}), ((v2 - v1, x2 - x1), {T2: -1.0})))
    began = time.perf_counter()
    fit = fit_system(measurement, structure, input_interpolation="bandlimited",
                     third_law=third_law)
    row = _line_constants(fit, time.perf_counter() - began, r1, r2, j1, j2, k_m, c_m)
    row["standard_errors"] = standard_errors(fit, measurement,
                                             ("T1",) if third_law else ("T1", "T2"))
    for name, value in row["standard_errors"]["relative"].items():
        print(f"  relative standard error of {name:<24} {value:.3%}")
    return row


def standard_errors(fit, measurement, held: tuple[str, ...]) -> dict:
    """Relative standard errors of a system fit's free constants (the forcing
    coefficients named in ``held`` excluded; a tied pair is one constant), σ²·(JᵀJ)⁻¹
    with J the output-error Jacobian of the responses, each coordinate over its standard deviation, from the
    variational equations at the fitted constants (:meth:`PopulationEvaluator.
    constant_jacobian`), initial states included as nuisance parameters; and the
    correlations above 0.5 in magnitude."""
    import jax.numpy as jnp

    from gpjax._system_couplings import tie_columns

    model = fit.model
    ev = model.evaluator(measurement)
    population = to_system_population([list(model.system)], ev)
    layout = ev.layout  # after the forcing columns exist
    flat = layout.pack(population)[0]
    mirrors = {layout.state_column(cb, eb): (layout.state_column(ca, ea), sign)
               for ea, ca, eb, cb, sign in tie_columns(model.ties(), ev)}
    held = {layout.forcing_column(ev.forcing_index(f), e)
            for e, equation in enumerate(model.system) for f in equation.forcing
            if str(f) in held}
    names, directions = [], []
    for e, equation in enumerate(model.system):
        columns = [(f"mass (eq. {e + 1})", layout.mass_column(e))]
        columns += [(f"{f} (eq. {e + 1})", layout.state_column(ev.equation_index(f, e), e))
                    for f in equation.state]
        columns += [(f"{f} (eq. {e + 1})", layout.forcing_column(ev.forcing_index(f), e))
                    for f in equation.forcing]
        for name, column in columns:
            if column in mirrors or column in held:
                continue
            direction = np.zeros(flat.size)
            direction[column] = flat[column]
            for mirror, (source, sign) in mirrors.items():
                if source == column:
                    direction[mirror] = sign * flat[column]
            names.append(name)
            directions.append(direction)
    responses = measurement.responses
    spread = np.concatenate([[np.std(responses[:, d]), np.std(np.diff(responses[:, d]))
                              / measurement.dt] for d in range(responses.shape[1])])
    for k, value in enumerate(spread):  # the initial states, in units of their spread
        direction = np.zeros(flat.size)
        direction[flat.size - spread.size + k] = value
        directions.append(direction)
    x, dx = (np.asarray(a) for a in ev.constant_jacobian(
        jnp.asarray(flat), jnp.asarray(np.array(directions)),
        jnp.asarray(ev.forcing_basis)[: ev.stage_rows(measurement.n_samples)]))
    scale = np.std(responses, axis=0)
    residual = ((responses - x) / scale).ravel()
    jacobian = (dx / scale[None, :, None]).reshape(residual.size, -1)
    variance = residual @ residual / (residual.size - jacobian.shape[1])
    covariance = variance * np.linalg.inv(jacobian.T @ jacobian)
    error = np.sqrt(np.diag(covariance))
    correlation = covariance / np.outer(error, error)
    return {"relative": dict(zip(names, error[:len(names)].tolist())),
            "correlations": {a: {b: float(correlation[i, j])
                                 for j, b in enumerate(names + ["x0 etc."] * spread.size)
                                 if j != i and abs(correlation[i, j]) > 0.5}
                             for i, a in enumerate(names)}}


def _line_constants(fit, seconds, r1, r2, j1, j2, k_m, c_m):
    """Eq. 22 is (J2/r2)·s2'' + r2·k_m·(s2 − s1) + … = −T2 times its scale λ = |g_T2|
    (1 where T2's coefficient is held at −1; r1/r2 with the third law)."""
    x1, x2, v1, v2 = sp.symbols("s1 s2 s1_dot s2_dot")
    first, second = fit.model.system
    scale = abs(second.forcing.get(sp.Symbol("T2"), -1.0)) or 1.0
    found = {"J1": first.mass * r1, "J2": second.mass * r2 / scale,
             "k_m (eq. 21)": first.state.get(x1 - x2, 0.0) / r1,
             "k_m (eq. 22)": second.state.get(x2 - x1, 0.0) / (r2 * scale),
             "c_m (eq. 21)": first.state.get(v1 - v2, 0.0) / r1,
             "c_m (eq. 22)": second.state.get(v2 - v1, 0.0) / (r2 * scale)}
    truth = {"J1": j1, "J2": j2, "k_m (eq. 21)": k_m, "k_m (eq. 22)": k_m,
             "c_m (eq. 21)": c_m, "c_m (eq. 22)": c_m}
    return _report(fit, found, truth, seconds)


def _chain_population(name: str, count: int, rng) -> tuple:
    """(evaluator inputs, population) of ``count`` perturbed truths of a catalogue chain."""
    data = generate(name, seed=0)
    c, names = data.system.constants, data.system.coordinates
    x = sp.symbols(names)
    v = sp.symbols([f"{n}_dot" for n in names])
    u = sp.Symbol("u")

    def s():
        return 1 + 0.05 * rng.standard_normal()

    def equation(i):
        state = {v[i]: c["c"] * s(), x[i]: c["k"] * s()}
        for j in (i - 1, i + 1):
            if 0 <= j < len(names):
                state |= {x[i] - x[j]: c["kc"] * s(), (x[i] - x[j]) ** 3: c["k3"] * s()}
        return Coefficients(c[f"m{i + 1}"] * s(), state, {u: 1.0} if i == 0 else {})

    return data.fit.system_measurement(), [[equation(i) for i in range(len(names))]
                                           for _ in range(count)]


def speed(count: int = 500, rounds: int = 10) -> dict:
    rng = np.random.default_rng(0)
    x1, v1, u = sp.symbols("x1 x1_dot u")
    data = generate("chain2", seed=0)
    c = data.system.constants
    cases = {}
    for fit_ic in (False, True):
        key = "with_initial_state_step" if fit_ic else "plain"
        one = PopulationEvaluator(data.fit.measurement("x1"), Symbols("x1", "t", ("u",)),
                                  max_degree=3, fit_initial_conditions=fit_ic, batch=count)
        cases[(key, 1)] = one, to_population([
            Coefficients(c["m1"] * (1 + 0.05 * rng.standard_normal()),
                         {v1: c["c"], x1: 50.0, x1 ** 3: c["k3"]}, {u: 1.0})
            for _ in range(count)], one)
        for d, name in ((2, "chain2"), (3, "chain3")):
            measurement, systems = _chain_population(name, count, rng)
            evaluator = PopulationEvaluator(measurement, Symbols("x1", "t", ("u",)),
                                            max_degree=3, fit_initial_conditions=fit_ic,
                                            batch=count)
            cases[(key, d)] = evaluator, to_system_population(systems, evaluator)
    times = {k: [] for k in cases}
    cpu = {k: [] for k in cases}
    for evaluator, population in cases.values():
        evaluator.score(population)  # compile or load
    for _ in range(rounds):  # interleaved, so load on a shared machine hits all alike
        for k, (evaluator, population) in cases.items():
            began, began_cpu = time.perf_counter(), time.process_time()
            evaluator.score(population)
            times[k].append(time.perf_counter() - began)
            cpu[k].append(time.process_time() - began_cpu)
    out = {}
    for key in ("plain", "with_initial_state_step"):
        wall = {d: min(times[(key, d)]) for d in (1, 2, 3)}
        process = {d: min(cpu[(key, d)]) for d in (1, 2, 3)}
        out[key] = {"seconds": wall, "cpu_seconds": process,
                    "ratio": {d: wall[d] / wall[1] for d in (2, 3)},
                    "cpu_ratio": {d: process[d] / process[1] for d in (2, 3)}}
        print(f"{key:<26} " + "  ".join(f"D={d} {wall[d] * 1e3:7.1f} ms" for d in wall)
              + "   ratios " + ", ".join(f"{wall[d] / wall[1]:.2f}" for d in (2, 3))
              + "   CPU ratios " + ", ".join(f"{process[d] / process[1]:.2f}" for d in (2, 3)),
              flush=True)
    return {"P": count, "N": data.fit.time.size, "rounds": rounds, **out}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("what", choices=("chains", "gear", "speed"))
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--search", action="store_true",
                        help="chains: search the structure with the system GP")
    parser.add_argument("--population", type=int, default=100)
    parser.add_argument("--generations", type=int, default=3)
    parser.add_argument("--third-law", action="store_true", dest="third_law",
                        help="chains: impose Newton's third law (shared coupling constants)")
    parser.add_argument("--systems", default="chain2,chain3",
                        help="chains: which, comma-separated (default chain2,chain3)")
    parser.add_argument("--json", help="write the results here")
    args = parser.parse_args()
    result = {**provenance(), "load_average": os.getloadavg()}
    if args.what == "chains":
        rows = chains(args.seeds, args.search, args.population, args.generations,
                      args.third_law, args.systems.split(","))
        result["search"] = args.search and {"population": args.population,
                                            "generations": args.generations, "max_degree": 4}
        result["third_law"] = args.third_law
        result["rows"] = rows
        print(f"\n{'system':<8} {'structure right':>16} {'constants ≤ 2 %':>16} "
              f"{'all coordinates NRMS ≤ 2 %':>28} {'median NRMS':>12}")
        for name in args.systems.split(","):
            mine = [r for r in rows if r["system"] == name]
            good = sum(max(r["nrms"]) <= 0.02 for r in mine)
            print(f"{name:<8} {sum(r['structure_right'] for r in mine):>13}/{len(mine)} "
                  f"{sum(r['max_constant_error'] <= 0.02 for r in mine):>13}/{len(mine)} "
                  f"{good:>25}/{len(mine)} "
                  f"{np.median([max(r['nrms']) for r in mine]):>12.3%}")
    elif args.what == "gear":
        result["gear"] = gear()
    else:
        result["speed"] = speed()
    if args.json:
        with open(args.json, "w", encoding="utf-8") as handle:
            json.dump(result, handle, indent=1, default=float)


if __name__ == "__main__":
    main()
