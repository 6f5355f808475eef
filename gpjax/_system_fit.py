"""Systems of several coordinates: the constants of a given structure, at converged
integration.

A system is a :class:`gpjax.Model` of one Newton–Euler equation per measured coordinate (eqs. 21–22):
``m_i·x_i'' + Σ c·φ(x_i, x_i', x_i − x_j, x_i' − x_j') = Σ g·ψ(t, u)``. Given the features
of every equation (a :data:`Structure`), :func:`fit_system` sets the constants as the
one-coordinate search does for one structure: weak-form equation-error least squares per
equation (:mod:`gpjax._weak_form`'s test functions; no second derivative of the data),
then output-error Levenberg–Marquardt on the simulated responses of all coordinates
together — every constant and every initial state (:class:`gpjax._refine.Refiner` on a
system evaluator, in rounds of ``GPConfig.refine_iterations`` steps until a round lowers
the objective by less than 0.1 %: one coordinate's convergence loop,
:func:`gpjax._refine.until_converged`) — at converged integration: the refitted system is
simulated by RK4 and by the reference solve (:func:`gpjax._reference.reference_response`),
and the step count grows until they agree (:mod:`gpjax._convergence`).

Each equation is normalised on its own (each can be multiplied by any factor): the first
input in it has coefficient 1 as given in the structure's start (±1), else its mass is
held at the value given (:func:`fit_system`'s ``masses``).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import sympy as sp

from . import _progress
from ._config import GPConfig
from ._coefficients import Coefficients, from_system_population, to_system_population
from ._convergence import fit_converged
from ._data import Measurement
from ._diagnose_fits import blocked_cv_residual
from ._evaluator import Scores
from ._model import Model
from ._refine import Refiner, free_width, refined_to_convergence, refit_horizons
from ._uncertainty import Uncertainty, model_names, uncertainty_of
from ._system_couplings import couple, coupled_least_squares, fixed_columns, tie_columns
from ._weak_form import (WeakForm, design, least_squares_residual, scaled_lstsq,
                         smoothed_weak_form)

#: Per equation: (state features, forcing features with their fixed coefficient or None).
Structure = tuple[tuple[tuple[sp.Expr, ...], dict[sp.Expr, float | None]], ...]


def weak_form_start(measurement: Measurement, structure: Structure,
                    ties=()) -> list[Coefficients]:
    """Per equation, constants by weak-form equation-error least squares on the smoothed
    states (:func:`gpjax._weak_form.smoothed_weak_form`, :func:`equation_constants`); with
    ``ties`` (Newton's third law) all equations at once."""
    weak = smoothed_weak_form(measurement)
    if ties:
        return coupled_least_squares(weak, structure, ties)
    return [equation_constants(weak, d, state, forcing)
            for d, (state, forcing) in enumerate(structure)]


def equation_constants(weak: WeakForm, d: int, state, forcing: dict) -> Coefficients:
    """Constants of equation ``d`` with ``state`` features and ``forcing`` features
    (feature -> held value or ``None``) by :func:`gpjax._weak_form.design`'s least
    squares: a held value is kept (the normalisation; the signs flip if the mass comes
    out negative), with none held the mass is 1. y0: the weak form's first state."""
    held = {f: v for f, v in forcing.items() if v is not None}
    free = [f for f in forcing if f not in held]
    matrix, target, _ = design(weak, tuple(state), tuple(forcing), equation=d, held=held)
    solution = scaled_lstsq(matrix, target)
    sign = -1.0 if held and solution[0] < 0 else 1.0
    k = 1 if held else 0
    return Coefficients(
        mass=sign * float(solution[0]) if held else 1.0,
        state={f: sign * float(v) for f, v in zip(state, solution[k:k + len(state)])},
        forcing={**{f: sign * v for f, v in held.items()},
                 **{f: sign * float(v) for f, v in zip(free, solution[k + len(state):])}},
        y0=weak.initial_state(d))


def equation_residual(weak: WeakForm, d: int, state, forcing) -> float:
    """Relative weak-form equation error of equation ``d`` with ``state`` and ``forcing``
    features, mass 1: how much of its inertia column ∫ψ''·x_d the features leave
    unexplained."""
    return least_squares_residual(weak, tuple(state), tuple(forcing), equation=d,
                                  held={}) / float(np.linalg.norm(weak.acceleration(d)))


def held_out(weak: WeakForm, structure) -> np.ndarray:
    """Held-out weak-form residual of a system, one number per window: per equation the
    blocked cross-validation residual of its mass-normalised least squares
    (:func:`gpjax._diagnose_fits.blocked_cv_residual`) relative to the RMS of its inertia
    column, combined over the equations as a root sum of squares, so the square that
    :func:`gpjax._diagnose_acceptance.predictive_test` compares is the sum of the
    equations' squares. Mass-normalised, so the equations' own normalisation (an input or
    the mass) does not change it; couplings are not tied (each equation is predicted by
    its own least squares)."""
    total = np.zeros(weak.rows)
    for d, (state, forcing) in enumerate(structure):
        matrix, target, _ = design(weak, tuple(state), tuple(forcing), equation=d, held={})
        residual = blocked_cv_residual(matrix, target, weak)
        total += (residual * weak.kernel_area / np.sqrt(np.mean(target ** 2))) ** 2
    return np.sqrt(total)


@dataclasses.dataclass(frozen=True)
class SystemFit:
    """:func:`fit_system`'s result: the model, its scores at the fitted step count, every
    convergence check made (the last one passed unless ``substeps`` hit the cap), and the
    constants' standard errors and 95 % intervals (:mod:`gpjax._uncertainty`; names as the
    model's constants, ``"x2.c1"``, ``"x2.m"``, and ``"x2(0)"``); ``reference``: the
    last check's reference response (N', D) on its samples."""

    model: Model
    scores: Scores
    checks: tuple
    uncertainty: Uncertainty | None = None
    reference: np.ndarray | None = None


def fit_system(measurement: Measurement, structure: Structure, *, max_degree: int = 3,
               input_interpolation: str = "linear",
               iterations: int = GPConfig.refine_iterations,
               start: list[Coefficients] | None = None, tolerance: float = 0.01,
               substeps: int | None = None, third_law: bool = False,
               first_substeps: int | None = None, kinds: tuple[str, ...] = (),
               carried: bool = False) -> SystemFit:
    """Constants and initial states of a system ``structure`` on ``measurement``
    (module docstring): weak-form start (or ``start``), Levenberg–Marquardt on all
    coordinates at once (rounds of ``iterations`` steps until converged), repeated at a
    finer step until the RK4 and reference responses differ by less than ``tolerance`` of
    the RMS residual (``substeps`` given: that step count, checked once;
    ``first_substeps``: the step count the ladder starts from, e.g. a similar system's
    converged one; ``kinds``: the bank kinds its evaluators hold beside the structure's
    own, a search's, so its refits share one set of programs). The first
    fit doubles its horizon (:data:`gpjax._refine.REFIT_HORIZONS`); a refit from the last
    fit, and the first with ``carried`` (``start`` holds a fitted system's constants, its
    signs narrowed), fit the whole record at once: their start is near.
    ``third_law``: every coupling feature (a power of x_i − x_j or x_i' − x_j') is one
    force acting on both coordinates, its mirror added to equation j and its constants
    tied (:mod:`gpjax._system_couplings`; then only one forcing value or mass per coupled
    group is held).

    Raises:
        ValueError: a feature outside an equation's basis (raise ``max_degree``).
    """
    ties = ()
    if third_law:
        structure, ties = couple(structure, measurement.response_names)
    start = start or weak_form_start(measurement, structure, ties)
    last = {}

    def fit_at(steps: int, previous: Model | None) -> Model:
        _progress.stage(f"fitting the system's constants at {steps} substeps, then its "
                        "convergence check")
        model, last["scores"], last["refit"] = _refit(
            measurement, structure, list(previous.system) if previous else start, steps,
            max_degree, input_interpolation, iterations, ties, kinds,
            refit_horizons(previous is not None or carried))
        return model

    model, checks, reference = fit_converged(fit_at, measurement, substeps=substeps,
                                             tolerance=tolerance, first=first_substeps)
    refiner, population, fixed, tied = last["refit"]
    uncertainty = uncertainty_of(refiner, population, fixed, ties=tied, names=lambda s: model_names(
        s, model, refiner.evaluator))
    return SystemFit(model, last["scores"], tuple(checks), uncertainty, reference)


def _refit(measurement, structure, start, steps, max_degree, interpolation, iterations, ties,
           kinds, horizons):
    def model_of(equations) -> Model:
        return Model.from_equations(measurement.response_names, measurement.time_name,
                                    measurement.input_names, equations,
                                    input_interpolation=interpolation, substeps=steps,
                                    third_law=bool(ties))

    evaluator = model_of(start).evaluator(measurement, max_degree=max_degree, kinds=kinds)
    population = to_system_population([start], evaluator)
    fixed = np.array([fixed_columns(structure, ties, evaluator.forcing_index)])
    if not np.all(np.isfinite(evaluator.layout.pack(population))):
        raise ValueError("the least-squares start of the system is not finite")
    free = sum(1 + len(s) + len(f) + 2 for s, f in structure)
    refiner = Refiner(evaluator, iterations=iterations, max_free=free_width(free), batch=1,
                      horizons=horizons)
    tied = [tie_columns(ties, evaluator)]
    refined, _ = refined_to_convergence(refiner, population, fixed,
                                        lambda p: evaluator.score(p).objective, ties=tied)
    equations = from_system_population(refined, evaluator, [start])[0]
    scores = evaluator.score(to_system_population([equations], evaluator))
    if not math.isfinite(float(scores.objective[0])):
        raise ValueError("the refined system diverged")
    return model_of(equations), scores, (refiner, refined, fixed, tied)
