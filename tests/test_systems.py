"""The synthetic systems (gpjax.systems): reproducible, converged, honest truth."""

import dataclasses
import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest
import sympy as sp

import gpjax
from gpjax.systems import (PHYSICS_SUITE, SYSTEMS, SimulationError, compare_structure, cramer_rao,
                           generate, get_system, integrate, nrms, simulate_equations,
                           truth_error, truth_refit, write_csv)
from gpjax._stage import hold_step

X, X_DOT, X_DDOT, U = sp.symbols("x x_dot x_ddot u")
#: Full-length no-chaos checks in the fast run (the hardening Duffing is the one prone to
#: chaos; the stage is solved in closed form); every system's check is in the slow run.
FAST_CHAOS_CHECKS = {"duffing", "stage"}


def short(name, duration=2.0):
    return dataclasses.replace(get_system(name), duration=duration)


def test_same_seed_same_arrays_other_seed_other_arrays():
    system = short("duffing")
    a, b, c = (generate(system, seed=s) for s in (3, 3, 4))
    for record in ("fit", "extrapolation"):
        for field in ("input_true", "input_measured", "response_true", "response_measured"):
            first, again = getattr(getattr(a, record), field), getattr(getattr(b, record), field)
            assert np.array_equal(first, again), (record, field)
            assert not np.allclose(first, getattr(getattr(c, record), field)), (record, field)
    assert not np.allclose(a.fit.input_true, a.extrapolation.input_true[: a.fit.time.size])


@pytest.mark.parametrize("name", [n for n in SYSTEMS if SYSTEMS[n].loop is None])
def test_truth_integration_converged(name):
    system = short(name)
    force = system.excitation.draw(np.random.default_rng(0), system.time, 1.0)
    x, _ = integrate(system, system.time, force)
    step = (system.max_step or 1.0 / system.sample_rate) / 2
    finer, _ = integrate(system, system.time, force, rtol=1e-12, max_step=step)
    assert np.max(np.abs(finer - x)) < 1e-6 * np.max(np.abs(x))


def test_stage_hold_step_is_exact():
    # moving and slowing down to a reversal, then stuck (|drive| <= friction)
    x, v = hold_step(0.0, 1.0, 0.5, 10.0, mass=2.0, damping=4.0, friction=2.0)
    assert v == 0.0
    reversal = 0.5 * math.log((1.0 + 0.375) / 0.375)  # v∞ = (0.5 − 2)/4 = −0.375
    assert x == pytest.approx(-0.375 * reversal + 1.375 * 0.5 * (1 - math.exp(-reversal / 0.5)))
    # breaking away from rest: v(h) = v∞·(1 − e^(−h/τ)), v∞ = (5 − 2)/4
    x, v = hold_step(0.0, 0.0, 5.0, 0.1, mass=2.0, damping=4.0, friction=2.0)
    assert v == pytest.approx(0.75 * (1 - math.exp(-0.2)), rel=1e-14)


def test_noise_levels_as_requested():
    data = generate("duffing", seed=1, noise=0.02, input_noise=0.05)
    for record in (data.fit, data.extrapolation):
        response_noise = (record.response_measured - record.response_true).std()
        input_noise = (record.input_measured - record.input_true).std()
        assert response_noise == pytest.approx(0.02 * record.response_true.std(), rel=0.1)
        assert input_noise == pytest.approx(0.05 * record.input_true.std(), rel=0.1)
    clean = generate(short("duffing"), seed=1, noise=0.0, input_noise=0.0)
    assert np.array_equal(clean.fit.response_measured, clean.fit.response_true)


@pytest.mark.parametrize("scale", [1.1, 1.25])
def test_extrapolation_input_is_scale_times_larger(scale):
    data = generate(short("pendulum"), seed=2, extrapolation_scale=scale)
    rms = [np.sqrt(np.mean(r.input_true ** 2)) for r in (data.fit, data.extrapolation)]
    assert rms[1] / rms[0] == pytest.approx(scale, rel=1e-12)
    assert rms[0] == pytest.approx(data.system.excitation.rms, rel=1e-12)


@pytest.mark.parametrize("name", [n if n in FAST_CHAOS_CHECKS else
                                  pytest.param(n, marks=pytest.mark.slow) for n in SYSTEMS])
def test_truth_reproduces_its_own_data_no_chaos(name):
    # the stage is a free mass: replayed open loop, 1 % input noise integrates to a drift
    # of 3–15 σ over 20 s (measured, seeds 0–4); its check uses the exact input
    input_noise = 0.0 if name == "stage" else 0.01
    data = generate(name, seed=0, extrapolation_scale=1.25, input_noise=input_noise)
    for record in ("fit", "extrapolation"):
        assert np.all(truth_error(data, record=record) < 3.0), record


