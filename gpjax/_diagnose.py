"""Diagnosis: trace the residual of a model to a missing physical effect, add it, repeat.

Each round:

1. **Residuals.** The time-domain residual (measured − simulated), its amplitude
   spectrum, and the equation-error residual — the generalised force the model misses,
   ``m·x'' + Σ c·φ − Σ g·ψ`` evaluated on Savitzky–Golay derivatives (pointwise, for
   plots) and in weak form (integrated against compact test functions, for fitting).
2. **Parameters of each effect.** Every effect of the library (:mod:`gpjax._effects`)
   has its nonlinear parameters searched on a grid from the data (candidate frequencies:
   the input's strongest spectral lines and any the user gives) and, in the first round,
   by Nelder–Mead from the best grid point (the best three for a dead zone's two
   parameters), to maximise the fraction of the
   weak-form equation-error residual energy its regressors explain once the model's own
   regressors are projected out (cheap and linear); they stay frozen for the rest of the
   diagnosis. If more than ``shortlist`` effects apply, the best by that fraction go on.
3. **Refit.** Each effect is added to the model on its own and all constants are
   refitted — weak-form least squares for the start, then optimistix
   Levenberg–Marquardt on the simulated response (:class:`gpjax._refine.Refiner`) — on
   the *estimation* part of the record (the first ``1 − holdout``), fitted over its first
   25 %, then all of it (a start that diverges is refitted over 10, 25, 50 and 100 %),
   and the refit is simulated over the whole record from its fitted initial state.
4. **Evidence: held-out output error, with one step of look-ahead.** (Simulation mode.)
   The equation error weighs a missing force by its size, the simulated response by what
   it does to the response (a force near resonance counts ~Q times more than a static
   one), so effects are ranked on the simulated response: by the mean-square error on the
   held-out last ``holdout`` fraction, each added parameter charged a factor
   (1 − ``min_gain``)^−1 — for the effect refitted alone, and for the best *pair* it
   belongs to. A pair's error is predicted by one Gauss–Newton step from the refit of
   either member with the other's coefficients added (from 0; sensitivities of the
   simulated response by forward-mode differentiation of the solve; the step is the
   least-squares fit of the estimation part of the residual, applied to the held-out
   part; the lower of the two predictions counts). An effect scores the lower of its
   charged error alone and that of its best pair; the two members of the best pair tie
   and the one better alone ranks first. The look-ahead keeps a flexible effect that
   mimics two simple ones at once (a one-sided backlash spring: an offset plus a
   stiffness change) from pre-empting them when the pair of simple effects does better.
   In equation-error mode (below) the ranking is the explained fraction of step 2. The
   report's evidence column states which.
5. **Acceptance by cross-validation on a held-out segment.** A candidate passes if its
   held-out mean-square error is below the current model's times
   (1 − ``min_gain``)^p · (1 − √(2/n)), p = the coefficients plus nonlinear parameters it
   adds, n = the held-out samples (equation-error mode: held-out windows). Each free
   parameter must buy ``min_gain``, default 2 %, of held-out error — a term that only fits
   noise buys nothing on data it was not fitted to — and the whole gain must exceed
   √(2/n), the relative sampling error of a mean square of n noise samples: at the noise
   floor a held-out error moves by that much with any term that bends the simulated
   response a little (on a 1,334-sample gear record, n = 334: 7.7 %). The best-ranked
   passing candidate is added (equation-error mode: the passing one with the lowest
   charged held-out error). Rounds stop when no candidate passes.

Drifting systems (a free mass with friction, a pure integrator): if the starting model has
no restoring term (no term in x alone), the whole diagnosis runs on the **equation error** instead (mode
``"equation_error"``): fits are weak-form least squares, the held-out criterion is the
weak-form residual on the held-out segment, and the reported ``rms`` is the RMS of the
pointwise generalised-force residual (force units, not response units).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import sympy as sp
from scipy.optimize import minimize

from ._canonical import Symbols
from ._convergence import MAX_SUBSTEPS, check_model, initial_substeps, next_substeps
from ._data import INPUT_INTERPOLATIONS, Measurement
from ._effects import Context, Effect, Terms, effects
from ._errors import ModelFileError, UserInputError
from ._evaluator import PopulationEvaluator
from ._objective import amplitude_spectrum, default_n_bins
from ._expressions import parse_expression
from ._model import Model
from ._refine import Refiner
from ._weak_form import (WeakForm, design, evaluate, least_squares, savgol_window,
                         smoothed_derivatives)

#: Strongest spectral lines of each input offered to frequency-dependent effects.
INPUT_LINES = 6
#: Continuation of the refit when a start and its refinement both diverge (fractions of the
#: estimation part fitted in turn).
CAREFUL_HORIZONS = (0.1, 0.25, 0.5, 1.0)
#: Best grid points polished by Nelder–Mead for effects of two or more nonlinear
#: parameters (one start for one parameter, whose grid is dense).
POLISH_STARTS = 3


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


@dataclasses.dataclass
class Fit:
    """A structure with fitted constants and its errors (see :func:`diagnose`)."""

    structure: Structure
    mass: float
    state: np.ndarray
    parametric: np.ndarray
    forcing: np.ndarray
    y0: tuple[float, float]
    simulated: np.ndarray | None
    metrics: dict[str, float]
    criterion: float
    force: np.ndarray | None = None

    def model(self, symbols: Symbols, provenance: dict, *,
              input_interpolation: str = "linear", substeps: int = 1) -> Model:
        """The fit as a :class:`Model` (feature texts as sympy prints them)."""
        return Model(symbols=symbols, mass=float(self.mass),
                     input_interpolation=input_interpolation, substeps=substeps,
                     state={str(f): float(c) for f, c in zip(self.structure.state, self.state)},
                     forcing={str(f): float(g)
                              for f, g in zip(self.structure.forcing, self.forcing)},
                     parametric={str(f): float(c) for f, c in
                                 zip(self.structure.parametric, self.parametric)},
                     initial_conditions=None if self.simulated is None else self.y0,
                     metrics={k: v for k, v in self.metrics.items() if v is not None},
                     provenance=provenance)


@dataclasses.dataclass(frozen=True)
class Candidate:
    """An effect with its best parameters and its evidence in one round: ``explained``
    (share of the equation-error residual) and, in simulation mode once refitted,
    ``predicted`` (ranking score, held-out RMS alone, best partner and the pair's
    predicted held-out RMS; see :func:`rank_by_output_error`)."""

    effect: Effect
    parameters: dict
    terms: Terms
    explained: float
    evidence: str
    predicted: dict | None = None


@dataclasses.dataclass
class Diagnosis:
    """Result of :func:`diagnose`; :func:`write_report` writes it out.

    Attributes:
        mode: ``"simulation"`` or ``"equation_error"`` (see the module docstring).
        steps: one dict per accepted effect (effect, evidence, term, coefficient, …), with
            the errors of the loop's fits (fitted on the estimation part).
        rankings: per round, every effect's evidence (best first).
        fits: the loop's accepted fits in order, starting with the refitted starting model,
            fitted on the estimation part (the held-out part decided).
        refits: the same structures refitted on the whole record once chosen (the held-out
            part has done its work); ``before`` and ``after`` are the first and the last.
        frequencies: candidate frequencies in Hz offered to frequency effects.
        n_train: samples of the estimation part; the rest is held out.
        measurement, symbols: the data and its names.
    """

    mode: str
    steps: list[dict]
    rankings: list[list[dict]]
    fits: list[Fit]
    refits: list[Fit]
    frequencies: tuple[float, ...]
    n_train: int
    measurement: Measurement
    symbols: Symbols
    settings: dict
    convergence: dict | None = None

    @property
    def before(self) -> Fit:
        """The starting structure refitted on the whole record."""
        return self.refits[0]

    @property
    def after(self) -> Fit:
        """The final structure refitted on the whole record."""
        return self.refits[-1]

    @property
    def effects_added(self) -> list[str]:
        return [step["effect"] for step in self.steps]

    def model(self) -> Model:
        """The final model, with its integration check (:attr:`convergence`)."""
        model = self._as_model(self.after, {"diagnosis": self.effects_added, "mode": self.mode})
        if self.convergence is None:
            return model
        return dataclasses.replace(model, convergence=self.convergence, metrics=model.metrics | {
            "rms_reference": self.convergence["rms_reference"]})

    def models(self) -> list[Model]:
        """The starting model and the model after each accepted step, in order, each
        refitted on the whole record."""
        return [self._as_model(fit, {}) for fit in self.refits]

    def _as_model(self, fit: Fit, provenance: dict) -> Model:
        return fit.model(self.symbols, provenance,
                         input_interpolation=self.settings["input_interpolation"],
                         substeps=self.settings["substeps"])

    def to_json(self) -> dict:
        return {"mode": self.mode, "criterion": _CRITERION[self.mode],
                "settings": self.settings, "n_samples": self.measurement.n_samples,
                "n_estimation": self.n_train, "frequencies_hz": list(self.frequencies),
                "effects_added": self.effects_added,
                "before": _summary(self.before), "after": _summary(self.after),
                "steps": self.steps, "rankings": self.rankings,
                "convergence": self.convergence, "model": self.model().to_json()}


_CRITERION = {
    "simulation": "effects ranked by held-out output error charged (1 - min_gain)^-p, "
                  "refitted alone and, one Gauss-Newton step ahead, with the best partner "
                  "effect; cross-validation on a held-out segment: the model is fitted on "
                  "the first part of the record and simulated over all of it; the "
                  "best-ranked effect whose held-out mean-square error falls below "
                  "(1 - min_gain)^p (1 - sqrt(2/n)) times the current model's is kept, "
                  "p = parameters the effect adds, n = held-out samples",
    "equation_error": "cross-validation of the weak-form equation error on a held-out "
                      "segment (the starting model drifts in open-loop simulation); an "
                      "effect is kept when its held-out mean square falls below "
                      "(1 - min_gain)^p (1 - sqrt(2/n)) times the current model's, "
                      "n = held-out windows",
}


def _summary(fit: Fit) -> dict:
    return {k: fit.metrics.get(k) for k in ("rms", "objective", "spectral_error",
                                            "rms_estimation", "rms_holdout")}


def explained_fraction(weak: WeakForm, structure: Structure, terms: Terms) -> float:
    """Fraction of the weak-form equation-error residual energy that ``terms`` explain
    after the structure's own regressors are projected out (0 … 1)."""
    matrix, target, _ = design(weak, structure.lhs, structure.forcing)
    new = [weak.column(f) for f in terms.state + terms.parametric + terms.forcing]
    new = [c for c in new if np.all(np.isfinite(c))]
    if not new:
        return 0.0
    extra = np.stack(new, axis=1)
    if matrix.shape[1]:
        scale = np.linalg.norm(matrix, axis=0)
        q, _ = np.linalg.qr(matrix / np.where(scale > 0, scale, 1.0))
        residual = target - q @ (q.T @ target)
        extra = extra - q @ (q.T @ extra)
    else:
        residual = target
    total = float(residual @ residual)
    norms = np.linalg.norm(extra, axis=0)
    if total == 0 or not np.any(norms > 1e-9 * (np.max(norms) + 1e-300)):
        return 0.0
    extra = extra[:, norms > 1e-9 * np.max(norms)]
    qe, _ = np.linalg.qr(extra / np.linalg.norm(extra, axis=0))
    projected = qe.T @ residual
    return float(np.clip(projected @ projected / total, 0.0, 1.0))


