"""Inputs between samples: linear or band-limited reconstruction at the RK4 stage times,
in the evaluator, the configuration and the model file."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from gpjax import GPConfig, Model, Symbols
from gpjax._data import Measurement, between_samples
from gpjax._model import simulate_model

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
        model = Model(symbols=Symbols("y", "t", ("u",)), mass=m, state={"y": k, "y_dot": d},
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
    model = Model(symbols=Symbols("y", "t", ("u",)), mass=m, state={"y": k, "y_dot": d},
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
