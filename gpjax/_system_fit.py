"""Systems of several coordinates: a model, its constants for a given structure, and the
converged-integration check.

A :class:`SystemModel` is one Newton–Euler equation per measured coordinate (eqs. 21–22):
``m_i·x_i'' + Σ c·φ(x_i, x_i', x_i − x_j, x_i' − x_j') = Σ g·ψ(t, u)``. Given the features
of every equation (a :data:`Structure`), :func:`fit_system` sets the constants as the
one-coordinate search does for one structure: weak-form equation-error least squares per
equation (:mod:`gpjax._weak_form`'s test functions; no second derivative of the data),
then output-error Levenberg–Marquardt on the simulated responses of all coordinates
together — every constant and every initial state (:class:`gpjax._refine.Refiner` on a
system evaluator) — at converged integration: the refitted system is simulated by RK4 and
by the reference solve (:func:`gpjax._reference.reference_system_response`), and the step
count grows until they agree (:mod:`gpjax._convergence`).

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
from ._canonical import Symbols
from ._coefficients import (Coefficients, Population, from_system_population,
                            to_system_population)
from ._convergence import fit_converged
from ._data import Measurement
from ._diagnose_fits import blocked_cv_residual
from ._evaluator import PopulationEvaluator, Scores
from ._reference import ReferenceSolver, reference_system_response
from ._refine import Refiner
from ._uncertainty import Uncertainty, system_names, uncertainty_of
from ._system_couplings import couple, coupled_least_squares, fixed_columns, tie_columns
from ._weak_form import WeakForm, smoothed_derivatives

#: Per equation: (state features, forcing features with their fixed coefficient or None).
Structure = tuple[tuple[tuple[sp.Expr, ...], dict[sp.Expr, float | None]], ...]


@dataclasses.dataclass(frozen=True)
class SystemModel:
    """A system of D equations with its constants and initial states.

    Attributes:
        coordinates: the response names, one per equation.
        time_name, input_names: the time and input column names.
        equations: one :class:`Coefficients` per coordinate (y0: that coordinate's state).
        input_interpolation: the inputs between samples.
        substeps: RK4 steps per sample interval the constants were fitted with.
        max_degree: the evaluator basis' highest power.
        third_law: each coupling force acts on both of its coordinates with opposite
            signs, its constants tied (:mod:`gpjax._system_couplings`).
    """

    coordinates: tuple[str, ...]
    time_name: str
    input_names: tuple[str, ...]
    equations: tuple[Coefficients, ...]
    input_interpolation: str = "linear"
    substeps: int = 1
    max_degree: int = 3
    third_law: bool = False

    @property
    def initial_conditions(self) -> tuple[tuple[float, float], ...]:
        return tuple(e.y0 for e in self.equations)

    def sympy(self) -> list[sp.Eq]:
        """The equations, ``m·x'' + Σ c·φ = Σ g·ψ`` with numbers."""
        out = []
        for name, e in zip(self.coordinates, self.equations):
            lhs = sp.Float(e.mass) * sp.Symbol(f"{name}_ddot") + sum(
                (sp.Float(v) * f for f, v in e.state.items()), sp.Integer(0))
            rhs = sum((sp.Float(v) * f for f, v in e.forcing.items()), sp.Integer(0))
            out.append(sp.Eq(lhs, rhs))
        return out

    def couplings(self) -> dict[tuple[int, int], sp.Expr]:
        """With ``third_law``, the coupling force F_ij of every coupled pair i < j (0-based
        equation numbers) with numbers: +F_ij in equation i, −F_ij in equation j."""
        if not self.third_law:
            return {}
        out: dict[tuple[int, int], sp.Expr] = {}
        for tie in self.ties():
            (i, feature), (j, _) = tie.source, tie.mirror
            key = (min(i, j), max(i, j))
            term = sp.Float(self.equations[i].state[feature]) * feature * (1 if i < j else -1)
            out[key] = out.get(key, sp.Integer(0)) + term
        return out

    def ties(self) -> tuple:
        """The :class:`gpjax._system_couplings.Tie` of every coupling term (none without
        ``third_law``)."""
        if not self.third_law:
            return ()
        structure = tuple((tuple(e.state), e.forcing) for e in self.equations)
        return couple(structure, self.coordinates)[1]

    def latex(self) -> list[str]:
        """The equations in LaTeX, derivatives as dots."""
        names = {}
        for name in self.coordinates:
            base = sp.latex(sp.Symbol(name))
            names |= {sp.Symbol(f"{name}_dot"): rf"\dot{{{base}}}",
                      sp.Symbol(f"{name}_ddot"): rf"\ddot{{{base}}}"}
        return [sp.latex(e, symbol_names=names) for e in self.sympy()]

    def evaluator(self, measurement: Measurement, **options) -> PopulationEvaluator:
        return PopulationEvaluator(measurement, Symbols(self.coordinates[0], self.time_name,
                                                        self.input_names),
                                   max_degree=self.max_degree, substeps=self.substeps,
                                   input_interpolation=self.input_interpolation, **options)

    def population(self, evaluator: PopulationEvaluator, y0) -> Population:
        """This system as a population of one on ``evaluator``, starting from ``y0`` (D, 2)."""
        return to_system_population([[e.replace(y0=tuple(map(float, s)))
                                      for e, s in zip(self.equations, y0)]], evaluator)

    def simulate(self, measurement: Measurement, *, initial_conditions=None,
                 solver: str = "reference") -> np.ndarray:
        """Responses (N, D) on ``measurement``'s time grid and inputs, by the reference
        solve or (``solver="rk4"``) the fitted RK4 step count, from ``initial_conditions``
        ((D, 2); default the fitted ones)."""
        y0 = self.initial_conditions if initial_conditions is None else initial_conditions
        if solver == "rk4":
            evaluator = self.evaluator(measurement)
            responses, _ = evaluator.simulate(self.population(evaluator, y0))
            return responses[0].T
        spread = measurement.responses.std(axis=0)
        rate = np.diff(measurement.responses, axis=0).std(axis=0) / measurement.dt
        return reference_system_response(
            self.equations, self.coordinates, self.time_name, self.input_names,
            measurement.time, measurement.inputs, y0, interpolation=self.input_interpolation,
            scale=np.stack([spread, rate], axis=1), solver=ReferenceSolver())[0]


def weak_form_start(measurement: Measurement, structure: Structure,
                    ties=()) -> list[Coefficients]:
    """Per equation, constants by weak-form equation-error least squares
    (:class:`SystemWeakForm`); with ``ties`` (Newton's third law) all equations at once."""
    weak = SystemWeakForm(measurement)
    if ties:
        return coupled_least_squares(weak, structure, ties)
    return [weak.equation(d, state, forcing) for d, (state, forcing) in enumerate(structure)]


class SystemWeakForm:
    """Weak-form equation-error least squares for the equations of a system: features are
    evaluated on Savitzky–Golay-smoothed states of all coordinates and integrated against
    :class:`gpjax._weak_form.WeakForm`'s test functions (one width for all coordinates);
    the inertia column is exact (∫ψ''·x_i). Columns are cached per equation and feature."""

    def __init__(self, measurement: Measurement):
        names = measurement.response_names
        self.measurement = measurement
        single = [measurement_of(measurement, d) for d in range(len(names))]
        smooth = [smoothed_derivatives(m) for m in single]
        self._states = [s.initial_state for s in smooth]
        values = {sp.Symbol(n): s.x for n, s in zip(names, smooth)}
        values |= {sp.Symbol(f"{n}_dot"): s.x_dot for n, s in zip(names, smooth)}
        values |= {sp.Symbol(measurement.time_name): measurement.time}
        self._values = values | {sp.Symbol(k): v for k, v in measurement.inputs.items()}
        width = max(s.window for s in smooth)
        self._weak = [WeakForm(single[d], Symbols(names[d], measurement.time_name,
                                                  measurement.input_names), smooth[d].x_dot,
                               width) for d in range(len(names))]
        self._columns: dict[tuple[int, sp.Expr], np.ndarray] = {}
        self._velocities = {sp.Symbol(f"{n}_dot"): d for d, n in enumerate(names)}

    def exact_column(self, equation: int, feature: sp.Expr) -> np.ndarray:
        """:meth:`column`, but a feature linear in the velocities (x_i', x_i' − x_j')
        integrated by parts against the measured positions (∫ψ·x' = −∫ψ'·x), as one
        coordinate's weak form does: no velocity estimate blurs a damping term's column."""
        symbols = feature.free_symbols
        if not symbols or not symbols <= set(self._velocities):
            return self.column(equation, feature)
        linear = sp.Poly(feature, *self._velocities)
        if linear.total_degree() != 1 or linear.coeff_monomial(1):
            return self.column(equation, feature)
        position = sum(float(linear.coeff_monomial(v)) * self.measurement.responses[:, d]
                       for v, d in self._velocities.items())
        return -self._weak[equation]._integrate(position, 1)

    def column(self, equation: int, feature: sp.Expr) -> np.ndarray:
        """∫ψ_k·feature for every window of ``equation``'s coordinate (cached)."""
        key = (equation, feature)
        if key not in self._columns:
            numbers = sp.lambdify(list(self._values), feature, modules="numpy")(
                *self._values.values())
            self._columns[key] = self._weak[equation]._integrate(
                np.broadcast_to(numbers, self.measurement.time.shape), 0)
        return self._columns[key]

    def rows(self, d: int) -> int:
        """Test-function windows of equation ``d``."""
        return self._weak[d].centres.size

    def acceleration(self, d: int) -> np.ndarray:
        """∫ψ''·x_d per window (the inertia column)."""
        return self._weak[d].acceleration()

    def initial_state(self, d: int) -> tuple[float, float]:
        """(x_d, x_d') at the first sample, from the smoothed record."""
        return self._states[d]

    def _mass_normalised(self, d: int, state, forcing, *, exact: bool = False
                         ) -> tuple[np.ndarray, np.ndarray]:
        """(columns, target) of equation ``d`` with mass 1: ``state`` and ``forcing``
        features against −∫ψ''·x_d (``exact``: state columns by :meth:`exact_column`)."""
        target = -self._weak[d].acceleration()
        column = self.exact_column if exact else self.column
        columns = [column(d, f) for f in state] + [-self.column(d, f) for f in forcing]
        return (np.stack(columns, axis=1) if columns else np.zeros((target.size, 0))), target

    def residual(self, d: int, state, forcing) -> float:
        """Relative weak-form equation error of equation ``d`` with ``state`` and
        ``forcing`` features (mass 1): how much of ∫ψ''·x_d the features leave unexplained."""
        matrix, target = self._mass_normalised(d, state, forcing)
        if not matrix.shape[1]:
            return 1.0
        norm = np.linalg.norm(matrix, axis=0)
        norm[norm == 0] = 1.0
        solution = np.linalg.lstsq(matrix / norm, target, rcond=None)[0]
        return float(np.linalg.norm(target - matrix / norm @ solution) / np.linalg.norm(target))

    def held_out(self, structure) -> np.ndarray:
        """Held-out weak-form residual of a system, one number per window: per equation the
        blocked cross-validation residual of its mass-normalised least squares
        (:func:`gpjax._diagnose_fits.blocked_cv_residual`; damping columns by parts,
        :meth:`exact_column`) relative to the RMS of its inertia column, combined over the equations as a root sum of squares, so the
        square that :func:`gpjax._diagnose_acceptance.predictive_test` compares is the
        sum of the equations' squares. Mass-normalised, so the equations' own
        normalisation (an input or the mass) does not change it; couplings are not tied
        (each equation is predicted by its own least squares)."""
        total = np.zeros(self.rows(0))
        for d, (state, forcing) in enumerate(structure):
            matrix, target = self._mass_normalised(d, state, forcing, exact=True)
            residual = blocked_cv_residual(matrix, target, self._weak[d])
            total += (residual * self._weak[d].kernel_area / np.sqrt(np.mean(target ** 2))) ** 2
        return np.sqrt(total)

    def equation(self, d: int, state, forcing: dict) -> Coefficients:
        """Constants of equation ``d`` with ``state`` and ``forcing`` features; a forcing
        feature given a number keeps it (the normalisation; the signs flip if the mass
        comes out negative), with none the mass is 1. y0: the smoothed first sample."""
        weak = self._weak[d]
        fixed = {f: v for f, v in forcing.items() if v is not None}
        free = [f for f in forcing if f not in fixed]
        target = sum((v * self.column(d, f) for f, v in fixed.items()),
                     np.zeros(weak.centres.size))
        columns = [self.column(d, f) for f in state] + [-self.column(d, f) for f in free]
        acceleration = weak.acceleration()
        if fixed:
            columns = [acceleration] + columns
        else:
            target = -acceleration
        matrix = np.stack(columns, axis=1) if columns else np.zeros((target.size, 0))
        norm = np.linalg.norm(matrix, axis=0)
        norm[norm == 0] = 1.0
        solution = np.linalg.lstsq(matrix / norm, target, rcond=None)[0] / norm
        sign = -1.0 if fixed and solution[0] < 0 else 1.0
        k = 1 if fixed else 0
        return Coefficients(
            mass=sign * float(solution[0]) if fixed else 1.0,
            state={f: sign * float(v) for f, v in zip(state, solution[k:k + len(state)])},
            forcing={**{f: sign * v for f, v in fixed.items()},
                     **{f: sign * float(v) for f, v in zip(free, solution[k + len(state):])}},
            y0=self._states[d])


def measurement_of(measurement: Measurement, coordinate: int) -> Measurement:
    """Coordinate ``coordinate`` of a system measurement, with its inputs."""
    return Measurement(time=measurement.time, response=measurement.responses[:, coordinate],
                       inputs=measurement.inputs, time_name=measurement.time_name,
                       response_name=measurement.response_names[coordinate])


@dataclasses.dataclass(frozen=True)
class SystemFit:
    """:func:`fit_system`'s result: the model, its scores at the fitted step count, every
    convergence check made (the last one passed unless ``substeps`` hit the cap), and the
    constants' standard errors and 95 % intervals (:mod:`gpjax._uncertainty`; names
    ``"x2: x2_dot"``, ``"x2: m"``, ``"x2(0)"``)."""

    model: SystemModel
    scores: Scores
    checks: tuple
    uncertainty: Uncertainty | None = None


def fit_system(measurement: Measurement, structure: Structure, *, max_degree: int = 3,
               input_interpolation: str = "linear", iterations: int = 30,
               start: list[Coefficients] | None = None, tolerance: float = 0.01,
               substeps: int | None = None, third_law: bool = False) -> SystemFit:
    """Constants and initial states of a system ``structure`` on ``measurement``
    (module docstring): weak-form start (or ``start``), Levenberg–Marquardt on all
    coordinates at once, repeated at a finer step until the RK4 and reference responses
    differ by less than ``tolerance`` of the RMS residual (``substeps`` given: that step
    count, checked once). ``third_law``: every coupling feature (a power of x_i − x_j or
    x_i' − x_j') is one force acting on both coordinates, its mirror added to equation j
    and its constants tied (:mod:`gpjax._system_couplings`; then only one forcing value or
    mass per coupled group is held).

    Raises:
        ValueError: a feature outside an equation's basis (raise ``max_degree``).
    """
    ties = ()
    if third_law:
        structure, ties = couple(structure, measurement.response_names)
    start = start or weak_form_start(measurement, structure, ties)
    last = {}

    def fit_at(steps: int, previous: SystemModel | None) -> SystemModel:
        _progress.stage(f"fitting the system's constants at {steps} substeps, then its "
                        "convergence check")
        model, last["scores"], last["refit"] = _refit(
            measurement, structure, list(previous.equations) if previous else start, steps,
            max_degree, input_interpolation, iterations, ties)
        return model

    model, checks = fit_converged(fit_at, measurement, substeps=substeps, tolerance=tolerance)
    refiner, population, fixed, tied = last["refit"]
    uncertainty = uncertainty_of(refiner, population, fixed, ties=tied, names=lambda s: system_names(
        s, model.equations, model.coordinates, refiner.evaluator))
    return SystemFit(model, last["scores"], tuple(checks), uncertainty)


def _refit(measurement, structure, start, steps, max_degree, interpolation, iterations, ties):
    model = SystemModel(measurement.response_names, measurement.time_name,
                        measurement.input_names, tuple(start), interpolation, steps, max_degree,
                        third_law=bool(ties))
    evaluator = model.evaluator(measurement)
    population = to_system_population([start], evaluator)
    fixed = np.array([fixed_columns(structure, ties, evaluator.forcing_index)])
    if not np.all(np.isfinite(evaluator.layout.pack(population))):
        raise ValueError("the least-squares start of the system is not finite")
    free = sum(1 + len(s) + len(f) + 2 for s, f in structure)
    refiner = Refiner(evaluator, iterations=iterations, max_free=free + free % 2, batch=1)
    tied = [tie_columns(ties, evaluator)]
    refined = refiner.refine(population, fixed, ties=tied).population
    equations = from_system_population(refined, evaluator, [start])[0]
    model = dataclasses.replace(model, equations=tuple(equations))
    scores = evaluator.score(to_system_population([equations], evaluator))
    if not math.isfinite(float(scores.objective[0])):
        raise ValueError("the refined system diverged")
    return model, scores, (refiner, refined, fixed, tied)
