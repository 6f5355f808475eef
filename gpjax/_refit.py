"""Constants of a known one-coordinate structure, with their uncertainty: :func:`refit`.

For an engineer who already knows the equation (from a run, a textbook or a model file)
and has a new record: the constants and initial state of ``model``'s structure refitted by
output-error Levenberg–Marquardt at converged integration, as a search refines its
reported model (:meth:`gpjax._fitness.Fitness.refine` to convergence, the step count grown
until the RK4 and reference responses agree, :func:`gpjax._convergence.fit_converged`),
then their standard errors and 95 % intervals (:mod:`gpjax._uncertainty`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ._config import GPConfig
from ._coefficients import from_population
from ._data import Measurement
from ._convergence import fit_converged
from ._model import Model, _check_inputs, fitted_initial_state
from ._refine import Refiner, free_width, refined_to_convergence, refit_horizons
from ._uncertainty import model_names, uncertainty_of
from ._weak_form import estimate_initial_conditions


def refit(model: Model, measurement: Measurement, *,
          iterations: int = GPConfig.refine_iterations, tolerance: float = 0.01,
          substeps: int | None = None) -> Model:
    """``model``'s structure with its constants and initial state refitted to
    ``measurement`` from ``model``'s values, and their :class:`~gpjax._uncertainty.Uncertainty`.

    Args:
        model: the structure and start values (the first input's coefficient, if 1, stays
            1; else the mass stays as given).
        measurement: one response and the model's inputs.
        iterations: Levenberg–Marquardt steps per round (rounds repeat while the objective
            falls by more than 0.1 %, at most 10: :func:`gpjax._refine.until_converged`).
        tolerance: the converged-integration check's tolerance (fraction of the RMS
            residual).
        substeps: a fixed RK4 step count (checked once) instead of growing it.

    The first fit doubles its horizon (:data:`gpjax._refine.REFIT_HORIZONS`); a refit at a
    finer step starts from it and fits the whole record at once.

    Raises:
        ModelFileError: the model's inputs are not the measurement's.
        UserInputError: the measurement has several responses.
    """
    from ._errors import UserInputError

    if measurement.n_coordinates != 1:
        raise UserInputError("refit takes one response; fit a system's constants with "
                             "gpjax.engine.fit_system")
    _check_inputs(model, measurement)
    start = model.initial_conditions or fitted_initial_state(
        model, measurement, estimate_initial_conditions(measurement))
    fits = {}

    def fit_at(steps: int, previous: Model | None) -> Model:
        current = previous or dataclasses.replace(model, initial_states=(tuple(start),))
        evaluator = current.evaluator(measurement, substeps=steps)
        population = current.population(evaluator, current.initial_conditions)
        u0 = model.symbols.u[0] if model.symbols.u else None
        normalised = u0 is not None and model.forcing.get(str(u0)) == 1.0
        fixed = np.array([evaluator.forcing_index(u0) if normalised else -1])
        free = evaluator.layout.width  # every column a width may need, rounded up below
        refiner = Refiner(evaluator, iterations=iterations, batch=1, max_free=free_width(free),
                          horizons=refit_horizons(previous is not None))
        population, best = refined_to_convergence(
            refiner, population, fixed, lambda p: evaluator.score(p).objective)
        best = float(best[0])
        coefficients = from_population(population, evaluator, [current.coefficients])[0]
        fitted = Model.from_coefficients(
            model.symbols, coefficients, input_interpolation=model.input_interpolation,
            substeps=steps, metrics={"objective": best}, provenance=model.provenance)
        fits[steps] = (refiner, population, fixed, coefficients)
        return fitted

    fitted, checks, _ = fit_converged(fit_at, measurement, substeps=substeps, tolerance=tolerance)
    refiner, population, fixed, coefficients = fits[fitted.substeps]
    return dataclasses.replace(
        fitted, convergence=checks[-1].to_json(),
        uncertainty=uncertainty_of(refiner, population, fixed, names=lambda s: model_names(
            s, fitted, refiner.evaluator, [coefficients])))