def test_csv_round_trips_through_load_csv(tmp_path):
    data = generate(short("saturating_spring"), seed=0)
    write_csv(data.fit, tmp_path / "fit.csv")
    loaded = gpjax.load_csv(tmp_path / "fit.csv", time="t", response="x", inputs=["u"])
    assert np.array_equal(loaded.time, data.fit.time)
    assert np.array_equal(loaded.response, data.fit.response_measured[0])
    assert np.array_equal(loaded.inputs["u"], data.fit.input_measured)


@pytest.mark.parametrize("layout", ["tab", "semicolon", "whitespace", "comment lines"])
def test_load_csv_reads_other_separators_and_skips_comment_lines(tmp_path, layout):
    """A rig's export separated by tabs, semicolons or spaces, or with ``#`` lines before
    its header, reads as the same values as the comma-separated file."""
    data = generate(short("saturating_spring"), seed=0)
    write_csv(data.fit, tmp_path / "fit.csv")
    text = (tmp_path / "fit.csv").read_text()
    text = {"tab": text.replace(",", "\t"), "semicolon": text.replace(",", ";"),
            "whitespace": text.replace(",", "   "),
            "comment lines": "# rig 3, channel map v2\n  # units: s, m, N\n" + text}[layout]
    (tmp_path / "other.csv").write_text(text)
    other = gpjax.load_csv(tmp_path / "other.csv", time="t", response="x", inputs=["u"])
    comma = gpjax.load_csv(tmp_path / "fit.csv", time="t", response="x", inputs=["u"])
    assert np.array_equal(other.time, comma.time)
    assert np.array_equal(other.response, comma.response)
    assert np.array_equal(other.inputs["u"], comma.inputs["u"])


def test_chain_gives_several_response_columns(tmp_path):
    data = generate(short("chain3"), seed=0)
    assert data.fit.response_true.shape == (3, data.fit.time.size)
    assert not np.allclose(data.fit.response_true[1], data.fit.response_true[2])
    write_csv(data.fit, tmp_path / "chain.csv")
    header = (tmp_path / "chain.csv").read_text().splitlines()[0]
    assert header == "t,x1,x2,x3,u"
    loaded = gpjax.load_csv(tmp_path / "chain.csv", time="t", response="x3", inputs=["u"])
    assert np.array_equal(loaded.response, data.fit.response_measured[2])
    assert data.fit.measurement("x2").response_name == "x2"


def test_stage_reads_a_quantised_encoder_in_closed_loop():
    data = generate(short("stage"), seed=0, noise=0.0)
    steps = data.fit.response_measured / data.system.loop.resolution
    assert np.allclose(steps, np.round(steps), atol=1e-6)
    assert np.std(data.fit.input_true) > data.system.constants["F"]


def test_bad_names_and_parameters_are_refused():
    with pytest.raises(ValueError, match="unknown system 'nope'"):
        generate("nope", seed=0)
    for bad in ({"seed": -1}, {"seed": 0, "noise": -0.1}, {"seed": 0, "input_noise": math.nan},
                {"seed": 0, "extrapolation_scale": 0.0}):
        with pytest.raises(ValueError):
            generate("duffing", **bad)
    with pytest.raises(ValueError, match="unknown coordinate"):
        generate(short("duffing"), seed=0).fit.measurement("y")


def test_structure_rule_counts_equivalent_forms():
    truth = get_system("stribeck").truth()[0]
    smoothed = sp.Eq(2.0 * X_DDOT + 1.2 * X_DOT + 2.0 * sp.tanh(X_DOT / 1e-4) + 80.02 * X
                     + 2.0 * sp.exp(-400.0 * X_DOT ** 2) * sp.tanh(1e4 * X_DOT), 2 * U)
    verdict = compare_structure(smoothed, truth, scales={X_DOT: 1.0})
    assert verdict["structure"] and verdict["constants"]
    assert not compare_structure(smoothed, truth, scales={X_DOT: 1e-3})["structure"]
    drag = get_system("quadratic_drag").truth()[0]
    swapped = sp.Eq(X_DDOT + 2.1 * sp.Abs(X_DOT) * X_DOT + 40 * X, U)
    verdict = compare_structure(swapped, drag)
    assert verdict["structure"] and not verdict["constants"]
    polynomial = compare_structure(sp.Eq(X_DDOT + X_DOT + X_DOT ** 3 + 40 * X, U), drag)
    assert polynomial["missing"] == ["x_dot*Abs(x_dot)"]
    assert sorted(polynomial["extra"]) == ["x_dot", "x_dot**3"]
    stiffening = get_system("exponential_stiffening")
    as_sinh = sp.Eq(X_DDOT + 2 * X_DOT + 10 * sp.sinh(4 * X), U)
    assert compare_structure(as_sinh, stiffening.truth()[0])["constants"]


@pytest.mark.parametrize("name", ["pendulum", "softening_spring"])
def test_scorer_reproduces_the_truth_on_the_extrapolation_record(name):
    data = generate(name, seed=0)
    record = data.extrapolation
    simulated = simulate_equations(data.system.truth(), record.coordinates, record.time,
                                   record.input_true, state0=record.initial_state)
    assert nrms(simulated, record.response_true) < 1e-5
    unstable = sp.Eq(X_DDOT - 50 * X ** 3, U)
    with pytest.raises(SimulationError, match="diverged"):
        simulate_equations([unstable], ("x",), record.time, record.input_true,
                           state0=record.initial_state, bound=100.0)


