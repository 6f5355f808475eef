"""Standard errors and intervals of constants (gpjax._uncertainty): the sandwich against
the classical covariance where that one is right, its coverage where it is not (a
narrow-band error under the regressors, as input noise rings through a resonance), the
file format and the printed forms."""

import json
import math

import numpy as np
import pytest

from gpjax import Model, ModelFileError, Symbols
from gpjax._coefficients import FlatLayout
from gpjax._uncertainty import Uncertainty, sandwich_covariance


def test_white_noise_gives_the_classical_least_squares_covariance():
    rng = np.random.default_rng(0)
    n = 4000
    x = rng.normal(size=(n, 3))
    e = 0.5 * rng.normal(size=n)
    residual = e - x @ np.linalg.lstsq(x, e, rcond=None)[0]
    covariance, dof = sandwich_covariance(residual, x)
    classical = 0.25 * np.linalg.inv(x.T @ x)
    np.testing.assert_allclose(np.sqrt(np.diag(covariance)), np.sqrt(np.diag(classical)),
                               rtol=0.05)
    assert np.all(dof > 300)  # thousands of bins share the information


def _resonant_noise(rng, n, pole=0.995, frequency=0.03):
    """Unit white noise through a lightly damped second-order filter plus white noise:
    a small narrow-band part at ``frequency`` (cycles per sample) under a white floor."""
    a1, a2 = 2 * pole * math.cos(2 * math.pi * frequency), -pole ** 2
    white = rng.normal(size=n)
    ringing = np.zeros(n)
    for t in range(2, n):
        ringing[t] = a1 * ringing[t - 1] + a2 * ringing[t - 2] + white[t]
    return 0.02 * ringing + rng.normal(size=n)


def test_intervals_cover_under_a_narrow_band_error_where_the_classical_ones_do_not():
    """Regressors in the error's band (as the sensitivities of a resonant system are):
    the classical interval misses often; the sandwich's 95 % interval covers 88–99 % of
    200 records."""
    rng = np.random.default_rng(1)
    n = 1500
    t = np.arange(n)
    x = np.column_stack([np.sin(2 * np.pi * 0.03 * t + 0.3), np.cos(2 * np.pi * 0.031 * t),
                         np.ones(n)])
    covered, classical_covered = [], []
    for _ in range(200):
        error = _resonant_noise(rng, n)
        beta, *_ = np.linalg.lstsq(x, error, rcond=None)  # the truth is 0
        residual = error - x @ beta
        covariance, dof = sandwich_covariance(residual, x)
        u = Uncertainty(("a", "b", "c"), beta, covariance, dof, n)
        covered.append(all(u.interval(k)[0] <= 0 <= u.interval(k)[1] for k in u.names))
        sigma2 = residual @ residual / (n - 3)
        se = np.sqrt(np.diag(sigma2 * np.linalg.inv(x.T @ x)))
        classical_covered.append(bool(np.all(np.abs(beta) <= 1.96 * se)))
    assert 0.88 <= np.mean(covered) <= 0.99
    assert np.mean(classical_covered) < 0.75


def test_a_constant_the_record_cannot_identify_gets_an_infinite_error():
    x = np.column_stack([np.ones(100), np.ones(100)])
    covariance, _ = sandwich_covariance(np.zeros(100), x)
    assert np.all(np.isinf(np.diag(covariance)))


def test_layout_parts_name_every_flat_column():
    layout = FlatLayout(n_state=3, n_forcing=2, n_inner=2, n_coordinates=2)
    assert layout.part(layout.mass_column(1)) == ("mass", 1, 0)
    assert layout.part(layout.state_column(2, 1)) == ("state", 1, 2)
    assert layout.part(layout.forcing_column(1, 0)) == ("forcing", 0, 1)
    assert layout.part(layout.inner_column(1)) == ("inner", 0, 1)
    assert layout.part(layout.width - 1) == ("y0", 1, 1)
    with pytest.raises(IndexError):
        layout.part(layout.width)


