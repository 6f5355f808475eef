"""The linear model eq. 23 fitted by optimistix least squares (gpjax.gear._linear)."""

import numpy as np
import pytest

from gpjax import ConfigError, DataError, Measurement
from gpjax.gear import generate_gear_example
from gpjax.gear._linear import fit_linear_model

J, K = 7.918e-5, 1500.0


def test_recovers_J_and_K_of_linear_data_within_1_percent():
    example = generate_gear_example(truth={"J": J, "K1": K, "K2": 0.0}, revolutions=0.2, seed=4)
    fit = fit_linear_model(example.measurement)
    assert fit.J == pytest.approx(J, rel=0.01)
    assert fit.K == pytest.approx(K, rel=0.01)
    noise = np.sqrt(np.mean((example.measurement.response - example.clean_response) ** 2))
    assert fit.rms < 1.5 * noise
    assert fit.model.metrics["rms"] == fit.rms and fit.model.initial_conditions is not None


def test_is_clearly_worse_than_eq_14_on_the_nonlinear_gear_example():
    example = generate_gear_example(revolutions=0.2, seed=1)
    fit = fit_linear_model(example.measurement)
    eq14_rms = np.sqrt(np.mean((example.measurement.response - example.clean_response) ** 2))
    assert fit.rms > 10 * eq14_rms
    assert fit.objective >= fit.rms  # f = w1·sqrt(Σe²) + f_freq ≥ the RMS for N ≥ 1


def test_refuses_data_with_two_inputs():
    t = np.arange(50) / 1000.0
    data = Measurement(time=t, response=np.sin(t), inputs={"T": t, "F": t})
    with pytest.raises(DataError, match="one input"):
        fit_linear_model(data)
    with pytest.raises(ConfigError, match="iterations"):
        fit_linear_model(Measurement(time=t, response=np.sin(t), inputs={"T": t}), iterations=0)