# --- candidate frequencies and evidence ---------------------------------------------------
def input_lines(measurement: Measurement, *, count: int = INPUT_LINES) -> list[float]:
    """The ``count`` strongest spectral lines (local maxima, DC excluded) of each input, Hz."""
    lines: list[float] = []
    for values in measurement.inputs.values():
        amplitude = amplitude_spectrum(values - np.mean(values))
        peaks = [j for j in range(1, amplitude.size - 1)
                 if amplitude[j] >= amplitude[j - 1] and amplitude[j] > amplitude[j + 1]]
        peaks.sort(key=lambda j: -amplitude[j])
        frequency = np.fft.rfftfreq(values.size, measurement.dt)
        lines += [float(frequency[j]) for j in peaks[:count]]
    return lines


def rank_effects(weak: WeakForm, structure: Structure, context: Context,
                 library: dict[str, Effect], *,
                 polish: bool = True) -> list[Candidate]:
    """Every applicable effect with its best parameters, ranked by the fraction of the
    equation-error residual it explains: the best grid point, or if ``polish`` the best
    grid point(s) (:data:`POLISH_STARTS`) polished by Nelder–Mead."""
    ranked = []
    present = set(structure.state + structure.parametric + structure.forcing)
    for effect in library.values():
        scored = []
        for parameters in effect.grid(context):
            terms = effect.build(context, parameters)
            if terms is None or set(terms.state + terms.parametric + terms.forcing) <= present:
                continue
            scored.append((explained_fraction(weak, structure, terms), parameters, terms))
        if not scored:
            continue
        scored.sort(key=lambda item: -item[0])
        starts = scored[:POLISH_STARTS if polish and len(effect.parameters) > 1 else 1]
        score, parameters, terms = max(
            (_polish(effect, context, start, weak, structure) if polish else start
             for start in starts), key=lambda item: item[0])
        evidence = f"explains {100 * score:.1f} % of the equation-error residual energy"
        if "frequency" in parameters:
            evidence += f" with a line at {parameters['frequency']:.6g} Hz"
        ranked.append(Candidate(effect, parameters, terms, score, evidence))
    ranked.sort(key=lambda c: -c.explained)
    return ranked


