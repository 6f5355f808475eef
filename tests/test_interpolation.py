"""Inputs between samples: linear, band-limited or zero-order-hold reconstruction at the
RK4 stage times, in the evaluator, the refiner, the configuration and the model file."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from gpjax import GPConfig, Model, Symbols
from gpjax.engine import PopulationEvaluator
from gpjax._data import Measurement, between_samples
from gpjax._model import simulate_model
from gpjax._refine import Refiner

FS = 610.0  # Hz, the Silverbox rate


def _signal(t):
    return np.sin(2 * np.pi * 190.0 * t + 0.3) + 0.5 * np.sin(2 * np.pi * 23.0 * t)


def test_between_samples_passes_through_the_samples_and_reconstructs_a_band_limited_signal():
    """At 610 Hz a 190 Hz sine interpolated linearly loses half its amplitude between
    samples; the band-limited reconstruction recovers it (away from the record's ends)."""
    n, factor = 2000, 4
    values = _signal(np.arange(n) / FS)
    fine_time = np.arange((n - 1) * factor + 1) / (FS * factor)
    band = between_samples(values, factor, "bandlimited")
    linear = between_samples(values, factor, "linear")
    for out in (band, linear):
        assert out.shape == fine_time.shape and np.array_equal(out[::factor], values)
    assert np.allclose(linear, np.interp(fine_time, np.arange(n) / FS, values))
    inner = slice(100 * factor, -100 * factor)
    assert np.max(np.abs(band - _signal(fine_time))[inner]) < 0.01
    assert np.max(np.abs(linear - _signal(fine_time))[inner]) > 0.4
    assert np.array_equal(between_samples(values, 1, "bandlimited"), values)
    with pytest.raises(ValueError, match="factor"):
        between_samples(values, 0)
    with pytest.raises(ValueError, match="interpolation"):
        between_samples(values, 2, "spline")


def _oscillator_record():
    """m·y'' + d·y' + k·y = u with u the two-tone signal above, sampled at 610 Hz; the
    response from the continuous input (DOP853)."""
    m, d, k = 1.0, 40.0, (2 * np.pi * 60.0) ** 2
    time = np.arange(1500) / FS
    solution = solve_ivp(lambda t, y: [y[1], (_signal(t) - d * y[1] - k * y[0]) / m],
                         (0, time[-1]), [0.0, 0.0], method="DOP853", t_eval=time,
                         rtol=1e-12, atol=1e-14)
    record = Measurement(time=time, response=solution.y[0], inputs={"u": _signal(time)},
                         time_name="t", response_name="y")
    return record, (m, d, k)


@pytest.mark.parametrize("substeps", [1, 4])
def test_band_limited_inputs_simulate_the_true_model_closer_to_the_data(substeps):
    """The exact model, simulated on the sampled input: linear interpolation distorts the
    190 Hz force; the band-limited reconstruction brings the error down ≥ 5×."""
    record, (m, d, k) = _oscillator_record()
    errors = {}
    for method in ("linear", "bandlimited"):
        model = Model.single(symbols=Symbols("y", "t", ("u",)), mass=m, state={"y": k, "y_dot": d},
                      forcing={"u": 1.0}, input_interpolation=method)
        evaluator = model.evaluator(record, substeps=substeps)
        assert evaluator.input_interpolation == method
        response, scores = evaluator.simulate(model.population(evaluator, (0.0, 0.0)))
        assert scores.status[0] == 0
        inner = slice(100, -100)
        errors[method] = np.sqrt(np.mean((response[0] - record.response)[inner] ** 2))
    assert errors["bandlimited"] < 0.2 * errors["linear"], errors


def test_model_file_records_the_interpolation_and_simulation_uses_it(tmp_path):
    record, (m, d, k) = _oscillator_record()
    model = Model.single(symbols=Symbols("y", "t", ("u",)), mass=m, state={"y": k, "y_dot": d},
                  forcing={"u": 1.0}, input_interpolation="bandlimited")
    model.save(tmp_path / "model.json")
    again = Model.load(tmp_path / "model.json")
    simulation = again.to_json()["simulation"]
    assert again == model and simulation["input_interpolation"] == "bandlimited"
    assert simulation["integrator"] == {"method": "rk4", "substeps": 1}
    written_by_hand = {key: model.to_json()[key] for key in ("variables", "canonical")}
    assert Model.from_json(written_by_hand).input_interpolation == "linear"
    band, _ = simulate_model(again, record, initial_conditions=(0.0, 0.0))
    linear, _ = simulate_model(Model.from_json(written_by_hand), record,
                               initial_conditions=(0.0, 0.0))
    assert not np.allclose(band, linear)


def test_config_carries_the_interpolation():
    assert GPConfig().input_interpolation == "linear"
    assert GPConfig(input_interpolation="bandlimited").input_interpolation == "bandlimited"
    assert GPConfig(input_interpolation="hold").input_interpolation == "hold"


def test_hold_keeps_each_sample_for_one_period():
    values = np.array([1.0, -2.0, 0.5, 3.0])
    np.testing.assert_array_equal(between_samples(values, 3, "hold"),
                                  [1, 1, 1, -2, -2, -2, 0.5, 0.5, 0.5, 3])
    np.testing.assert_array_equal(between_samples(values, 1, "hold"), values)


# m·x'' + c·x' + k·x = u + α·t, ω·dt = 0.5, u held over each sample period.
HOLD = {"m": 1.0, "c": 2.0, "k": 50.0 ** 2, "alpha": 40.0, "dt": 0.01, "y0": (0.01, 0.0)}
H = Symbols("x", "t", ("u",))


def _held_oscillator(n=200, seed=3):
    """The exact samples of the oscillator above driven by a random held input: per sample
    period the forcing is affine in t, so one matrix exponential of the state (x, x', u,
    t, 1) steps from sample to sample."""
    m, c, k, alpha, dt = (HOLD[key] for key in ("m", "c", "k", "alpha", "dt"))
    u = np.random.default_rng(seed).normal(size=n)
    generator = np.zeros((5, 5))
    generator[0, 1] = generator[3, 4] = 1.0
    generator[1, :4] = [-k / m, -c / m, 1 / m, alpha / m]
    step = expm(generator * dt)
    state = np.array([*HOLD["y0"], 0.0, 0.0, 1.0])
    response = np.empty(n)
    for i in range(n):
        response[i] = state[0]
        state[2] = u[i]
        state = step @ state
    return Measurement(time=dt * np.arange(n), response=response, inputs={"u": u},
                       time_name="t", response_name="x")


def _held_model(evaluator, scale=0.0, seed=0):
    """The oscillator as a population of one, its constants off by up to ``scale``."""
    u, t = evaluator.forcing_index(H.u[0]), evaluator.forcing_index(H.t)
    off = 1 + scale * np.random.default_rng(seed).uniform(-1, 1, 4)
    pop = evaluator.empty(1)
    pop.mass[:] = HOLD["m"] * off[0]
    pop.state[0] = [HOLD["k"] * off[1], HOLD["c"] * off[2]]
    pop.forcing[0, [u, t]] = [1.0, HOLD["alpha"] * off[3]]
    pop.y0[0] = HOLD["y0"]
    return pop


def _held_error(record, substeps, interpolation="hold", stage_input=None):
    evaluator = PopulationEvaluator(record, H, max_degree=1, substeps=substeps, batch=1,
                                    input_interpolation=interpolation, pad_to_bucket=False)
    if stage_input is not None:
        evaluator._stage_inputs = {"u": stage_input}
    response, scores = evaluator.simulate(_held_model(evaluator))
    assert scores.status[0] == 0
    return np.max(np.abs(response[0] - record.response))


def test_hold_inputs_integrate_at_fourth_order():
    """With each step's own end row (the input's left limit) the error falls 16× per halving
    of the step; one row shared by a step's end and the next one's start (the held value
    after the jump) leaves the integration first order: about 2×."""
    record = _held_oscillator()
    u = record.inputs["u"]
    split = [_held_error(record, s) for s in (1, 2, 4)]
    shared = [_held_error(record, s, "linear", between_samples(u, 2 * s, "hold"))
              for s in (1, 2, 4)]
    split_ratios = np.array(split[:-1]) / split[1:]
    shared_ratios = np.array(shared[:-1]) / shared[1:]
    assert np.all(split_ratios > 10), split_ratios
    assert np.all(shared_ratios < 3), shared_ratios


def test_hold_refuses_the_diffrax_integrator():
    with pytest.raises(ValueError, match="diffrax.*hold"):
        PopulationEvaluator(_held_oscillator(n=30), H, input_interpolation="hold",
                            integrator="diffrax")


@pytest.mark.slow  # ~17 s on 2 cores: the fast tier stays within 5 minutes
def test_refiner_recovers_a_held_oscillator():
    """Levenberg–Marquardt over the split rows (variational Jacobian, also on the shorter
    first horizon) recovers constants started 5 % off from the exact samples; the Jacobian
    equals forward-mode autodiff through the scan."""
    record = _held_oscillator(n=120)
    evaluator = PopulationEvaluator(record, H, max_degree=1, substeps=8, batch=1,
                                    input_interpolation="hold")
    refiner = Refiner(evaluator, iterations=20, batch=1)
    start = _held_model(evaluator, 0.05, seed=1)
    fixed = np.array([evaluator.forcing_index(H.u[0])])
    out = refiner.refine(start, fixed)
    assert out.succeeded.all()
    np.testing.assert_allclose(out.population.mass, HOLD["m"], rtol=1e-5)
    np.testing.assert_allclose(out.population.state[0], [HOLD["k"], HOLD["c"]], rtol=1e-5)

    samples = record.n_samples // 2
    basis = jnp.asarray(evaluator._forcing_basis[: evaluator.stage_rows(samples)])
    pop = _held_model(evaluator, 0.05, seed=2)
    constants = jnp.asarray(np.concatenate([pop.mass, pop.state[0], pop.forcing[0], pop.y0[0]]))
    directions = jnp.eye(constants.size)
    x, jacobian = evaluator.constant_jacobian(constants, directions, basis)
    reference = jax.jacfwd(lambda p: evaluator.scan_solve(*evaluator.unpack(p, basis))[:, 0])
    np.testing.assert_allclose(jacobian, reference(constants), rtol=1e-9, atol=1e-12)
    assert x.shape == (samples,)


def test_model_file_round_trips_hold(tmp_path):
    model = Model.single(H, mass=HOLD["m"], state={"x": HOLD["k"], "x_dot": HOLD["c"]},
                  forcing={"u": 1.0, "t": HOLD["alpha"]}, input_interpolation="hold")
    model.save(tmp_path / "model.json")
    again = Model.load(tmp_path / "model.json")
    assert again == model and again.to_json()["simulation"]["input_interpolation"] == "hold"
    record = _held_oscillator(n=60)
    evaluator = again.evaluator(record, substeps=4)
    assert evaluator.input_interpolation == "hold"
    response, _ = evaluator.simulate(again.population(evaluator, HOLD["y0"]))
    np.testing.assert_allclose(response[0], record.response, atol=1e-4 * np.ptp(record.response))
