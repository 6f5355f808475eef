"""Converged integration: the reference solve, the step-count rule and the model check
(the check of a whole fit, and ``gpjax simulate``: tests/test_demo_run.py)."""

import dataclasses
import math

import numpy as np
import pytest
from scipy.linalg import expm

from gpjax import Model, Symbols
from gpjax._convergence import (MAX_SUBSTEPS, Convergence, bandwidth_hz, check_model,
                                fit_converged, initial_substeps, needed_substeps,
                                next_substeps, reference_started, stable_substeps)
from gpjax._data import Measurement

S = Symbols("x", "t", ("u",))
M, C, K = 1.0, 3.0, 40.0 ** 2  # ω·dt = 0.8 at dt = 0.02


def _held_record(n=400, dt=0.02, seed=3):
    """A linear oscillator driven by a zero-order-hold input, solved exactly sample to
    sample (constant forcing over each interval: the augmented matrix exponential)."""
    rng = np.random.default_rng(seed)
    u = rng.normal(0.0, 100.0, n)
    a = np.array([[0.0, 1.0, 0.0], [-K / M, -C / M, 1.0 / M], [0.0, 0.0, 0.0]])
    step = expm(a * dt)
    y = np.zeros((n, 2))
    y[0] = (0.01, -0.2)
    for k in range(n - 1):
        y[k + 1] = (step @ np.array([*y[k], u[k]]))[:2]
    return Measurement(time=dt * np.arange(n), response=y[:, 0], inputs={"u": u},
                       time_name="t", response_name="x")


def _noisy(record: Measurement, seed: int = 0) -> Measurement:
    """``record`` with white noise of 2 % of its response's spread added to the response."""
    rng = np.random.default_rng(seed)
    return Measurement(time=record.time, response=record.response + rng.normal(
        0, 0.02 * np.std(record.response), record.n_samples), inputs=record.inputs,
        time_name="t", response_name="x")


def _model(interpolation, **changes):
    return Model.single(S, mass=M, state={"x": K, "x_dot": C}, forcing={"u": 1.0},
                 input_interpolation=interpolation, **changes)


def test_reference_solve_matches_the_exact_solution_of_a_held_input():
    record = _held_record()
    x = _model("hold").simulate(record, initial_conditions=(0.01, -0.2))
    assert np.max(np.abs(x - record.response)) < 1e-9 * np.ptp(record.response)


@pytest.mark.slow  # ~17 s on 2 cores: the fast tier stays within 5 minutes
def test_rk4_converges_to_the_reference_at_fourth_order_for_every_input_reconstruction():
    record = _held_record()
    for interpolation in ("hold", "linear", "bandlimited"):
        model = _model(interpolation, initial_conditions=(0.01, -0.2))
        reference = model.simulate(record, initial_conditions=(0.01, -0.2))
        errors = [np.sqrt(np.mean((model.simulate(record, initial_conditions=(0.01, -0.2),
                                                  solver="rk4") - reference) ** 2))
                  for model in (_model(interpolation, substeps=s) for s in (1, 2, 4))]
        assert errors[0] / errors[1] > 10 and errors[1] / errors[2] > 10, (interpolation,
                                                                            errors)


def test_the_step_rule_follows_the_bandwidth_and_the_fourth_order_error():
    record = _held_record()
    assert 0 < bandwidth_hz(record) <= 25.0  # the Nyquist frequency
    phase = 2 * math.pi * bandwidth_hz(record) * record.dt
    assert initial_substeps(record) == max(1, math.ceil(phase / 0.5))
    failed = Convergence(substeps=2, rms_rk4=1.0, rms_reference=1.0, difference_rms=0.08,
                         ratio=0.08, tolerance=0.01)
    wanted = next_substeps(failed)  # (0.08 / 0.005)^(1/4) = 2: the law asks for twice
    assert wanted == 4 and not failed.converged
    # the law's count as it is, not rounded up to twice the last: (0.0104 / 0.005)^(1/4)
    # = 1.2 (Silverbox's estimation part at 5 steps asks for 7, which pass, not 10)
    assert next_substeps(dataclasses.replace(failed, substeps=5, ratio=0.0104)) == 7
    # a law that asks for no more than the last count still moves one step
    assert next_substeps(dataclasses.replace(failed, substeps=5, ratio=0.005)) == 6
    assert next_substeps(Convergence(2, 1.0, math.inf, math.inf, math.inf, 0.01)) == 8


def test_a_coarse_model_fails_the_check_and_a_fine_one_passes():
    record = _held_record()
    coarse, reference = check_model(_model("hold", initial_conditions=(0.01, -0.2)), record,
                                    tolerance=0.01)
    # the exact data: the residual is the integrator's error alone, so any step fails 1 %
    assert not coarse.converged and coarse.ratio > 0.5
    assert np.max(np.abs(reference - record.response)) < 1e-9 * np.ptp(record.response)
    noisy = _noisy(record)
    fine, _ = check_model(_model("hold", initial_conditions=(0.01, -0.2), substeps=8), noisy,
                          tolerance=0.01)
    assert fine.converged and fine.ratio < 0.01


