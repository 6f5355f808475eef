"""The one weak form of any number of coordinates (:mod:`gpjax._weak_form`)."""

from __future__ import annotations

import numpy as np
import sympy as sp

from gpjax._data import Measurement
from gpjax._weak_form import (WeakForm, design, smoothed_derivatives, smoothed_weak_form,
                              system_band_hz)

X1, X2, X1_DOT, X2_DOT, U = sp.symbols("x1 x2 x1_dot x2_dot u")


def _two_coordinates(seed: int = 0) -> Measurement:
    """Two noisy band-limited coordinates and an input, 2,001 samples at 100 Hz."""
    rng = np.random.default_rng(seed)
    t = np.arange(2001) / 100.0
    tones = [(f, rng.uniform(0, 2 * np.pi)) for f in np.linspace(0.2, 3.0, 12)]
    x1 = sum(np.sin(2 * np.pi * f * t + p) for f, p in tones)
    x2 = sum(np.cos(2 * np.pi * f * t + 0.5 * p) for f, p in tones[::2])
    noise = 0.01 * rng.standard_normal((2, t.size))
    return Measurement(time=t, responses=np.stack([x1 + noise[0], x2 + noise[1]], axis=1),
                       response_names=("x1", "x2"), inputs={"u": np.sin(t)})


def _one(measurement: Measurement, values: np.ndarray, velocity: np.ndarray,
         half_width: int) -> WeakForm:
    """The one-coordinate weak form of a response ``values`` on ``measurement``'s grid."""
    single = Measurement(time=measurement.time, response=values, inputs=measurement.inputs)
    return WeakForm(single, velocity, half_width)


def test_a_linear_feature_of_several_coordinates_is_integrated_by_parts_on_the_data():
    m = _two_coordinates()
    weak = smoothed_weak_form(m)
    x1, x2 = m.responses.T
    relative = _one(m, x1 - x2, np.zeros_like(x1), weak.half_width)
    x = sp.Symbol("x")
    # ∫ψ·(x1' − x2') = −∫ψ'·(x1 − x2) on the measured positions, not on smoothed velocities
    np.testing.assert_allclose(weak.column(X1_DOT - X2_DOT),
                               relative.column(sp.Symbol("x_dot")), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(weak.column(X1 - X2), relative.column(x), rtol=1e-12)
    np.testing.assert_allclose(weak.acceleration(1),
                               _one(m, x2, np.zeros_like(x2), weak.half_width).acceleration())


def test_a_nonlinear_feature_is_evaluated_on_the_state_estimates_given():
    m = _two_coordinates(1)
    weak = smoothed_weak_form(m)
    # every coordinate smoothed to the system's band (its relative coordinate's included)
    smooth = [smoothed_derivatives(m.coordinate(d), system_band_hz(m)) for d in range(2)]
    on_smoothed = _one(m, smooth[0].x - smooth[1].x, smooth[0].x_dot - smooth[1].x_dot,
                       weak.half_width)
    x = sp.Symbol("x")
    np.testing.assert_allclose(weak.column((X1 - X2) ** 3), on_smoothed.column(x ** 3),
                               rtol=1e-12)
    measured = WeakForm(m, np.column_stack([s.x_dot for s in smooth]), weak.half_width)
    assert not np.allclose(measured.column((X1 - X2) ** 3), weak.column((X1 - X2) ** 3),
                           rtol=1e-6)
    assert weak.initial_state(1) == (float(smooth[1].x[0]), float(smooth[1].x_dot[0]))


def test_each_equation_has_its_own_inertia_and_held_normalisation():
    m = _two_coordinates(2)
    weak = smoothed_weak_form(m)
    matrix, target, normalised = design(weak, (X1, X1 - X2), (U,), equation=0)
    assert normalised and matrix.shape == (weak.rows, 3)
    np.testing.assert_array_equal(matrix[:, 0], weak.acceleration(0))
    np.testing.assert_array_equal(target, weak.column(U))
    matrix, target, normalised = design(weak, (X2, X2 - X1), (U,), equation=1, held={})
    assert not normalised and matrix.shape == (weak.rows, 3)
    np.testing.assert_array_equal(target, -weak.acceleration(1))
    np.testing.assert_array_equal(matrix[:, 2], -weak.column(U))