def _model_with_intervals() -> Model:
    uncertainty = Uncertainty(("m", "k1", "x(0)"), np.array([1.002, 39.9, 0.01]),
                              np.diag([1e-6, 0.01, np.inf]), np.array([40.0, 12.0, 3.0]),
                              8000)
    return Model.single(symbols=Symbols("x", "t", ("u",)), mass=1.002, state={"x": 39.9},
                 forcing={"u": 1.0}, initial_conditions=(0.01, 0.0), uncertainty=uncertainty)


def test_the_model_prints_saves_and_reloads_its_intervals():
    model = _model_with_intervals()
    assert "m = 1.002 ± 0.002" in str(model) and "k1 = 39.9 ± 0.22" in str(model)
    assert r"\pm" in model.latex(numeric=True) and r"\pm" not in model.latex()
    data = json.loads(json.dumps(model.to_json()))
    constants = data["uncertainty"]["constants"]
    assert constants["x(0)"]["se"] is None  # not identifiable: null, not Infinity
    assert constants["k1"]["low"] < 39.9 < constants["k1"]["high"]
    assert Model.from_json(data) == model
    data["uncertainty"]["covariance"] = [[1.0]]
    with pytest.raises(ModelFileError, match="uncertainty"):
        Model.from_json(data)


@pytest.mark.slow  # ~20 s: a record generated and refitted at converged integration
def test_refit_of_the_true_structure_brackets_the_truth():
    """Duffing with 1 % noise on response and input: every constant within 4 standard
    errors of the truth, and no interval wider than ±2 %."""
    from gpjax import refit
    from gpjax.systems import generate

    synthetic = generate("duffing", seed=5, noise=0.01, input_noise=0.01)
    t = synthetic.truth
    start = Model.single(symbols=Symbols("x", "t", ("u",)), mass=1.1 * t["m"],
                  state={"x_dot": 0.9 * t["c"], "x": 1.05 * t["k"], "x**3": 0.9 * t["k3"]},
                  forcing={"u": 1.0}, input_interpolation="bandlimited")
    fitted = refit(start, synthetic.fit.measurement())
    assert fitted.convergence["converged"]
    band = fitted.uncertainty
    assert set(band.names) == {"m", "c1", "k1", "k2", "x(0)", "x'(0)"}
    for name, truth in (("m", t["m"]), ("c1", t["c"]), ("k1", t["k"]), ("k2", t["k3"])):
        value = fitted.constants()[name]
        assert abs(value - truth) < 4 * band.standard_errors[name], name
        assert band.half_width(name) < 0.02 * truth, name


def _oscillator_with_intervals(se_k: float) -> Model:
    """x'' + 2x' + 4x = u with a standard error ``se_k`` on k1 only (c1 nearly exact)."""
    import dataclasses

    model = Model.single(symbols=Symbols(response="x", time="t", inputs=("u",)), mass=1.0,
                  state={"x_dot": 2.0, "x": 4.0}, forcing={"u": 1.0})
    return dataclasses.replace(model, uncertainty=Uncertainty(
        names=("c1", "k1"), values=np.array([2.0, 4.0]),
        covariance=np.diag([1e-12, se_k ** 2]), dof=np.array([1e6, 1e6]), n_samples=1000))


def test_prediction_band_of_a_step_response_is_that_of_one_over_k():
    """At rest under a unit step, x → 1/k1: the band's edges are 1/(k1 ± 1.96 se)."""
    from gpjax import prediction_band

    model = _oscillator_with_intervals(0.04)
    t = np.arange(2000) * 0.01
    band = prediction_band(model, t, {"u": np.ones_like(t)}, (0.0, 0.0), draws=2000, seed=3)
    assert band.diverged == 0 and band.constants == ("c1", "k1")
    assert band.response[-1] == pytest.approx(0.25, rel=1e-6)
    expected = 1 / (4 + 1.96 * 0.04), 1 / (4 - 1.96 * 0.04)
    half = (expected[1] - expected[0]) / 2
    assert abs(band.low[-1] - expected[0]) < 0.05 * half
    assert abs(band.high[-1] - expected[1]) < 0.05 * half
    assert band.low[0] == band.high[0] == 0.0  # the initial state is held
    again = prediction_band(model, t, {"u": np.ones_like(t)}, (0.0, 0.0), draws=2000, seed=3)
    np.testing.assert_array_equal(again.high, band.high)


