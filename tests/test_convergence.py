"""Converged integration: the reference solve, the step-count rule, the fit's check, and
``gpjax simulate``."""

import json
import math
import subprocess
import sys

import numpy as np
import pytest
from scipy.linalg import expm

from gpjax import Model, Symbols
from gpjax._convergence import (Convergence, bandwidth_hz, check_model, initial_substeps,
                                next_substeps)
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


def _model(interpolation, **changes):
    return Model(symbols=S, mass=M, state={"x": K, "x_dot": C}, forcing={"u": 1.0},
                 input_interpolation=interpolation, **changes)


def test_reference_solve_matches_the_exact_solution_of_a_held_input():
    record = _held_record()
    x = _model("hold").simulate(record, initial_conditions=(0.01, -0.2))
    assert np.max(np.abs(x - record.response)) < 1e-9 * np.ptp(record.response)


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
    wanted = next_substeps(failed)  # (0.08 / 0.005)^(1/4) = 2 → twice the steps at least
    assert wanted == 4 and not failed.converged
    assert next_substeps(Convergence(2, 1.0, math.inf, math.inf, math.inf, 0.01)) == 8


def test_a_coarse_model_fails_the_check_and_a_fine_one_passes():
    record = _held_record()
    coarse, reference = check_model(_model("hold", initial_conditions=(0.01, -0.2)), record,
                                    tolerance=0.01)
    # the exact data: the residual is the integrator's error alone, so any step fails 1 %
    assert not coarse.converged and coarse.ratio > 0.5
    assert np.max(np.abs(reference - record.response)) < 1e-9 * np.ptp(record.response)
    noisy = Measurement(time=record.time, response=record.response + np.random.default_rng(0)
                        .normal(0, 0.02 * np.std(record.response), record.n_samples),
                        inputs=record.inputs, time_name="t", response_name="x")
    fine, _ = check_model(_model("hold", initial_conditions=(0.01, -0.2), substeps=8), noisy,
                          tolerance=0.01)
    assert fine.converged and fine.ratio < 0.01


def test_the_reported_model_means_the_same_under_the_reference_solver(demo_fit):
    identifier, measurement, truth = demo_fit
    model = identifier.model_
    check = model.convergence
    assert check["converged"] and check["ratio"] < 0.01
    assert model.substeps == check["substeps"] > 1  # one RK4 step per sample is not enough
    reference = identifier.simulate()
    rk4 = identifier.simulate(solver="rk4")
    residual = np.sqrt(np.mean((measurement.response - reference) ** 2))
    assert np.sqrt(np.mean((rk4 - reference) ** 2)) < 0.01 * residual
    assert model.metrics["rms_reference"] == pytest.approx(residual, rel=1e-6)
    assert identifier.score() > 0.999
    assert "reference solve" in str(identifier)
    for name, key in (("J", "m"), ("K1", "k1"), ("K2", "k2")):
        assert model.constants()[key] == pytest.approx(truth[name], rel=0.01)


def _cli(*args, cwd):
    return subprocess.run([sys.executable, "-m", "gpjax", *map(str, args)], cwd=cwd,
                          capture_output=True, text=True, timeout=300)


@pytest.mark.slow  # a CLI run: CI's slow step (fast tier <= 5 min on 2 cores)
def test_gpjax_simulate_writes_the_reference_response(demo_fit, tmp_path):
    identifier, measurement, _ = demo_fit
    identifier.model_.save(tmp_path / "model.json")
    measurement.to_csv(tmp_path / "data.csv")
    done = _cli("simulate", "model.json", "data.csv", "--out", "sim.csv", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    table = np.loadtxt(tmp_path / "sim.csv", delimiter=",", skiprows=1)
    header = (tmp_path / "sim.csv").read_text().splitlines()[0]
    assert header == "t,phi" and table.shape == (measurement.n_samples, 2)
    expected = identifier.model_.simulate(measurement)
    np.testing.assert_allclose(table[:, 1], expected, rtol=0, atol=1e-12)
    # without the response column the initial state must be given
    inputs_only = tmp_path / "inputs.csv"
    inputs_only.write_text("t,T\n" + "".join(
        f"{float(t)!r},{float(u)!r}\n" for t, u in zip(measurement.time, measurement.inputs["T"])))
    refused = _cli("simulate", "model.json", "inputs.csv", "--out", "sim2.csv", cwd=tmp_path)
    assert refused.returncode == 2 and not (tmp_path / "sim2.csv").exists()
    assert refused.stderr.count("\n") == 1 and "--initial" in refused.stderr
    given = _cli("simulate", "model.json", "inputs.csv", "--out", "sim2.csv", "--initial",
                 *identifier.model_.initial_conditions, cwd=tmp_path)
    assert given.returncode == 0, given.stderr
    again = np.loadtxt(tmp_path / "sim2.csv", delimiter=",", skiprows=1)
    reference = identifier.simulate()
    np.testing.assert_allclose(again[:, 1], reference, rtol=0, atol=1e-9 * np.ptp(reference))


def test_model_file_records_the_integration_and_refuses_a_bad_one(demo_fit, tmp_path):
    identifier = demo_fit[0]
    data = identifier.model_.to_json()
    assert data["simulation"]["integrator"] == {"method": "rk4",
                                                "substeps": identifier.model_.substeps}
    assert data["simulation"]["reference_solver"]["method"] == "diffrax.Dopri8"
    assert Model.from_json(json.loads(json.dumps(data))) == identifier.model_
    data["simulation"]["integrator"] = {"method": "rk4", "substeps": 0}
    with pytest.raises(Exception, match="simulation.integrator"):
        Model.from_json(data)