def _polish(effect: Effect, context: Context, best, weak, structure):
    """Nelder–Mead on the numeric parameters (within bounds), maximising the evidence."""
    score, parameters, terms = best
    names = [p.name for p in effect.parameters if isinstance(parameters.get(p.name), float)]
    if not names:
        return best
    bounds = effect.bounds(context)
    duration = context.time[-1] - context.time[0]
    start = np.array([parameters[n] for n in names])
    steps = np.array([0.5 / duration if n == "frequency" else
                      0.2 * (abs(v) or 0.1 * (bounds[n][1] - bounds[n][0]))
                      for n, v in zip(names, start)])

    def negative(values):
        trial = dict(parameters, **{n: float(np.clip(v, *bounds[n]))
                                    for n, v in zip(names, values)})
        built = effect.build(context, trial)
        return -explained_fraction(weak, structure, built) if built else 0.0

    simplex = np.vstack([start] + [start + np.eye(len(names))[i] * steps[i]
                                   for i in range(len(names))])
    result = minimize(negative, start, method="Nelder-Mead",
                      options={"initial_simplex": simplex, "maxfev": 30 * len(names),
                               "xatol": 1e-12, "fatol": 1e-6})
    if -result.fun <= score:
        return best
    polished = dict(parameters, **{n: float(np.clip(v, *bounds[n]))
                                   for n, v in zip(names, result.x)})
    return -float(result.fun), polished, effect.build(context, polished)