def test_the_doubling_estimate_measures_rk4s_error_as_the_reference_does():
    """Richardson: 16/15 of RK4's change from h to h/2 is its error at h, to leading order,
    so the estimate's ratio is the Dopri8 check's where RK4 is in its h⁴ regime."""
    record = _held_record()
    noisy = _noisy(record)
    for steps in (2, 4):
        model = _model("linear", initial_conditions=(0.01, -0.2), substeps=steps)
        exact, _ = check_model(model, noisy, tolerance=0.01)
        estimated, _ = check_model(model, noisy, tolerance=0.01, estimate="doubling")
        assert exact.estimate == "reference" and estimated.estimate == "doubling"
        assert abs(estimated.ratio / exact.ratio - 1) < 0.1, (steps, estimated, exact)
    with pytest.raises(ValueError, match="estimate"):
        check_model(model, noisy, tolerance=0.01, estimate="halving")


def test_the_step_count_is_measured_where_the_fourth_order_law_does_not_hold_yet():
    """A sharp smoothed sign (tanh(200·x')): the h⁴ law from the check at one step asks for
    2 steps, which still fail; the measured count passes with half the tolerance."""
    record = _held_record()
    noisy = _noisy(record)
    model = Model.single(S, mass=M, state={"x": K, "x_dot": C, "tanh(200*x_dot)": 20.0},
                         forcing={"u": 1.0}, input_interpolation="hold",
                         initial_conditions=(0.01, -0.2))
    check, reference = check_model(model, noisy, tolerance=0.01)
    law = next_substeps(check)
    at_law, _ = check_model(dataclasses.replace(model, substeps=law), noisy, tolerance=0.01)
    assert not check.converged and not at_law.converged
    steps = needed_substeps(model, noisy, check, reference)
    passed, _ = check_model(dataclasses.replace(model, substeps=steps), noisy, tolerance=0.01)
    assert steps > law and passed.ratio < 0.005


def test_models_differing_only_in_a_features_numbers_share_one_reference_solve():
    """A sign narrowed for the width check, or another sin frequency, is a value of the
    compiled reference solve, not a new program; exponents stay in the structure."""
    from gpjax._reference import _structure

    def structure(scale, frequency):
        model = Model.single(S, mass=M, state={"x**3": K, f"tanh({scale}*x_dot)": 2.0,
                                               f"sin({frequency}*x)": 1.0},
                             forcing={"u": 1.0})
        return _structure(model.system)

    (a, names_a, values_a), (b, names_b, values_b) = structure(500, 1.5), structure(2000, 2.5)
    assert a == b and names_a == names_b
    assert sorted(set(values_b) - set(values_a)) == [2.5, 2000.0]
    assert a[0].has(S.x ** 3)


def test_records_of_one_length_bucket_share_one_reference_solve():
    """The record enters the reference solve padded to its length bucket: a record of
    another length in the bucket takes the executable the first one got (none compiled or
    loaded), and its response is the longer record's first samples (each interval is
    solved on its own, the padding never)."""
    from gpjax import _aot
    from gpjax._record import padded_length
    from gpjax._reference import reference_response

    record, model = _held_record(n=400), _model("linear")
    assert padded_length(400) == padded_length(390)
    long, ok_long = reference_response(model, record.time, record.inputs, [(0.01, -0.2)])
    executables = _aot._LEDGER[1]
    short, ok_short = reference_response(model, record.time[:390],
                                         {"u": record.inputs["u"][:390]}, [(0.01, -0.2)])
    assert _aot._LEDGER[1] == executables
    assert ok_long and ok_short and long.shape == (400, 1) and short.shape == (390, 1)
    np.testing.assert_array_equal(short, long[:390])


def test_a_sticking_mass_needs_a_stable_step_and_a_crossing_does_not():
    """tanh(43799·x') on a 2 kg mass: rate 3·43799/2 ≈ 65,700 /s, so dt = 1 ms needs
    ceil(65.7 / 2.785) = 24 steps while the mass sticks (x' = 0 for many samples); a
    response that crosses x' = 0 within a sample interval keeps one step. A check at fewer
    steps than the stable count does not converge, whatever its RMS ratio."""
    t = np.arange(0.0, 2.0, 1e-3)
    model = Model.single(S, mass=2.0, state={"x_dot": 4.0, "tanh(43799*x_dot)": 3.0},
                         forcing={"u": 1.0})
    data = Measurement(time=t, response=np.sin(3 * t), inputs={"u": np.sin(t)},
                       time_name="t", response_name="x")
    stuck = np.where(t < 1.0, 0.01, np.sin(3 * t))
    assert stable_substeps(model, data, stuck) == 24
    assert stable_substeps(model, data, np.sin(3 * t)) == 1
    check = Convergence(4, 1.0, 1.0, 0.001, 0.001, 0.01, t.size, stable_substeps=24)
    assert not check.converged and next_substeps(check) == 24