def test_physics_suite_names_the_nine_systems():
    assert len(PHYSICS_SUITE) == 9 and set(PHYSICS_SUITE) <= set(SYSTEMS)
    assert all(len(SYSTEMS[n].coordinates) == 1 for n in PHYSICS_SUITE)


def test_dry_friction_sticks_then_slips_as_the_closed_form():
    # x'' + sign(x') = 2·sin(t) from rest: stuck until 2·sin(t) = 1 (t0 = π/6), then
    # v(t) = 2·(cos t0 − cos t) − (t − t0) until v returns to 0
    law = sp.Eq(X_DDOT + sp.sign(X_DOT), U)
    time = np.linspace(0.0, 2.0, 201)
    x = simulate_equations([law], ("x",), time, 2 * np.sin(time), state0=np.zeros(2))[0]
    t0 = math.pi / 6
    assert np.all(x[time <= t0] == 0.0)
    moving = (time > t0) & (time < 2.0)
    exact = (2 * math.cos(t0) * (time - t0) - 2 * (np.sin(time) - math.sin(t0))
             - (time - t0) ** 2 / 2)
    assert np.allclose(x[moving], exact[moving], rtol=1e-7, atol=1e-9)


def _physics_suite():
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "physics_suite.py"
    spec = importlib.util.spec_from_file_location("physics_suite", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_physics_suite_records_a_crashed_fit_as_a_row():
    suite = _physics_suite()
    data = generate(short("duffing"), seed=0)
    row = suite._row(data, "broken", lambda: 1 / 0)
    assert row["error"].startswith("ZeroDivisionError") and row["nrms"] is None
    truth = suite._row(data, "truth", lambda: data.system.truth()[0])
    assert truth["error"] is None and truth["structure"] and truth["nrms"] < 1e-5


def test_truth_refit_lowers_the_misfit_within_the_floor_and_returns_exact_data_unchanged():
    """On noisy data the refitted constants leave the truth (the data are noisy) for a
    smaller misfit than the truth's, within 4 Cramér–Rao σ of it (the input exact, so the
    floor holds); on noise-free data they are the truth."""
    system = short("duffing")
    noisy = generate(system, seed=1, noise=0.02, input_noise=0.0)
    refit = truth_refit(noisy)
    floor = cramer_rao(noisy)
    errors = {k: refit[k] / system.constants[k] - 1 for k in refit}
    assert all(abs(errors[k]) < 4 * floor[k] for k in errors), (errors, floor)
    assert max(abs(errors[k]) / floor[k] for k in errors) > 0.3, (errors, floor)

    def misfit(constants):  # RMS misfit in noise σ under the measured input
        return float(truth_error(dataclasses.replace(
            noisy, system=dataclasses.replace(system, constants=constants)))[0])

    assert misfit(refit) < misfit(system.constants)
    moved = {k: v * (1 + 0.3 * floor[k] * np.sign(errors[k])) for k, v in refit.items()}
    assert misfit(refit) < misfit(moved)  # at the minimum: a step further is worse
    exact = truth_refit(generate(system, seed=1, noise=0.0, input_noise=0.0))
    assert all(math.isclose(exact[k], v, rel_tol=1e-5) for k, v in system.constants.items())


def test_physics_suite_runs_only_the_methods_asked_for():
    with pytest.raises(SystemExit, match="unknown method 'oracle'"):
        _physics_suite().main(["--methods", "oracle"])


@pytest.mark.slow
@pytest.mark.handrun  # minutes on 2 cores: the hand-run tier (README, Quick start)
def test_physics_suite_runs_end_to_end(tmp_path):
    out = tmp_path / "suite.json"
    assert _physics_suite().main(["--systems", "duffing", "--seeds", "1", "--population",
                                  "20", "--generations", "1", "--methods",
                                  "truth,gpjax,gpjax-no-local-search", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())["rows"]
    assert [r["method"] for r in rows] == ["truth", "gpjax", "gpjax-no-local-search"]
    assert all(r["error"] is None for r in rows)


@pytest.mark.slow
def test_cramer_rao_floor_tells_an_identifiable_constant_from_one_that_is_not():
    """On the suite's records the Duffing constants are pinned far below 2 %; the
    Stribeck velocity vs = 2 % of RMS(x') acts on a few per cent of the samples and is
    not; the floor scales with the noise."""
    duffing = cramer_rao(generate("duffing", seed=0))
    assert max(duffing.values()) < 0.005, duffing
    stribeck = cramer_rao(generate("stribeck", seed=0))
    assert stribeck["vs"] > 0.1 and stribeck["k"] < 0.005, stribeck
    louder = cramer_rao(generate("duffing", seed=0, noise=0.04))
    assert all(math.isclose(louder[k], 4 * duffing[k], rel_tol=1e-6) for k in duffing)
