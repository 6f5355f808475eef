"""The paper's protocol on the bundled gear example, fitted once for this file: what the
run reports (timings, the equations table, the reference-solve check), and how its model
simulates, saves and reloads (API and ``gpjax simulate``)."""

import json
import subprocess
import sys

import numpy as np
import pytest

from gpjax import GPConfig, Identifier, Measurement, Model, UserInputError
from gpjax.gear import load_bundled_example

# The demo fit (~35 s) and its checks: CI's slow step, so the fast tier stays within 5 min.
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def demo_fit(tmp_path_factory):
    """The paper's protocol on the bundled example: (identifier with its run folder
    ``identifier.run_dir``, measurement, truth)."""
    measurement, truth = load_bundled_example()
    out = tmp_path_factory.mktemp("demo-run")
    identifier = Identifier(GPConfig.paper()).fit(measurement, seed=0, out=out)
    identifier.run_dir = out
    return identifier, measurement, truth


def test_timings_split_the_run_into_its_stages(demo_fit):
    t = demo_fit[0].timings_
    assert 0 < t["selection_s"] and 0 < t["convergence_s"] and 0 <= t["compile_s"]
    assert 0 < t["intervals_s"]  # the standard errors and residual statistics
    assert t["selection_s"] + t["convergence_s"] < t["total_s"]
    parts = (t["search_s"] + t["selection_s"] + t["convergence_s"] + t["intervals_s"]
             + t["writing_s"])
    assert parts == pytest.approx(t["total_s"], rel=1e-9)  # every second accounted for
    assert t["compiles"] >= 1 and t["generations"] >= 0


def test_identifier_simulates_new_inputs_and_reloads_to_score_again(demo_fit):
    identifier, measurement, _ = demo_fit
    model = identifier.model_
    u = {"T": 1.1 * measurement.inputs["T"]}
    x0 = (0.0, 0.0)
    np.testing.assert_allclose(identifier.simulate(measurement.time, u, x0),
                               model.simulate_inputs(measurement.time, u, x0), rtol=0, atol=0)
    default = identifier.simulate(measurement.time, measurement.inputs)
    np.testing.assert_allclose(default, identifier.simulate(), rtol=0, atol=1e-12)
    rows = identifier.equations_
    chosen = [i for i, row in enumerate(rows) if row["selected"]][0]
    assert identifier.sympy(chosen) == identifier.sympy()
    assert identifier.latex(0) != identifier.latex(chosen)
    again = Identifier.load(identifier.run_dir, measurement)
    assert again.score() == pytest.approx(identifier.score(), rel=1e-12)
    assert [str(again.sympy(i)) for i in range(len(rows))] == [
        str(identifier.sympy(i)) for i in range(len(rows))]
    other = Measurement(time=measurement.time, response=measurement.response[::-1].copy(),
                        inputs=measurement.inputs, time_name="t", response_name="phi")
    with pytest.raises(UserInputError, match="not the data"):
        Identifier.load(identifier.run_dir, other)


def test_the_reported_model_means_the_same_under_the_reference_solver(demo_fit):
    identifier, measurement, truth = demo_fit
    model = identifier.model_
    check = model.convergence
    assert check["converged"] and check["ratio"] < 0.01
    assert model.substeps == check["substeps"] > 1  # one RK4 step per sample is not enough
    # the loop refitted at more steps (one step per sample is not enough) and says why it
    # stopped: the check passed
    assert check["stopped"] == "converged" and check["refits"] == len(identifier.convergence_) - 1
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


def test_gpjax_simulate_writes_the_reference_response(demo_fit, tmp_path):
    identifier, measurement, _ = demo_fit
    identifier.model_.save(tmp_path / "model.json")
    measurement.to_csv(tmp_path / "data.csv")
    done = _cli("simulate", "model.json", "data.csv", "--out", "sim.csv", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    table = np.loadtxt(tmp_path / "sim.csv", delimiter=",", skiprows=1)
    header = (tmp_path / "sim.csv").read_text().splitlines()[0]
    assert header == "t,phi" and table.shape == (measurement.n_samples, 2)
    from gpjax._model import fitted_initial_state
    from gpjax._weak_form import estimate_initial_conditions
    start = fitted_initial_state(identifier.model_, measurement,  # the command's own state
                                 estimate_initial_conditions(measurement))
    expected = identifier.model_.simulate(measurement, initial_conditions=tuple(start))
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