@pytest.mark.slow  # 13-21 s: the fast tier stays within 5 minutes on 2 cores
def test_gpjax_simulate_band_writes_edges_and_refuses_a_model_without_intervals(tmp_path):
    import dataclasses
    import subprocess
    import sys

    model = _oscillator_with_intervals(0.04)
    model.save(tmp_path / "model.json")
    dataclasses.replace(model, uncertainty=None).save(tmp_path / "bare.json")
    t = np.arange(1000) * 0.01
    (tmp_path / "in.csv").write_text("t,u\n" + "".join(f"{float(x)!r},1.0\n" for x in t))

    def cli(*args):
        return subprocess.run([sys.executable, "-m", "gpjax", "simulate", *args],
                              cwd=tmp_path, capture_output=True, text=True, timeout=300)

    done = cli("model.json", "in.csv", "--out", "band.csv", "--initial", "0", "0", "--band")
    assert done.returncode == 0, done.stderr
    lines = (tmp_path / "band.csv").read_text().splitlines()
    assert lines[0] == "t,x,x_low,x_high" and len(lines) == 1001
    table = np.loadtxt(tmp_path / "band.csv", delimiter=",", skiprows=1)
    assert np.all(table[:, 2] <= table[:, 1]) and np.all(table[:, 1] <= table[:, 3])
    assert table[-1, 3] - table[-1, 2] > 1e-3
    refused = cli("bare.json", "in.csv", "--out", "bare.csv", "--initial", "0", "0", "--band")
    assert refused.returncode == 2 and not (tmp_path / "bare.csv").exists()
    assert refused.stderr.count("\n") == 1 and "uncertainty" in refused.stderr


def test_profile_interval_follows_an_asymmetric_objective_at_the_sandwich_scale():
    """S(θ) rises 4× faster below θ̂ than above: the profile interval is θ̂ + (−t/2, +t)·s
    where the sandwich se equals the Gauss–Newton one, and twice as wide where the sandwich
    se is twice it (the magnitude adjustment); the file keeps it."""
    import dataclasses
    import types

    from gpjax._coefficients import Population
    from gpjax._profile import profile_bounds

    start = Population(mass=np.ones(1), state=np.zeros((1, 1)), forcing=np.zeros((1, 1)),
                       y0=np.zeros((1, 2)), inner=np.array([[2.0]]))
    refiner = types.SimpleNamespace(refine=lambda population, fixed, held: types.SimpleNamespace(
        population=population))  # nothing else to refit

    def objective(population):
        d = population.inner[:, 0] - 2.0
        return np.where(d < 0, 4.0, 1.0) * d ** 2 / 0.01 ** 2  # s0 = 0.01

    for se, factor in ((0.01, 1.0), (0.02, 2.0)):
        (low, high), = profile_bounds(refiner, start, np.array([-1]), None, inner={
            "k.θ1": {"slot": 0, "value": 2.0, "se": se, "naive_se": 0.01, "quantile": 1.96}},
            objective=objective, fitted=0.0).values()
        assert low == pytest.approx(2.0 - factor * 0.98 * 0.01, rel=1e-3)
        assert high == pytest.approx(2.0 + factor * 1.96 * 0.01, rel=1e-3)
    u = Uncertainty(("k.θ1",), np.array([2.0]), np.array([[0.02 ** 2]]), np.array([50.0]), 100,
                    profile={"k.θ1": (low, high)})
    assert u.interval("k.θ1") == (low, high)
    assert u.half_width("k.θ1") == pytest.approx((high - low) / 2)
    back = Uncertainty.from_json(json.loads(json.dumps(u.to_json())))
    assert back == u and dataclasses.replace(back, profile={}) != u