# --- fitting ------------------------------------------------------------------------------
class _Problem:
    """Data, split and settings shared by all fits of one diagnosis (``holdout`` = 0: fits
    on the whole record, with criterion 0)."""

    def __init__(self, measurement: Measurement, symbols: Symbols, *, holdout: float,
                 iterations: int, substeps: int, batch: int,
                 input_interpolation: str = "linear"):
        self.measurement, self.symbols = measurement, symbols
        self.n_train = int(round((1.0 - holdout) * measurement.n_samples))
        self.train = measurement.segment(0, self.n_train)
        self.n_bins = default_n_bins(measurement.response)
        cutoff = default_n_bins(self.train.response) / (self.n_train * measurement.dt)
        window = savgol_window(self.train, cutoff)
        self.derivatives = smoothed_derivatives(measurement, cutoff)
        train_derivatives = (self.derivatives if self.n_train == measurement.n_samples
                             else smoothed_derivatives(self.train, cutoff))
        self.weak_full = WeakForm(measurement, symbols, self.derivatives.x_dot, window)
        self.weak = (self.weak_full if self.n_train == measurement.n_samples
                     else WeakForm(self.train, symbols, train_derivatives.x_dot, window))
        self.holdout_rows = self.weak_full.centres - self.weak_full.half_width >= self.n_train
        self.u0 = symbols.u[0] if symbols.u else None
        self.y0 = (float(self.derivatives.x[0]), float(self.derivatives.x_dot[0]))
        self.iterations, self.substeps, self.batch = iterations, substeps, batch
        self.input_interpolation = input_interpolation
        self.train_x_dot = train_derivatives.x_dot
        self.pool_lhs: tuple[sp.Expr, ...] = ()
        self.pool_forcing: tuple[sp.Expr, ...] = ()
        self.simulator: _Simulator | None = None

    def sampling_error(self, mode: str) -> float:
        """√(2/n), the relative standard error of a held-out mean square of n independent
        noise values (n: held-out samples, or held-out windows in equation-error mode)."""
        n = (int(np.count_nonzero(self.holdout_rows)) if mode == "equation_error"
             else self.measurement.n_samples - self.n_train)
        return math.sqrt(2.0 / n) if n else 0.0

    def context(self, structure: Structure, frequencies: tuple[float, ...]) -> Context:
        return Context(symbols=self.symbols, x=self.train.response, x_dot=self.train_x_dot,
                       time=self.train.time, inputs=self.train.inputs,
                       frequencies=frequencies, forcing=tuple(map(str, structure.forcing)))

    def generalised_force(self, fit: Fit) -> np.ndarray:
        """Pointwise equation-error residual m·x'' + Σc·φ − Σg·ψ on smoothed derivatives."""
        d, s, m = self.derivatives, fit.structure, self.measurement
        force = fit.mass * d.x_ddot
        for feature, c in zip(s.state + s.parametric, np.concatenate([fit.state, fit.parametric])):
            force = force + c * evaluate(feature, self.symbols, m, d.x, d.x_dot)
        for feature, g in zip(s.forcing, fit.forcing):
            force = force - g * evaluate(feature, self.symbols, m, d.x, d.x_dot)
        return force

    def drifts(self, structure: Structure) -> bool:
        """Whether the model drifts in open loop: it has no restoring term (no term in x
        alone or g(t)·h(x)) — a free mass or an integrator."""
        x = self.symbols.x
        return not any(x in f.free_symbols for f in structure.state + structure.parametric)

    def fit_equation_error(self, structures: list[Structure]) -> list[Fit]:
        fits = []
        for structure in structures:
            mass, lhs, forcing, solution = least_squares(self.weak, structure.lhs, structure.forcing)
            n_state = len(structure.state)
            fit = Fit(structure, mass, lhs[:n_state], lhs[n_state:], forcing, self.y0, None, {}, 0.0)
            matrix, target, _ = design(self.weak_full, structure.lhs, structure.forcing)
            # window residual / ∫ψ: the generalised force averaged over each window
            windowed = (target - matrix @ solution) / self.weak_full.kernel_area
            fit.force = self.generalised_force(fit)
            held_out = windowed[self.holdout_rows]
            fit.criterion = float(np.mean(held_out ** 2)) if held_out.size else 0.0
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
        simulator = self._simulator_for(structures)
        count, fixed = len(structures), self._fixed_forcing(structures, simulator.train)
        population = self._starts(structures, structures, simulator.train)
        options = [population, simulator.refiner.refine(population, fixed).population]
        every = _stack(*options)
        responses, scores = simulator.full.simulate(every)
        chosen = [self._chosen(responses, scores, i, count, len(options)) for i in range(count)]
        if not all(simulates for _, simulates in chosen):
            pooled = [s.plus(Terms(state=tuple(f for f in self.pool_lhs
                                               if f not in s.state + s.parametric),
                                   forcing=self.pool_forcing)) for s in structures]
            retry = _stack(population, self._starts(structures, pooled, simulator.train))
            refined = simulator.careful_refiner.refine(retry, np.concatenate([fixed, fixed]))
            options += [_rows(refined.population, slice(0, count)),
                        _rows(refined.population, slice(count, 2 * count))]
            every = _stack(*options)
            responses, scores = simulator.full.simulate(every)
            chosen = [self._chosen(responses, scores, i, count, len(options))
                      for i in range(count)]
        return [self._simulated_fit(s, every, j, responses[j], simulator.train, scores.status[j])
                for s, (j, _) in zip(structures, chosen)]

    def _starts(self, structures: list[Structure], fitted: list[Structure], ev):
        """Populations of ``structures`` with their coefficients from the weak-form least
        squares of ``fitted`` (each a superset of its structure; extra terms dropped)."""
        population = ev.empty(len(structures))
        for i, (s, fit) in enumerate(zip(structures, self.fit_equation_error(fitted))):
            lhs = dict(zip(fit.structure.state + fit.structure.parametric,
                           np.concatenate([fit.state, fit.parametric])))
            forcing = dict(zip(fit.structure.forcing, fit.forcing))
            population.mass[i] = fit.mass
            for f in s.state + s.parametric:
                population.state[i, ev.state_index(f)] = lhs[f]
            for g in s.forcing:
                population.forcing[i, ev.forcing_index(g)] = forcing[g]
            population.y0[i] = self.y0
        return population

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
            ok = scores.status[j] == 0 and np.isfinite(train_rms)
            options.append((train_rms if ok else math.inf, j))
        value, j = min(options)
        return j, math.isfinite(value)

    def _simulator_for(self, structures: list[Structure]) -> "_Simulator":
        """The compiled evaluators and refiner, rebuilt only when a feature is new to them."""
        lhs, forcing = list(self.pool_lhs), list(self.pool_forcing)
        for s in structures:
            lhs += [f for f in s.state + s.parametric if f not in lhs]
            forcing += [g for g in s.forcing if g not in forcing]
        if self.simulator is None or not (set(lhs) <= set(self.simulator.lhs)
                                          and set(forcing) <= set(self.simulator.forcing)):
            if self.simulator is not None:
                lhs = list(dict.fromkeys(self.simulator.lhs + tuple(lhs)))
                forcing = list(dict.fromkeys(self.simulator.forcing + tuple(forcing)))
            self.simulator = _Simulator(self, tuple(lhs), tuple(forcing))
        return self.simulator

    def _simulated_fit(self, s: Structure, population, j: int, simulated, ev, status) -> Fit:
        lhs = np.array([population.state[j, ev.state_index(f)] for f in s.state + s.parametric])
        forcing = np.array([population.forcing[j, ev.forcing_index(g)] for g in s.forcing])
        fit = Fit(s, float(population.mass[j]), lhs[:len(s.state)], lhs[len(s.state):], forcing,
                  (float(population.y0[j, 0]), float(population.y0[j, 1])), simulated, {}, math.inf)
        fit.force = self.generalised_force(fit)
        if status != 0:
            fit.metrics = {"rms": math.inf, "objective": math.inf, "spectral_error": math.inf,
                           "rms_estimation": math.inf, "rms_holdout": math.inf}
            return fit
        fit.metrics = simulation_metrics(self.measurement.response, simulated, self.n_train,
                                         self.n_bins)
        holdout = self.measurement.response[self.n_train:] - simulated[self.n_train:]
        fit.criterion = float(np.mean(holdout ** 2)) if holdout.size else 0.0
        return fit