def test_the_fit_ladder_refits_until_the_check_passes_and_stops_on_a_failed_fit():
    """:func:`fit_converged`, the one ladder of the estimator, systems and the diagnosis:
    a coarse fit is fitted again at the step count its check asks for, until it passes; a
    fit that fails (``None``) leaves the last model and its checks; ``unsolved_ends`` stops
    at a check whose reference solve failed, which otherwise climbs to the cap."""
    record = _held_record()
    noisy = _noisy(record)
    asked = []

    def fit_at(steps, previous):
        asked.append((steps, previous is not None))
        return _model("hold", initial_conditions=(0.01, -0.2), substeps=steps)

    model, checks, reference = fit_converged(fit_at, noisy, substeps=None, tolerance=0.01,
                                             first=1)
    assert [c.converged for c in checks] == [False] * (len(checks) - 1) + [True]
    # the failing rungs by the doubling estimate, the one that passes by the reference
    assert [c.estimate for c in checks] == ["doubling"] * (len(checks) - 1) + ["reference"]
    assert asked[0] == (1, False) and all(again for _, again in asked[1:])
    # unconfirmed, the passing estimate stands; with unsolved_ends the failing rungs are
    # the reference's; the ladder is the same
    del asked[:]
    _, unconfirmed, _ = fit_converged(fit_at, noisy, substeps=None, tolerance=0.01, first=1,
                                      confirm=False, unsolved_ends=True)
    assert [c.substeps for c in unconfirmed] == [c.substeps for c in checks]
    assert [c.estimate for c in unconfirmed] == ["reference"] * (len(checks) - 1) + ["doubling"]
    passing, _, _ = fit_converged(fit_at, noisy, substeps=None, tolerance=0.01,
                                  first=checks[-1].substeps, confirm=False)
    assert len(asked) == len(checks) + 1 and passing.substeps == checks[-1].substeps
    assert model.substeps == checks[-1].substeps > 1 and reference.shape == (noisy.n_samples,)

    failing = iter([_model("hold", initial_conditions=(0.01, -0.2), substeps=1), None])
    model, checks, _ = fit_converged(lambda steps, previous: next(failing), noisy,
                                     substeps=None, tolerance=0.01, first=1)
    assert model.substeps == 1 and len(checks) == 1 and not checks[0].converged

    # m·x'' + K·x − 1e9·x³ = u from x = 0.01: the cubic wins and x escapes in finite time
    blowing_up = Model.single(S, mass=M, state={"x": K, "x**3": -1e9}, forcing={"u": 1.0},
                              input_interpolation="hold", initial_conditions=(0.01, -0.2))
    ladders = {}
    for ends in (True, False):
        steps_asked = []

        def fit_unsolved(steps, previous, steps_asked=steps_asked):
            steps_asked.append(steps)
            return dataclasses.replace(blowing_up, substeps=steps)

        _, checks, _ = fit_converged(fit_unsolved, noisy, substeps=None, tolerance=0.01,
                                     first=1, unsolved_ends=ends)
        # the reference cannot integrate it (its RK4 responses at h and h/2 agree, on a
        # response 1e16 large, but not at a stable step): the last check is the reference's
        assert not math.isfinite(checks[-1].ratio) and checks[-1].estimate == "reference"
        ladders[ends] = steps_asked
    assert ladders[True] == [1] and ladders[False][-1] == MAX_SUBSTEPS


def test_a_reference_started_in_the_background_is_the_checks_own_and_the_ladder_takes_it():
    """:func:`reference_started` compiles in the calling thread and solves in another: the
    compile is counted when it returns, its response is the one :func:`check_model` solves
    itself, and a ``fit_at`` that returns (model, future) has its Dopri8 check take that
    response instead of solving again (a stand-in response shows it was used)."""
    from concurrent.futures import Future

    from gpjax import _aot

    record = _held_record()
    noisy = _noisy(record, seed=1)
    # a structure no other test solves: its executable is compiled (or loaded) here
    model = Model.single(S, mass=M, state={"x": K, "x_dot": C, "x**3": 1.0},
                         forcing={"u": 1.0}, input_interpolation="hold",
                         initial_conditions=(0.01, -0.2), substeps=8)
    compiled = _aot._LEDGER[1]
    started = reference_started(model, noisy)
    assert _aot._LEDGER[1] == compiled + 1  # before the solve's result is asked for
    own, reference = check_model(model, noisy, tolerance=0.01)
    np.testing.assert_array_equal(started.result(), reference)
    assert check_model(model, noisy, tolerance=0.01, reference=started.result())[0] == own

    stand_in = reference + 0.5 * np.std(reference)

    def fit_at(steps, previous):
        future = Future()
        future.set_result(stand_in)
        return model, future

    _, checks, taken = fit_converged(fit_at, noisy, substeps=8, tolerance=0.01)
    assert checks[-1].estimate == "reference" and not checks[-1].converged
    np.testing.assert_array_equal(taken, stand_in)
