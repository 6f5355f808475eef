"""Diagnosis, step 3: refit a structure's constants and measure its errors.

A :class:`Structure` (features only) becomes a :class:`Fit` (one
:class:`~gpjax._coefficients.Coefficients` and its errors) by weak-form least squares alone
(equation-error mode) or by that start, optimistix Levenberg–Marquardt on the simulated
response of the estimation part (:class:`gpjax._refine.Refiner`) and a simulation of the whole
record (simulation mode). :class:`FitProblem` holds the data, the estimation/held-out split
and the compiled evaluators shared by every fit of one diagnosis.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import sympy as sp

from ._canonical import Symbols
from ._coefficients import Coefficients, Population, from_population, to_population
from ._data import Measurement
from ._effects import Context, Terms
from ._evaluator import OK, PopulationEvaluator, split_state_features
from ._memory import check_fit_memory
from ._model import Model
from ._objective import amplitude_spectrum, default_n_bins
from ._refine import Refiner, refined_to_convergence
from ._diagnose_noise import signal_band_hz
from ._weak_form import (WeakForm, design, evaluate, least_squares, savgol_window, scaled_lstsq,
                         smoothed_derivatives, smoothing_cutoff_hz)

#: Continuation of the refit when a start and its refinement both diverge (fractions of the
#: estimation part fitted in turn).
CAREFUL_HORIZONS = (0.1, 0.25, 0.5, 1.0)
#: Contiguous folds of the equation-error mode's blocked cross-validation.
FOLDS = 5
#: :meth:`_Simulator.jacobian`'s directions come in multiples of this many.
DIRECTIONS_STEP = 8


@dataclasses.dataclass(frozen=True)
class Structure:
    """Features of a model: state (x or x' alone), parametric g(t)·h(x), forcing."""

    state: tuple[sp.Expr, ...]
    parametric: tuple[sp.Expr, ...]
    forcing: tuple[sp.Expr, ...]

    @property
    def lhs(self) -> tuple[sp.Expr, ...]:
        """State then parametric features (the left-hand side's coefficients, in order)."""
        return self.state + self.parametric

    def plus(self, terms: Terms) -> "Structure":
        """This structure with ``terms`` added (features already present are kept once)."""
        def merged(old, new):
            return old + tuple(f for f in new if f not in old)
        return Structure(merged(self.state, terms.state),
                         merged(self.parametric, terms.parametric),
                         merged(self.forcing, terms.forcing))

    def coefficients(self, lhs: dict[sp.Expr, float], forcing: dict[sp.Expr, float], *,
                     mass: float, y0: tuple[float, float]) -> Coefficients:
        """This structure's constants taken from ``lhs`` and ``forcing`` (feature ->
        value; supersets allowed, missing features are 0)."""
        return Coefficients(mass=float(mass), state={f: float(lhs.get(f, 0.0)) for f in self.lhs},
                            forcing={g: float(forcing.get(g, 0.0)) for g in self.forcing},
                            y0=tuple(map(float, y0)))


@dataclasses.dataclass
class Fit:
    """A structure with fitted constants and its errors (see :func:`diagnose`):
    ``criterion`` is the mean square of ``holdout``, the held-out residual (response
    samples of the held-out tail, or every weak-form window by blocked cross-validation in
    equation-error mode)."""

    structure: Structure
    coefficients: Coefficients
    simulated: np.ndarray | None
    metrics: dict[str, float]
    criterion: float
    force: np.ndarray | None = None
    holdout: np.ndarray | None = None
    weak: WeakForm | None = None  # the weak form an equation-error fit solved

    def model(self, symbols: Symbols, provenance: dict, *,
              input_interpolation: str = "linear", substeps: int = 1) -> Model:
        """The fit as a :class:`Model`; an equation-error fit (never simulated) has no
        initial conditions."""
        coefficients = self.coefficients
        if self.simulated is None:
            coefficients = coefficients.replace(y0=(math.nan, math.nan))
        return Model.from_coefficients(
            symbols, coefficients, input_interpolation=input_interpolation, substeps=substeps,
            metrics={k: v for k, v in self.metrics.items() if v is not None},
            provenance=provenance)


def at_rest(response: np.ndarray) -> np.ndarray:
    """Samples where the measured response is unchanged over the two intervals before them
    (a drifting stage at rest to its encoder's resolution): there dry friction is
    set-valued (any force up to the static limit), which no single-valued friction term of
    the equation of motion matches, so their windows are left out of the equation error."""
    still = np.r_[False, np.diff(response) == 0]
    return still & np.r_[False, still[:-1]]


def drifts(structure: Structure, symbols: Symbols) -> bool:
    """Whether the model drifts in open loop: it has no restoring term (no term in x alone
    or g(t)·h(x)) — a free mass or an integrator."""
    return not any(symbols.x in f.free_symbols for f in structure.state + structure.parametric)


class FitProblem:
    """Data, split and settings shared by all fits of one diagnosis (``holdout`` = 0: fits
    on the whole record, with criterion 0; ``rate_band``: for drifting models, derivatives
    and weak-form windows sized by the wider of the response's band and its rate's, and
    windows where the response is at rest left out (:func:`at_rest`)).

    Raises:
        UserInputError: the fits' estimated memory at ``substeps`` exceeds what is available
            (:func:`gpjax._memory.check_fit_memory`).
    """

    def __init__(self, measurement: Measurement, symbols: Symbols, *, holdout: float,
                 iterations: int, substeps: int, batch: int,
                 input_interpolation: str = "linear", rate_band: bool = False,
                 cutoff_hz: float | None = None):
        self.measurement, self.symbols = measurement, symbols
        self.n_train = int(round((1.0 - holdout) * measurement.n_samples))
        self.train = measurement.segment(0, self.n_train)
        self.n_bins = default_n_bins(measurement.response)
        # a drifting response's energy is its drift: its derivatives keep the band of its
        # rate too, the differenced response's signal band (velocity-level equation error)
        cutoff = smoothing_cutoff_hz(self.train)
        if rate_band:
            cutoff = max(cutoff, signal_band_hz(np.diff(self.train.response), measurement.dt))
        #: Band (Hz) the derivatives and the weak-form windows keep (``cutoff_hz`` if given).
        self.cutoff_hz = cutoff = cutoff_hz or cutoff
        self.band_hz = smoothing_cutoff_hz(measurement)
        window = savgol_window(self.train, cutoff)
        self.derivatives = smoothed_derivatives(measurement, cutoff)
        train_derivatives = (self.derivatives if self.n_train == measurement.n_samples
                             else smoothed_derivatives(self.train, cutoff))
        resting = at_rest(measurement.response) if rate_band else None
        self.weak_full = WeakForm(measurement, self.derivatives.x_dot, window,
                                  excluded=resting)
        self.weak = (self.weak_full if self.n_train == measurement.n_samples
                     else WeakForm(self.train, train_derivatives.x_dot, window,
                                   excluded=None if resting is None
                                   else resting[: self.n_train]))
        self.u0 = symbols.u[0] if symbols.u else None
        self.y0 = self.derivatives.initial_state
        self.iterations, self.substeps, self.batch = iterations, substeps, batch
        self.input_interpolation = input_interpolation
        self.train_x_dot = train_derivatives.x_dot
        self.pool_lhs: tuple[sp.Expr, ...] = ()
        self.pool_forcing: tuple[sp.Expr, ...] = ()
        self.simulator: _Simulator | None = None
        check_fit_memory(n_samples=measurement.n_samples, substeps=substeps, population=batch,
                         stage="the diagnosis's fits")

    def context(self, structure: Structure, frequencies: tuple[float, ...]) -> Context:
        return Context(symbols=self.symbols, x=self.train.response, x_dot=self.train_x_dot,
                       time=self.train.time, inputs=self.train.inputs,
                       frequencies=frequencies, forcing=tuple(map(str, structure.forcing)))

    def generalised_force(self, fit: Fit) -> np.ndarray:
        """Pointwise equation-error residual m·x'' + Σc·φ − Σg·ψ on smoothed derivatives."""
        d, c, m = self.derivatives, fit.coefficients, self.measurement
        force = c.mass * d.x_ddot
        for feature, value in c.state.items():
            force = force + value * evaluate(feature, m, d.x, d.x_dot)
        for feature, value in c.forcing.items():
            force = force - value * evaluate(feature, m, d.x, d.x_dot)
        return force

    def fit_equation_error(self, structures: list[Structure]) -> list[Fit]:
        fits = []
        for structure in structures:
            mass, lhs, forcing, solution = least_squares(self.weak, structure.lhs, structure.forcing)
            coefficients = structure.coefficients(dict(zip(structure.lhs, lhs)),
                                                  dict(zip(structure.forcing, forcing)),
                                                  mass=mass, y0=self.y0)
            fit = Fit(structure, coefficients, None, {}, 0.0, weak=self.weak)
            matrix, target, _ = design(self.weak_full, structure.lhs, structure.forcing)
            # window residual / ∫ψ: the generalised force averaged over each window
            windowed = (target - matrix @ solution) / self.weak_full.kernel_area
            fit.force = self.generalised_force(fit)
            fit.holdout = blocked_cv_residual(matrix, target, self.weak_full)
            fit.criterion = float(np.mean(fit.holdout ** 2))
            fit.metrics = {"rms": float(np.sqrt(np.mean(windowed ** 2))),
                           "objective": float(np.sqrt(np.sum(windowed ** 2))),
                           "spectral_error": None, "rms_estimation": None, "rms_holdout": None}
            fits.append(fit)
        return fits

    def fit_simulation(self, structures: list[Structure]) -> list[Fit]:
        """Least-squares start, Levenberg–Marquardt refinement on the estimation part,
        simulation of the whole record; the best of start and refinement is kept. If both
        diverge for some structure, two more starts are refined along a finer continuation:
        the same start, and the structure's coefficients from a least-squares fit of the
        structure with every effect's terms (which removes the bias a missing effect puts
        into the structure's own coefficients)."""
        simulator = self.simulator_for(structures)
        count, fixed = len(structures), self._fixed_forcing(structures, simulator.train)
        population = self._starts(structures, structures, simulator.train)
        options = [population, simulator.converged(simulator.refiner, population, fixed)]
        every = Population.concatenate(options)
        responses, scores = simulator.full.simulate(every)
        chosen = [self._chosen(responses, scores, i, count, len(options)) for i in range(count)]
        if not all(simulates for _, simulates in chosen):
            pooled = [s.plus(Terms(state=tuple(f for f in self.pool_lhs
                                               if f not in s.state + s.parametric),
                                   forcing=self.pool_forcing)) for s in structures]
            retry = Population.concatenate(
                [population, self._starts(structures, pooled, simulator.train)])
            refined = simulator.converged(simulator.careful_refiner, retry,
                                          np.concatenate([fixed, fixed]))
            options += [refined.rows(slice(0, count)), refined.rows(slice(count, 2 * count))]
            every = Population.concatenate(options)
            responses, scores = simulator.full.simulate(every)
            chosen = [self._chosen(responses, scores, i, count, len(options))
                      for i in range(count)]
        rows = [j for j, _ in chosen]
        found = from_population(every.rows(rows), simulator.train, [
            s.coefficients({}, {}, mass=math.nan, y0=self.y0) for s in structures])
        return [self._simulated_fit(s, c, responses[j], scores.status[j])
                for s, c, j in zip(structures, found, rows)]

    def _starts(self, structures: list[Structure], fitted: list[Structure], ev):
        """Populations of ``structures`` with their coefficients from the weak-form least
        squares of ``fitted`` (each a superset of its structure; extra terms dropped)."""
        fits = self.fit_equation_error(fitted)
        return to_population([s.coefficients(f.coefficients.state, f.coefficients.forcing,
                                             mass=f.coefficients.mass, y0=self.y0)
                              for s, f in zip(structures, fits)], ev)

    def _fixed_forcing(self, structures: list[Structure], ev) -> np.ndarray:
        """Per structure, the forcing column held at 1 (the first input) or −1."""
        return np.array([ev.forcing_index(self.u0) if self.u0 is not None
                         and self.u0 in s.forcing else -1 for s in structures])

    def _chosen(self, responses, scores, i: int, count: int, n_options: int):
        """(row, whether it simulates) of structure ``i``'s best option: the lowest RMS on
        the estimation part among rows i, count + i, … that simulate."""
        options = []
        for j in range(i, n_options * count, count):
            residual = self.measurement.response[: self.n_train] - responses[j, : self.n_train]
            train_rms = float(np.sqrt(np.mean(residual ** 2)))
            ok = scores.status[j] == OK and np.isfinite(train_rms)
            options.append((train_rms if ok else math.inf, j))
        value, j = min(options)
        return j, math.isfinite(value)

    def simulator_for(self, structures: list[Structure]) -> "_Simulator":
        """The compiled evaluators and refiner, rebuilt only when a feature is new to them.

        They hold the features of the structures fitted so far, not the whole pool of
        effect terms: every column costs every step of every refit and simulation (on
        Silverbox's estimation part, a refit's step took 2.7× as long on the pool)."""
        lhs, forcing = [], []
        for s in structures:
            lhs += [f for f in s.state + s.parametric if f not in lhs]
            forcing += [g for g in s.forcing if g not in forcing]
        if self.simulator is None or not (set(lhs) <= set(self.simulator.lhs)
                                          and set(forcing) <= set(self.simulator.forcing)):
            if self.simulator is not None:
                lhs = list(dict.fromkeys(self.simulator.lhs + tuple(lhs)))
                forcing = list(dict.fromkeys(self.simulator.forcing + tuple(forcing)))
            # the old evaluators' arrays go before the new ones are built, not after them
            self.simulator = None
            self.simulator = _Simulator(self, tuple(lhs), tuple(forcing))
        return self.simulator

    def _simulated_fit(self, s: Structure, coefficients: Coefficients, simulated,
                       status) -> Fit:
        fit = Fit(s, coefficients, simulated, {}, math.inf)
        fit.force = self.generalised_force(fit)
        fit.holdout = np.full(self.measurement.n_samples - self.n_train, math.inf)
        if status != OK:
            fit.metrics = {"rms": math.inf, "objective": math.inf, "spectral_error": math.inf,
                           "rms_estimation": math.inf, "rms_holdout": math.inf}
            return fit
        fit.metrics = simulation_metrics(self.measurement.response, simulated, self.n_train,
                                         self.n_bins)
        holdout = self.measurement.response[self.n_train:] - simulated[self.n_train:]
        fit.holdout = holdout
        fit.criterion = float(np.mean(holdout ** 2)) if holdout.size else 0.0
        return fit


def blocked_cv_residual(matrix: np.ndarray, target: np.ndarray, weak: WeakForm) -> np.ndarray:
    """Out-of-sample weak-form residual of every window (force units): the windows in
    :data:`FOLDS` contiguous blocks, each predicted by the least squares of the windows
    that share no sample with it (blocked cross-validation; the equation-error mode's
    held-out residual, so all of the record is tested, not only its tail)."""
    rows, centres, h = target.size, weak.centres, weak.half_width
    bounds = np.linspace(0, rows, FOLDS + 1).astype(int)
    residual = np.empty(rows)
    for start, stop in zip(bounds[:-1], bounds[1:]):
        fold = slice(start, stop)
        train = (centres < centres[start] - 2 * h) | (centres > centres[stop - 1] + 2 * h)
        solution = scaled_lstsq(matrix[train], target[train])
        residual[fold] = target[fold] - matrix[fold] @ solution
    return residual / weak.kernel_area


class _Simulator:
    """Evaluators on the estimation part and the whole record, and a refiner, compiled
    once for a fixed set of features (the refiner's compile dominates a diagnosis)."""

    def __init__(self, problem: FitProblem, lhs: tuple[sp.Expr, ...],
                 forcing: tuple[sp.Expr, ...]):
        self.lhs, self.forcing = lhs, forcing
        # the effects' nonlinear parameters stay frozen (module docstring of _diagnose), so
        # feature-bank members are fixed features here, their inner constants not refined
        degree, extra, _ = split_state_features(lhs, problem.symbols, families=False)
        settings = dict(max_degree=max(3, degree), substeps=problem.substeps, n_bins=1,
                        extra_state_features=extra,
                        input_interpolation=problem.input_interpolation)
        self.train = PopulationEvaluator(problem.train, problem.symbols, batch=problem.batch,
                                         **settings)
        self.full = self.train if problem.n_train == problem.measurement.n_samples else (
            PopulationEvaluator(problem.measurement, problem.symbols, batch=2 * problem.batch,
                                **settings))
        for ev in (self.train, self.full):
            for g in forcing:
                ev.forcing_index(g)
        self.refiner = Refiner(self.train, iterations=problem.iterations, batch=problem.batch,
                               max_free=3 + len(lhs) + len(forcing))
        self._careful_refiner: Refiner | None = None
        self._jacobian = None

    @property
    def careful_refiner(self) -> Refiner:
        """A refiner with a finer continuation (horizons 10, 25, 50, 100 % of the record),
        compiled on first use: for starts whose simulation diverges over the record."""
        if self._careful_refiner is None:
            self._careful_refiner = Refiner(self.train, iterations=self.refiner.iterations,
                                            batch=self.refiner.batch,
                                            max_free=self.refiner.max_free,
                                            horizons=CAREFUL_HORIZONS)
        return self._careful_refiner

    def converged(self, refiner: Refiner, population: Population,
                  fixed_forcing: np.ndarray) -> Population:
        """``population`` refined by ``refiner`` on the estimation part in rounds until
        each model converges (:func:`gpjax._refine.refined_to_convergence`, the loop of
        every fit whose constants are reported or compared)."""
        return refined_to_convergence(refiner, population, fixed_forcing,
                                      lambda p: self.train.score(p).objective)[0]

    def jacobian(self, fit: Fit, columns: list[int]) -> np.ndarray:
        """Sensitivities of the simulated response over the whole record to the flat
        parameter vector's ``columns`` (of mass, state coefficients, forcing coefficients,
        x0, x0') at ``fit`` — shape (N, len(columns)) — from the variational equations
        (:meth:`PopulationEvaluator.constant_jacobian`, one pass). Only the columns asked
        for: the forcing tangents are a (stage rows × directions) array, so every column
        of the basis on a long record would cost gigabytes (Silverbox, 65,000 samples at 10
        steps: 1.5 GB). The directions are padded to a multiple of
        :data:`DIRECTIONS_STEP` with zero rows, so few sizes compile."""
        ev = self.full
        if self._jacobian is None:  # the basis an argument, not a constant of the program
            self._jacobian = jax.jit(
                lambda p, directions, basis: ev.constant_jacobian(p, directions, basis)[1])
        p = ev.layout.pack(to_population([fit.coefficients], ev))[0]
        rows = -(-len(columns) // DIRECTIONS_STEP) * DIRECTIONS_STEP
        directions = np.zeros((rows, p.size))
        directions[np.arange(len(columns)), columns] = 1.0
        jacobian = self._jacobian(jnp.asarray(p), jnp.asarray(directions),
                                  jnp.asarray(ev.forcing_basis))
        return np.asarray(jacobian)[: ev.measurement.n_samples, : len(columns)]


def simulation_metrics(measured: np.ndarray, simulated: np.ndarray, n_train: int,
                       n_bins: int) -> dict[str, float]:
    """RMS (all, estimation part, held-out part), objective f = f_time + f_freq (eqs. 7–9
    with unit weights) and the spectral error f_freq, in response units."""
    residual = measured - simulated
    f_time = float(np.sqrt(np.sum(residual ** 2)))
    f_freq = float(np.sum(np.abs(amplitude_spectrum(measured)[:n_bins]
                                 - amplitude_spectrum(simulated)[:n_bins])))
    holdout = residual[n_train:]
    return {"rms": float(np.sqrt(np.mean(residual ** 2))), "objective": f_time + f_freq,
            "spectral_error": f_freq, "rms_estimation": float(np.sqrt(np.mean(
                residual[:n_train] ** 2))),
            "rms_holdout": float(np.sqrt(np.mean(holdout ** 2))) if holdout.size else None}

#: Windows of the consensus refit: cutoffs from the rate's band down by √2 steps, this many.
LADDER = 9


def consensus_refits(problem: FitProblem, structures: list[Structure]) -> list[Fit]:
    """Equation-error refits of ``structures`` on the whole record (``problem``: holdout 0,
    drifting) that do not hang on one window width. Least squares in the weak form is
    consistent for any test function, so with exact data the constants would not depend on
    the window; with a quantised, noisy position they do — the shortest windows bias the
    mass low (a light stage: 0.67 for 0.76 at 7 samples, 0.77 from 15 up), and single widths
    can swing (2.1 for 2.8). So each structure is fitted with windows for :data:`LADDER`
    cutoffs, the rate's band divided by √2 each time (not below the position's band, nor
    where the windows left are too few for the blocked cross-validation's folds), and
    the fit whose constants lie nearest the constant-wise median (the medoid: sum of
    relative distances) is kept — one coherent model, robust to a minority of widths."""
    low = smoothing_cutoff_hz(problem.measurement)
    unknowns = max(2 + len(s.lhs) + len(s.forcing) for s in structures)
    ladder = [fit_structures(problem, "equation_error", structures)]
    for cutoff in problem.cutoff_hz / np.sqrt(2.0) ** np.arange(1, LADDER):
        rung = FitProblem(problem.measurement, problem.symbols, holdout=0.0,
                          iterations=problem.iterations, substeps=problem.substeps,
                          batch=problem.batch, input_interpolation=problem.input_interpolation,
                          rate_band=True, cutoff_hz=cutoff)
        # every cross-validation fold's fit must stay overdetermined
        if cutoff < low or rung.weak_full.centres.size < FOLDS * unknowns:
            break
        ladder.append(fit_structures(rung, "equation_error", structures))
    out = []
    for k in range(len(structures)):
        fits = [rung[k] for rung in ladder]
        values = np.array([[f.coefficients.mass, *f.coefficients.state.values(),
                            *f.coefficients.forcing.values()] for f in fits])
        middle = np.median(values, axis=0)
        scale = np.where(np.abs(middle) > 0, np.abs(middle), 1.0)
        out.append(fits[int(np.argmin(np.sum(np.abs(values - middle) / scale, axis=1)))])
    return out


def fit_structures(problem: FitProblem, mode: str, structures: list[Structure]) -> list[Fit]:
    """Fits of ``structures``: weak-form least squares (``mode`` "equation_error") or
    refined on the simulated response ("simulation")."""
    if mode == "equation_error":
        return problem.fit_equation_error(structures)
    return problem.fit_simulation(structures)