class _Simulator:
    """Evaluators on the estimation part and the whole record, and a refiner, compiled
    once for a fixed set of features (the refiner's compile dominates a diagnosis)."""

    def __init__(self, problem: _Problem, lhs: tuple[sp.Expr, ...],
                 forcing: tuple[sp.Expr, ...]):
        self.lhs, self.forcing = lhs, forcing
        powers = [_power(f, problem.symbols) for f in lhs]
        extra = tuple(f for f, p in zip(lhs, powers) if p is None)
        degree = max([3] + [p[1] for p in powers if p is not None])
        settings = dict(max_degree=degree, substeps=problem.substeps, n_bins=1,
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

    def jacobian(self, fit: Fit) -> np.ndarray:
        """Sensitivities of the simulated response over the whole record to the parameter
        vector (mass, every state coefficient, every forcing coefficient, x0, x0') at
        ``fit`` — shape (N, 1 + F_state + F_forcing + 2) — from the variational equations
        (:meth:`PopulationEvaluator.constant_jacobian`, one pass)."""
        ev = self.full
        n_state = len(ev.state_features)
        if self._jacobian is None:
            basis = jnp.asarray(ev.forcing_basis)
            self._jacobian = jax.jit(
                lambda p: ev.constant_jacobian(p, jnp.eye(p.size), basis)[1])
        p = np.zeros(1 + n_state + ev.forcing_capacity + 2)
        p[0] = fit.mass
        s = fit.structure
        for f, c in zip(s.state + s.parametric, np.concatenate([fit.state, fit.parametric])):
            p[1 + ev.state_index(f)] = c
        for g, c in zip(s.forcing, fit.forcing):
            p[1 + n_state + ev.forcing_index(g)] = c
        p[-2:] = fit.y0
        return np.asarray(self._jacobian(jnp.asarray(p)))


# --- output-error evidence -----------------------------------------------------------------
def rank_by_output_error(problem: _Problem, candidates: list[Candidate], results: list[Fit],
                         min_gain: float) -> list[int]:
    """Order (indices, best first) of the candidates whose refits are ``results``, ranked
    on the held-out output error with one step of look-ahead (module docstring, 4.); the
    candidates' evidence is rewritten to say so. While the leader owes its place to a
    predicted pair, that pair is refitted and its prediction replaced by the refit."""
    charge = [_charge(c, min_gain) for c in candidates]
    alone = [r.criterion * k for r, k in zip(results, charge)]
    pairs: dict[tuple[int, int], float] = {}
    for i, fit in enumerate(results):
        if not math.isfinite(fit.criterion):
            continue
        predict = _gauss_newton(problem, fit)
        for j, other in enumerate(candidates):
            if j != i:
                key = (min(i, j), max(i, j))
                pairs[key] = min(pairs.get(key, math.inf), predict(other.terms))
    refitted: set[tuple[int, int]] = set()
    while True:
        best = [(value, None, None) for value in alone]  # (score, partner, pair error)
        for (i, j), value in pairs.items():
            charged = value * charge[i] * charge[j]
            for a, b in ((i, j), (j, i)):
                if charged < best[a][0]:
                    best[a] = (charged, b, value)
        order = sorted(range(len(candidates)), key=lambda i: (best[i][0], alone[i]))
        leader, partner = order[0], best[order[0]][1]
        key = None if partner is None else (min(leader, partner), max(leader, partner))
        if key is None or key in refitted:
            break
        pair = results[leader].structure.plus(candidates[partner].terms)
        criterion = problem.fit_simulation([pair])[0].criterion
        pairs[key] = criterion if math.isfinite(criterion) else math.inf
        refitted.add(key)
    for i, c in enumerate(candidates):
        score, partner, pair = best[i]
        evidence = f"held-out RMS {math.sqrt(results[i].criterion):.4g} refitted alone"
        verified = partner is not None and (min(i, partner), max(i, partner)) in refitted
        if partner is not None:
            how = "refitted" if verified else "predicted (Gauss–Newton step)"
            evidence += f", {math.sqrt(pair):.4g} {how} with {candidates[partner].effect.name}"
        candidates[i] = dataclasses.replace(c, evidence=evidence, predicted={
            "score": score, "holdout_rms_alone": math.sqrt(results[i].criterion),
            "partner": None if partner is None else candidates[partner].effect.name,
            "holdout_rms_with_partner": None if pair is None else math.sqrt(pair),
            "pair_refitted": verified})
    return order


def _gauss_newton(problem: _Problem, fit: Fit):
    """A function: the terms of one more effect -> the held-out mean-square error that one
    Gauss–Newton step from ``fit`` predicts with them added (their coefficients from 0,
    the fit's own parameters free): least squares of the residual measured − simulated on
    the estimation part, applied to the held-out part."""
    structure = fit.structure
    simulator = problem._simulator_for([structure])
    ev = simulator.full
    jacobian = simulator.jacobian(fit)
    residual = problem.measurement.response - fit.simulated
    n_state, n = len(ev.state_features), problem.n_train

    def columns(lhs, forcing, fixed=None):
        return ([1 + ev.state_index(f) for f in lhs]
                + [1 + n_state + ev.forcing_index(g) for g in forcing if g != fixed])

    normalised = problem.u0 is not None and problem.u0 in structure.forcing
    base = (([0] if normalised else [])
            + columns(structure.state + structure.parametric, structure.forcing,
                      problem.u0 if normalised else None)
            + [jacobian.shape[1] - 2, jacobian.shape[1] - 1])

    def predicted(terms: Terms) -> float:
        extra = columns(terms.state + terms.parametric, terms.forcing)
        a = jacobian[:, base + [c for c in dict.fromkeys(extra) if c not in base]]
        scale = np.linalg.norm(a[:n], axis=0)
        a = a / np.where(scale > 0, scale, 1.0)
        step = np.linalg.lstsq(a[:n], residual[:n], rcond=None)[0]
        return float(np.mean((residual[n:] - a[n:] @ step) ** 2))

    return predicted


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


def _power(feature: sp.Expr, symbols: Symbols):
    for symbol in (symbols.x, symbols.x_dot):
        if feature == symbol:
            return symbol, 1
        if isinstance(feature, sp.Pow) and feature.base == symbol and feature.exp.is_Integer \
                and feature.exp > 0:
            return symbol, int(feature.exp)
    return None


def _stack(*populations):
    from ._evaluator import Population
    return Population(*(np.concatenate([getattr(p, name) for p in populations])
                        for name in ("mass", "state", "forcing", "y0")))


def _rows(population, rows: slice):
    from ._evaluator import Population
    return Population(*(getattr(population, name)[rows]
                        for name in ("mass", "state", "forcing", "y0")))


# --- the loop ------------------------------------------------------------------------------
def structure_of(model: Model) -> Structure:
    """The features of a model (its constants are ignored: they are refitted)."""
    def parse(texts):
        return tuple(parse_expression(t, model.symbols.names()) for t in texts)
    return Structure(parse(model.state), parse(model.parametric), parse(model.forcing))


def diagnose(measurement: Measurement, model: Model, *, library: dict[str, Effect] | None = None,
             frequencies: tuple[float, ...] = (), holdout: float = 0.25, max_steps: int = 4,
             shortlist: int = 4, min_gain: float = 0.02, iterations: int = 20,
             substeps: int | str = "auto", convergence_tolerance: float = 0.01,
             input_interpolation: str | None = None, mode: str = "auto") -> Diagnosis:
    """Add missing effects to ``model`` while held-out error improves (module docstring).

    Args:
        measurement: the data; its columns must carry the model's variable names.
        model: the starting model; only its structure is used, constants are refitted.
        library: effects to consider (default: all registered effects).
        frequencies: candidate frequencies in Hz for frequency effects (e.g. the gear mesh
            frequency), tried before the input's strongest spectral lines.
        holdout: fraction of the record (at its end) held out for cross-validation.
        max_steps: most effects added.
        shortlist: most effects refitted per round (the best by explained fraction of the
            equation-error residual, if more apply).
        min_gain: relative fall of the held-out mean-square error each added parameter
            must bring (on top of the held-out error's own sampling error, √(2/n)).
        iterations: Levenberg–Marquardt steps per refit.
        substeps: RK4 steps per sample interval, or ``"auto"``: the larger of the data's
            bandwidth rule and the starting model's, raised (and the chosen structures
            refitted on the whole record) until the final model's RK4 response agrees with
            the reference solve to ``convergence_tolerance`` of its RMS residual
            (:mod:`gpjax._convergence`; simulation mode). The check is reported either way.
        convergence_tolerance: that agreement, as a fraction of the RMS residual.
        input_interpolation: inputs between samples in the simulation, ``"linear"``,
            ``"bandlimited"`` (for inputs with content near the Nyquist frequency) or
            ``"hold"`` (for inputs applied by a DAC; :func:`gpjax._data.between_samples`);
            default: the starting model's. The final model
            records it.
        mode: ``"auto"``, ``"simulation"`` or ``"equation_error"``.

    Raises:
        UserInputError: the data's names differ from the model's, or a setting is out of
            range.
    """
    symbols = model.symbols
    names = (measurement.time_name, measurement.response_name, tuple(measurement.input_names))
    if names != (symbols.time, symbols.response, tuple(symbols.inputs)):
        raise ModelFileError(
            f"the model's variables (time {symbols.time!r}, response {symbols.response!r}, "
            f"inputs {list(symbols.inputs)}) differ from the data's columns (time {names[0]!r}, "
            f"response {names[1]!r}, inputs {list(names[2])}); pass matching --time, "
            "--response and --input or edit the model's \"variables\"")
    if not 0.05 <= holdout <= 0.5:
        raise UserInputError(f"holdout must lie in [0.05, 0.5], got {holdout}; use e.g. 0.25")
    if mode not in ("auto", "simulation", "equation_error"):
        raise UserInputError(f"mode {mode!r} is unknown; use auto, simulation or equation_error")
    input_interpolation = input_interpolation or model.input_interpolation
    if input_interpolation not in INPUT_INTERPOLATIONS:
        raise UserInputError(f"input interpolation {input_interpolation!r} is unknown; use "
                             f"{' or '.join(INPUT_INTERPOLATIONS)}")
    automatic = substeps == "auto"
    if automatic:
        substeps = max(initial_substeps(measurement), model.substeps)
    if (max_steps < 0 or shortlist < 1 or min_gain < 0 or iterations < 1
            or not isinstance(substeps, int) or not 1 <= substeps <= MAX_SUBSTEPS
            or not 0 < convergence_tolerance < 1):
        raise UserInputError(f"max_steps >= 0, shortlist >= 1, min_gain >= 0, iterations >= 1, "
                             f"substeps \"auto\" or 1 … {MAX_SUBSTEPS} and 0 < "
                             "convergence_tolerance < 1 are required; fix the setting")
    library = effects() if library is None else dict(library)
    problem = _Problem(measurement, symbols, holdout=holdout, iterations=iterations,
                       substeps=substeps, batch=shortlist + 1,
                       input_interpolation=input_interpolation)
    lines = tuple(dict.fromkeys([*map(float, frequencies), *input_lines(problem.train)]))
    structure = structure_of(model)
    chosen_mode = "equation_error" if mode == "equation_error" else "simulation"
    current = None
    steps, rankings, fits = [], [], []
    for round_number in range(max_steps + 1):
        context = problem.context(structure, lines)
        ranked = rank_effects(problem.weak, structure, context, library,
                              polish=round_number == 0)
        if round_number == 0:  # parameters found on the starting residual are kept
            library = {c.effect.name: _frozen(c) for c in ranked}
            problem.pool_lhs = tuple(dict.fromkeys(
                f for c in ranked for f in c.terms.state + c.terms.parametric))
            problem.pool_forcing = tuple(dict.fromkeys(f for c in ranked for f in c.terms.forcing))
        shortlisted = ranked[:shortlist] if round_number < max_steps else []
        candidates = [structure.plus(c.terms) for c in shortlisted]
        if current is None:
            if mode == "auto" and problem.drifts(structure):
                chosen_mode = "equation_error"
            results = _fit(problem, chosen_mode, [structure] + candidates)
            current, results = results[0], results[1:]
            fits.append(current)
        else:
            results = _fit(problem, chosen_mode, candidates) if candidates else []
        if chosen_mode == "simulation" and results:
            order = rank_by_output_error(problem, shortlisted, results, min_gain)
            ranked = [shortlisted[i] for i in order] + ranked[len(shortlisted):]
            shortlisted, results = ranked[:len(order)], [results[i] for i in order]
        rankings.append([{"effect": c.effect.name, "explained": c.explained,
                          "parameters": c.parameters, "evidence": c.evidence,
                          **({"predicted": c.predicted} if c.predicted else {})}
                         for c in ranked])
        if not results:
            break
        # held-out error charged (1 − min_gain) per added parameter must beat the current
        # model's by more than its sampling error; simulation: the best-ranked such
        # candidate, equation error: the lowest
        penalised = [r.criterion * _charge(c, min_gain) for r, c in zip(results, shortlisted)]
        required = current.criterion * (1.0 - problem.sampling_error(chosen_mode))
        passing = [i for i, value in enumerate(penalised) if value < required]
        if not passing:
            break
        best = passing[0] if chosen_mode == "simulation" else min(passing,
                                                                   key=penalised.__getitem__)
        steps.append(_step(shortlisted[best], ranked, current, results[best], chosen_mode))
        structure, current = results[best].structure, results[best]
        fits.append(current)
    settings = {"holdout": holdout, "max_steps": max_steps, "shortlist": shortlist,
                "min_gain": min_gain, "iterations": iterations,
                "input_interpolation": input_interpolation}
    while True:  # the structures are chosen; refit them on the whole record, converged
        whole = _Problem(measurement, symbols, holdout=0.0, iterations=iterations,
                         substeps=substeps, batch=len(fits),
                         input_interpolation=input_interpolation)
        whole.pool_lhs, whole.pool_forcing = problem.pool_lhs, problem.pool_forcing
        refits = _fit(whole, chosen_mode, [fit.structure for fit in fits])
        result = Diagnosis(mode=chosen_mode, steps=steps, rankings=rankings, fits=fits,
                           refits=refits, frequencies=lines, n_train=problem.n_train,
                           measurement=measurement, symbols=symbols,
                           settings=settings | {"substeps": substeps})
        if chosen_mode != "simulation":
            return result
        check, _ = check_model(result.model(), measurement, tolerance=convergence_tolerance)
        if check.converged or not automatic or substeps >= MAX_SUBSTEPS:
            result.convergence = check.to_json()
            return result
        substeps = next_substeps(check)


def _fit(problem: _Problem, mode: str, structures: list[Structure]) -> list[Fit]:
    if mode == "equation_error":
        return problem.fit_equation_error(structures)
    return problem.fit_simulation(structures)


def _charge(candidate: Candidate, min_gain: float) -> float:
    """(1 − min_gain)^−p, p = the coefficients plus nonlinear parameters the effect adds:
    the factor on its held-out mean square for the parameters it spends."""
    terms = candidate.terms
    added = len(terms.state + terms.parametric + terms.forcing) + len(candidate.effect.parameters)
    return (1.0 - min_gain) ** -added


def _frozen(candidate: Candidate) -> Effect:
    """The candidate's effect with its parameters fixed (a one-point grid)."""
    parameters = dict(candidate.parameters)
    return dataclasses.replace(candidate.effect, grid=lambda context: [parameters])


def _step(candidate: Candidate, ranked: list[Candidate], before: Fit, after: Fit,
          mode: str) -> dict:
    s = after.structure
    added = candidate.terms.state + candidate.terms.parametric + candidate.terms.forcing
    values = dict(zip(s.state + s.parametric + s.forcing,
                      np.concatenate([after.state, after.parametric, after.forcing])))
    coefficients = {str(f): float(values[f]) for f in added}
    parameters = dict(candidate.parameters)
    if len(added) == 2 and candidate.effect.name == "mesh_stiffness_variation":
        a, b = coefficients[str(added[0])], coefficients[str(added[1])]
        coefficient = float(math.hypot(a, b))
        parameters["phase_rad"] = float(math.atan2(-b, a))
    else:
        coefficient = float(next(iter(coefficients.values())))
    rank = 1 + [c.effect.name for c in ranked].index(candidate.effect.name)
    sign = candidate.effect.sign
    step = {"effect": candidate.effect.name, "meaning": candidate.effect.meaning,
            "sign_as_meant": None if sign == 0 else bool(sign * coefficient > 0),
            "evidence": f"{candidate.evidence} (rank {rank} of {len(ranked)})",
            "explained": candidate.explained, "term": candidate.effect.term,
            "features": [str(f) for f in added], "coefficient": coefficient,
            "coefficients": coefficients, "parameters": parameters, "mode": mode}
    for when, fit in (("before", before), ("after", after)):
        for key in ("rms", "objective", "spectral_error", "rms_holdout"):
            step[f"{key}_{when}"] = fit.metrics.get(key)
    return step


# --- report ----------------------------------------------------------------------------
def write_report(diagnosis: Diagnosis, out) -> None:
    """Write report.json, report.md, model.json and three figures into folder ``out``:
    residual_time.png, residual_spectrum.png, measured_vs_simulated.png."""
    import json
    from pathlib import Path

    from ._report import write_bytes_atomic, write_text_atomic

    out = Path(out)
    report = diagnosis.to_json()
    write_text_atomic(out / "report.json", json.dumps(_finite(report), indent=2) + "\n")
    write_text_atomic(out / "report.md", report_markdown(diagnosis))
    diagnosis.model().save(out / "model.json")
    for name, figure in _figures(diagnosis).items():
        write_bytes_atomic(out / name, figure)


def _finite(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_finite(v) for v in value]
    return value


def _number(value) -> str:
    return "–" if value is None else f"{value:.4g}"


def report_markdown(diagnosis: Diagnosis) -> str:
    """The report as Markdown: the table effect → evidence → term → coefficient → errors."""
    d = diagnosis
    unit = "response units" if d.mode == "simulation" else "force units (equation error)"
    lines = [f"# Diagnosis of {d.symbols.response}", "",
             f"Mode: **{d.mode}** — {_CRITERION[d.mode]}.", "",
             f"Inputs between samples in the simulation: "
             f"{d.settings['input_interpolation']} interpolation.", "",
             f"Starting model: `{d.before.model(d.symbols, {}).sympy()}`", "",
             f"Final model: `{d.model().sympy()}`", "",
             f"Effects added: {', '.join(d.effects_added) or 'none'}", "",
             f"RMS in {unit}; f = f_time + f_freq (eqs. 7–9); spectral error = f_freq.", "",
             f"Whole record (the starting and the final structure refitted on all of it once "
             f"chosen): RMS {_number(d.before.metrics.get('rms'))} → "
             f"{_number(d.after.metrics.get('rms'))}, f {_number(d.before.metrics.get('objective'))}"
             f" → {_number(d.after.metrics.get('objective'))}, spectral error "
             f"{_number(d.before.metrics.get('spectral_error'))} → "
             f"{_number(d.after.metrics.get('spectral_error'))}.", "",
             *_convergence_lines(d),
             f"Steps: fitted on the first {d.n_train} of {d.measurement.n_samples} samples; "
             "the held-out rest decided.", "",
             "| effect | evidence | term | coefficient | RMS before | RMS after | f before | "
             "f after | spectral before | spectral after | held-out RMS before | after |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for s in d.steps:
        lines.append(f"| {s['effect']} | {s['evidence']} | {s['term']} | {s['coefficient']:.6g} "
                     f"| {_number(s['rms_before'])} | {_number(s['rms_after'])} | "
                     f"{_number(s['objective_before'])} | {_number(s['objective_after'])} | "
                     f"{_number(s['spectral_error_before'])} | {_number(s['spectral_error_after'])} "
                     f"| {_number(s['rms_holdout_before'])} | {_number(s['rms_holdout_after'])} |")
    for caution in sign_cautions(d):
        lines += ["", f"**Caution:** {caution}"]
    lines += ["", "## Evidence per round (best first)", "",
              "Simulation mode: held-out RMS with the effect refitted alone (/ predicted with "
              "its best partner); equation-error mode: share of the weak-form equation-error "
              "residual energy the effect explains.", ""]
    for i, ranking in enumerate(d.rankings, start=1):
        lines.append(f"{i}. " + ", ".join(map(_evidence_cell, ranking)))
    lines += ["", "Figures: residual_time.png, residual_spectrum.png, measured_vs_simulated.png.",
              ""]
    return "\n".join(lines)


def _convergence_lines(d: Diagnosis) -> list[str]:
    """The final model's integration check, for the report."""
    c = d.convergence
    if c is None:
        return []
    verdict = "converged" if c["converged"] else "**not converged**"
    return [f"Integration: RK4 with {c['substeps']} step(s) per sample. Reference solve "
            f"(adaptive diffrax Dopri8, rtol 1e-10): RMS {_number(c['rms_reference'])}; the "
            f"two responses differ by {c['ratio']:.2%} of it ({verdict}, tolerance "
            f"{c['tolerance']:.0%}).", ""]


def sign_cautions(diagnosis: Diagnosis) -> list[str]:
    """One sentence per added effect fitted with the opposite sign of its physical meaning
    (:attr:`gpjax._effects.Effect.sign`), e.g. a friction force along the velocity."""
    return [f"{s['effect']} was fitted with coefficient {s['coefficient']:.4g}, the opposite "
            "sign of the effect it names (for a loss: a force that feeds energy in); read it "
            "as an unmodelled force of that shape, not as that effect"
            for s in diagnosis.steps if s.get("sign_as_meant") is False]


def _evidence_cell(entry: dict) -> str:
    predicted = entry.get("predicted")
    if predicted is None:
        return f"{entry['effect']} {100 * entry['explained']:.1f} %"
    cell = f"{entry['effect']} {_number(predicted['holdout_rms_alone'])}"
    if predicted["partner"]:
        cell += f" / {_number(predicted['holdout_rms_with_partner'])} with {predicted['partner']}"
    return cell


def _figures(d: Diagnosis) -> dict[str, bytes]:
    import io

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def png(fig) -> bytes:
        buffer = io.BytesIO()
        fig.savefig(buffer, format="png", dpi=110)
        plt.close(fig)
        return buffer.getvalue()

    m, time = d.measurement, d.measurement.time
    out = {}
    fig, axes = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for label, fit in (("before", d.before), ("after", d.after)):
        if fit.simulated is not None:
            axes[0].plot(time, m.response - fit.simulated, lw=0.7, label=label)
    axes[0].axvline(time[d.n_train - 1], color="k", ls=":", label="held out in the selection →")
    axes[0].set_ylabel(f"{m.response_name} measured − simulated")
    axes[0].legend(loc="upper right")
    for label, fit in (("before", d.before), ("after", d.after)):
        axes[1].plot(time, fit.force, lw=0.7, label=label)
    axes[1].set_ylabel("equation-error residual\n(generalised force)")
    axes[1].set_xlabel(f"{m.time_name} [s]")
    axes[1].legend(loc="upper right")
    out["residual_time.png"] = png(fig)

    fig, ax = plt.subplots(figsize=(9, 4))
    frequency = np.fft.rfftfreq(m.n_samples, m.dt)
    for label, fit in (("before", d.before), ("after", d.after)):
        signal = (m.response - fit.simulated) if fit.simulated is not None else fit.force
        ax.semilogy(frequency[1:], amplitude_spectrum(signal)[1:] + 1e-300, lw=0.7, label=label)
    for f in d.frequencies:
        ax.axvline(f, color="grey", ls=":", lw=0.8)
    ax.set_xlabel("frequency [Hz] (dotted: candidate frequencies)")
    ax.set_ylabel("residual amplitude")
    ax.legend()
    out["residual_spectrum.png"] = png(fig)

    fig, ax = plt.subplots(figsize=(9, 4))
    ax.plot(time, m.response, "k", lw=0.8, label="measured")
    for label, fit in (("before", d.before), ("after", d.after)):
        if fit.simulated is not None:
            ax.plot(time, fit.simulated, lw=0.8, ls="--", label=f"simulated {label}")
    ax.set_xlabel(f"{m.time_name} [s]")
    ax.set_ylabel(m.response_name)
    ax.legend()
    out["measured_vs_simulated.png"] = png(fig)
    return out