def test_a_constant_force_fitted_by_the_zero_bin_alone_still_gets_its_interval():
    """A constant regressor is fitted by the zero-frequency bin alone (leverage 1, no
    residual left there); its variance comes from the neighbouring bins. Under white noise
    that is the classical σ²/n, and over 300 records the 95 % interval covers 91–99 %."""
    rng = np.random.default_rng(2)
    n = 2000
    t = np.arange(n)
    x = np.column_stack([np.ones(n), np.sin(2 * np.pi * 0.01 * t), 0.001 * t])
    covered, ratios = [], []
    for _ in range(300):
        error = rng.normal(size=n)
        beta, *_ = np.linalg.lstsq(x, error, rcond=None)  # the truth is 0
        covariance, dof = sandwich_covariance(error - x @ beta, x)
        u = Uncertainty(("a", "b", "c"), beta, covariance, dof, n)
        covered.append(u.interval("a")[0] <= 0 <= u.interval("a")[1])
        ratios.append(math.sqrt(covariance[0, 0] / np.linalg.inv(x.T @ x)[0, 0]))
    assert np.all(np.isfinite(ratios)) and 0.9 <= np.median(ratios) <= 1.1
    assert 0.91 <= np.mean(covered) <= 0.99


def test_only_the_constants_of_an_undetermined_combination_lose_their_interval():
    """Two nearly proportional columns (a gear's two input torques, seed 0 of
    ``benchmarks/gear_front_door.py``) get no interval; the third constant keeps its own
    (before, one undetermined combination made every interval infinite)."""
    rng = np.random.default_rng(0)
    t = np.linspace(0.0, 1.0, 400)
    third = np.sin(7 * t)
    pair = np.column_stack([np.ones_like(t), np.ones_like(t) * (1 + 1e-9 * t)])
    residual = 0.01 * rng.standard_normal(t.size)
    covariance, dof = sandwich_covariance(residual, np.column_stack([pair, third]))
    assert np.all(np.isinf(np.diag(covariance)[:2]))
    assert np.isfinite(covariance[2, 2]) and covariance[2, 2] > 0
    assert np.all(covariance[2, :2] == 0) and dof[2] > 1


def test_a_constant_fitted_almost_only_by_the_zero_bin_gets_the_classical_interval():
    """A column that is nearly constant puts its constant's information in the zero bin,
    with leverage just below 1 (0.999 here; 0.9998 for the demo's undamped gear). Read from
    that one bin, CR3 inflated its variance by 1/(1 − h) and counted one χ²₁: the interval
    was ~17× the classical one with t₀.₉₇₅(1) = 12.7. The zero bin's variance is read from
    its neighbours: under white noise the classical σ²(XᵀX)⁻¹, and over 200 records the
    95 % interval covers 91–99 %."""
    rng = np.random.default_rng(3)
    n = 2000
    t = np.arange(n)
    x = np.column_stack([1 + 0.05 * np.sin(2 * np.pi * 0.01 * t),
                         np.sin(2 * np.pi * 0.013 * t + 0.4)])
    covered, ratios = [], []
    for _ in range(200):
        error = rng.normal(size=n)
        beta, *_ = np.linalg.lstsq(x, error, rcond=None)  # the truth is 0
        covariance, dof = sandwich_covariance(error - x @ beta, x)
        u = Uncertainty(("a", "b"), beta, covariance, dof, n)
        covered.append(u.interval("a")[0] <= 0 <= u.interval("a")[1])
        ratios.append(math.sqrt(covariance[0, 0] / np.linalg.inv(x.T @ x)[0, 0]))
    assert 0.85 <= np.median(ratios) <= 1.15
    assert 0.91 <= np.mean(covered) <= 0.99
