"""The linear gear-pair model, eq. 23, fitted by gradient-based least squares (paper §7, point 3).

``J·φ'' + K·φ = T(t)`` (eq. 23 with K = r1·k_m constant) is the model the paper fitted with
gradient methods before turning to genetic programming (Fig. 12). This module fits it the
same way gpjax refines GP candidates, so the two are compared on equal terms:

1. **Start**: weak-form equation-error least squares (:func:`gpjax._weak_form.least_squares`,
   the canonical form integrated against compact test functions; no second derivative of
   the noisy response) gives J and K with T's coefficient fixed to 1; the initial state
   (φ, φ') at the first sample comes from a Savitzky–Golay fit (eq. 13's estimate).
2. **Refinement**: optimistix Levenberg–Marquardt on the *simulated* response
   (:class:`gpjax._refine.Refiner`, forward-mode through gpjax's batched RK4 solve),
   over J, K and the initial state, minimising Σ(φ_meas − φ_calc)² (the square of eq. 8).
   The refined constants are kept only if they lower the objective of eq. 7.

The result is scored with gpjax's own evaluator (eqs. 7–9), so its RMS and objective are
directly comparable with a GP model's ``metrics``.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .._canonical import Symbols
from .._coefficients import from_population
from .._data import Measurement
from .._errors import ConfigError, DataError
from .._evaluator import OK
from .._model import Model
from .._refine import Refiner
from .._weak_form import WeakForm, least_squares, smoothed_derivatives

#: How the fit starts, in words (also stored in the model's provenance).
START = "weak-form equation-error least squares, Savitzky-Golay initial state"


@dataclasses.dataclass(frozen=True)
class LinearFit:
    """A fitted eq. 23 and how well it reproduces the measurement.

    Attributes:
        model: the fitted ``J·φ'' + K·φ = T`` as a :class:`gpjax.Model` (initial
            conditions and metrics included).
        start: the equation-error start, same form (before Levenberg–Marquardt).
        J: inertia coefficient (the torque's units × s² per response unit; kg·m² for a
            response in rad and T in N·m; N·m·s²/deg for the paper's φ in degrees).
        K: stiffness coefficient (torque per response unit; N·m/deg for the paper's data).
        rms: root-mean-square of φ_meas − φ_calc, in the response's units.
        objective: f of eq. 7 (f_time + f_freq with the evaluator's default weights and m).
        refined: whether Levenberg–Marquardt improved on the start (else the start is kept).
        steps: Levenberg–Marquardt steps taken.
    """

    model: Model
    start: Model
    J: float
    K: float
    rms: float
    objective: float
    refined: bool
    steps: int


def fit_linear_model(measurement: Measurement, *, iterations: int = 60) -> LinearFit:
    """Fit eq. 23, ``J·φ'' + K·φ = T``, and its initial state to ``measurement``.

    Args:
        measurement: response φ(t) and exactly one input T(t), uniformly sampled.
        iterations: maximum Levenberg–Marquardt steps.

    Raises:
        DataError: the measurement does not have exactly one input.
        ConfigError: ``iterations`` is not a positive integer.
    """
    if len(measurement.input_names) != 1:
        raise DataError(f"eq. 23 has one input (the torque), the data has "
                        f"{len(measurement.input_names)}; pass exactly one input column")
    if isinstance(iterations, bool) or not isinstance(iterations, int) or iterations < 1:
        raise ConfigError(f"iterations must be a positive integer, got {iterations!r}")
    symbols = Symbols(measurement.response_name, measurement.time_name,
                      tuple(measurement.input_names))
    x, u = symbols.x, symbols.u[0]
    derivatives = smoothed_derivatives(measurement)
    weak = WeakForm(measurement, derivatives.x_dot, derivatives.window)
    mass, (stiffness,), _, _ = least_squares(weak, (x,), (u,))
    y0 = derivatives.initial_state
    start = _model(symbols, float(mass), float(stiffness), y0, refined=False)

    evaluator = start.evaluator(measurement)
    population = start.population(evaluator, y0)
    start_scores = evaluator.score(population)
    refiner = Refiner(evaluator, iterations=iterations, batch=1)
    result = refiner.refine(population, np.array([evaluator.forcing_index(u)]))
    scores = evaluator.score(result.population)
    refined = bool(scores.status[0] == OK and (start_scores.status[0] != OK or
                                              scores.objective[0] < start_scores.objective[0]))
    if refined:
        found = from_population(result.population, evaluator, [start.coefficients])[0]
        model = _model(symbols, found.mass, found.state[x], found.y0, refined=True)
    else:
        scores, model = start_scores, start
    metrics = {"rms": float(scores.rms[0]), "f_time": float(scores.f_time[0]),
               "f_freq": float(scores.f_freq[0]), "objective": float(scores.objective[0]),
               "n_bins": evaluator.n_bins}
    model = dataclasses.replace(model, metrics=metrics)
    return LinearFit(model=model, start=start, J=model.mass, K=model.state[str(x)],
                     rms=metrics["rms"], objective=metrics["objective"], refined=refined,
                     steps=int(result.steps[0]))


def _model(symbols: Symbols, mass: float, stiffness: float, y0: tuple[float, float], *,
           refined: bool) -> Model:
    return Model.single(symbols, mass=mass, state={str(symbols.x): stiffness},
                 forcing={str(symbols.u[0]): 1.0}, initial_conditions=y0,
                 provenance={"model": "eq. 23 (linear)", "start": START,
                             "refined": "optimistix Levenberg-Marquardt" if refined else "no"})
