"""Genetic programming over systems: one Newton–Euler equation per measured coordinate.

A candidate is a tuple of D trees, tree i read as equation i (``tree = 0``). Tree i's
terminals are its own coordinate x_i, x_i', x_i'', the relative coordinates d_ij = x_i − x_j
and d_ij' (j ≠ i; the couplings of eqs. 21–22), the inputs, t and random constants; the
function set is eq. 10's (add, sub, mul). The structure rules hold per equation: x_i'' only
as (non-zero constant)·x_i'' (constant inertia), every other term a power of one state
variable (x_i, x_i', d_ij or d_ij' alone: eqs. 5–6 per argument, up to ``max_degree``) or a
function of time and inputs; anything else makes the candidate invalid.

The initial population is half ramped half-and-half trees (the paper's) and half random
sums of valid terms (1–4 state features, inputs): with several variables per equation few
random trees are valid (a product of two variables is a cross term).

Constants are GP's structure's, set by least squares: each equation's by weak-form equation
error on its own (:func:`gpjax._system_fit.equation_constants`, normalised by its first input,
else by its mass), the initial states by the evaluator's Gauss–Newton step. The best
``refine_top`` new systems of a generation are refined by Levenberg–Marquardt on all
coordinates together and keep the refined constants. Fitness is eqs. 7–9 summed over the
coordinates, each normalised by its scale (:class:`gpjax.engine.PopulationEvaluator`).

Operators. Crossover, mutation and perturbation (the paper's, probabilities 0.63 / 0.27 /
0.09, reproduction 0.01) act within one equation at a time: equation i of the child comes
from equation i of its parents, since equation i's terminals (x_i, d_ij) mean something
only for coordinate i. A crossover swaps a whole equation instead with probability
``p_swap``: the objective is a sum over coordinates and equation i mostly decides how well
coordinate i fits, so a parent's good equation is a building block that subtree crossover
would mostly break. Each generation the ``local_search`` best systems also offer their
one-term changes (a power of one variable or an input added to one equation, or a term
dropped), at most ``local_steps`` steps each.

The reported system is chosen as one coordinate's is (:mod:`gpjax._select`), by the
held-out predictive test at level ``selection_alpha``: from the best system found, a
system one term smaller replaces it unless the larger one predicts the held-out windows of
the weak-form equation error significantly better (blocked cross-validation,
:func:`gpjax._system_fit.held_out`; Diebold–Mariano by batch means), the
removals tried in the order of their held-out mean square, until none qualifies; a power
swap (a bank term for its polynomial stand-in near 0), a bank swap (the reverse, where it
removes a term) and a mirror swap (one end of a coupling given the law of its other end:
Newton's third law) are tried too, the first two decided by the simulated guard below
(:func:`gpjax._system_select.simplest`: the held-out equation error is biased between a
function and its Taylor stand-in). So an input in an equation that the data do not need,
a coupling term, or a sin(x1 − x2) standing in for a linear spring, goes unless the
held-out windows demonstrate it. Where the held-out test cannot tell the two apart either way (the
equation error has little power where the states' smoothing blurs a term's effect: a
gear's mesh damping), the removal must also not simulate significantly worse
(:meth:`SystemScorer.simulates_better`: one coordinate's guard,
:func:`gpjax._select.simulates_better`, on the refined systems' simulated residuals).
That guard is in-sample and nested, so it leans towards the larger system, and a term that
fits the measured input's noise as it rings through the dynamics passes it; so a removal
that predicts the held-out windows significantly better is taken without it, and the Wald
pruning below removes what the converged fit does not demonstrate. The chosen system is
refitted at converged integration (:func:`gpjax._system_fit.fit_system`); where the
reference solver cannot integrate that fit, its one-term removal that it integrates best
replaces it (:func:`gpjax._system_final.integrable`). A term whose
constant that fit cannot tell from 0 (a Wald test with the interval's standard error, at
``selection_alpha`` over the number of features its equation chose from: Bonferroni, the
test is post-selection) is dropped and the rest refitted, one at a time, least
significant first (:func:`gpjax._system_final.insignificant_removals`). The Wald test reads the residual as
noise, so it runs only on a fit whose every coordinate is at its noise floor
(:func:`gpjax._system_final.flagged`, the report's flag): a model that misses physics
leaves signal in its residual, which the sandwich counts as noise, and its wide intervals
do not show a term to be spurious. A removal whose refit raises a residual far above its
noise is undone and the next term is tried (two inputs whose records are nearly
proportional have no interval, p = 1 both, and only one of them is needed). No in-sample test vetoes a removal
here: a likelihood ratio with a Newey–West sample count (used before, here and in the
guard) found a term needed whose constant was −0.12 ± 0.23 (chain2 seed 4, p = 5e-9), the
guard's test p = 0.012.

With Newton's third law (``GPConfig.third_law``, :mod:`gpjax._system_couplings`) the
relative coordinates d_ij are terminals of equation min(i, j) only; each coupling term
found there also acts on coordinate j with the opposite sign, its constant shared (least
squares over all equations at once, tied Levenberg–Marquardt steps), and the multi-term
local moves are scored by the weak-form residual of all equations together.
Settings: one :class:`gpjax.GPConfig`, the same object and defaults as one coordinate's
(``local_steps``, ``p_swap`` and ``third_law`` only act on several coordinates). The fields
that shape one coordinate's grammar (:data:`gpjax._config.ONE_COORDINATE`) must keep their
defaults.
"""


from __future__ import annotations

import dataclasses
import itertools
import math
import time

import numpy as np
import sympy as sp

from . import _progress, _trees
from ._canonical import Symbols
from ._config import GPConfig, check_system_config
from ._convergence import search_substeps
from ._data import Measurement
from ._evaluator import PENALTY, PopulationEvaluator
from ._evolve import GenerationLoop, RunState, Standing, distinct_first, tournament
from ._features import SIGN_WIDTH
from ._memory import check_fit_memory
from ._objective import stop_objective
from ._operators import crossover, initial_population, mutation, perturbation
from ._sign_width import NARROWING, next_narrowing, sharpened, width_check
from ._system_bank import kinds_for, sign_scales
from ._system_final import reported
from ._system_fit import SystemFit, fit_system
from ._weak_form import smoothed_weak_form
from ._system_grammar import Equations
from ._system_scorer import SystemScorer, as_trees, key_text
from ._system_select import removals, simplest


@dataclasses.dataclass(frozen=True)
class SearchResult:
    """The final fit of the reported system; per generation (0 first) its
    :class:`gpjax._evolve.GenerationStats` as a dict; its smoothed signs' width check
    (:meth:`gpjax._sign_width.WidthCheck.to_json`, ``None`` without a sign) and why its
    narrowing ended unconverged (``stopped``, :func:`gpjax._sign_width.why_stopped`); and
    the seconds of the stages (``selection_s``, ``convergence_s``: the final fit at
    converged integration and its uncertainty)."""

    fit: SystemFit
    history: list[dict]
    timings: dict
    sign_width: dict | None = None
    stopped: str | None = None

    @property
    def model(self):
        return self.fit.model


class SystemEvolution(GenerationLoop):
    """GP over the systems of one measurement (module docstring), run by
    :class:`gpjax._evolve.GenerationLoop` (generations, checkpoints, resume and islands as
    one coordinate's): an individual is a D-tuple of trees, one per equation.

    Raises:
        ConfigError: a :data:`gpjax._config.ONE_COORDINATE` field changed.
    """

    def __init__(self, measurement: Measurement, config: GPConfig):
        check_system_config(config)
        self.measurement, self.config = measurement, config
        self.stop_objective = stop_objective(measurement, config)
        weak = smoothed_weak_form(measurement)
        kinds = kinds_for(config.functions)
        scales = (sign_scales(measurement.response_names, weak.rms) if "sign" in kinds
                  else None)
        self.equations = Equations(measurement, config.max_degree, config.third_law,
                                   config.functions, scales, config.input_forcing)
        self.grammars = [self.equations.grammar(i, config)
                         for i in range(len(self.equations.names))]
        #: RK4 steps per sample of the search, as one coordinate's (``GPConfig.substeps``)
        self.substeps = search_substeps(measurement, config.substeps)
        check_fit_memory(n_samples=measurement.n_samples, substeps=self.substeps,
                         population=config.population, coordinates=measurement.n_coordinates)
        evaluator = PopulationEvaluator(
            measurement, Symbols(self.equations.names[0], measurement.time_name,
                                 measurement.input_names), substeps=self.substeps,
            max_degree=config.max_degree, fit_initial_conditions=True, n_bins=config.n_bins,
            w_time=config.w_time, w_freq=config.w_freq,
            input_interpolation=config.input_interpolation, batch=config.population,
            kinds=kinds, sign_scales=scales)
        self.scorer = SystemScorer(weak, self.equations, evaluator, batch=config.refine_top,
                                   iterations=config.refine_iterations)
        self.fresh_columns = self.forcing_columns()

    # --- the generations ------------------------------------------------------------
    def _first_message(self) -> str:
        return (f"generation 0: compiling (or loading) the evaluator of "
                f"{len(self.grammars)} equations, scoring {self.config.population} systems")

    def _first_population(self, rng: np.random.Generator) -> list[tuple]:
        """Half ramped half-and-half trees, half random sums of valid terms (module
        docstring)."""
        count, config = len(self.grammars), self.config
        trees = list(zip(*(initial_population(g, rng, config.population, config.init_depth)
                           for g in self.grammars)))
        for k in range(0, len(trees), 2):
            trees[k] = as_trees(tuple(_random_terms(i, self.equations, rng)
                                      for i in range(count)), self.equations)
        return trees

    def _child(self, parents, standing: Standing, rng: np.random.Generator) -> tuple:
        """One equation of a parent changed: crossover with another parent's same equation
        (or, with probability ``p_swap``, that equation swapped whole), mutation or
        perturbation (module docstring)."""
        config, fitness = self.config, standing.objectives
        parent = list(parents[tournament(fitness, rng, config.tournament)])
        i = int(rng.integers(len(parent)))
        draw = rng.random()
        if draw < config.p_crossover:
            other = parents[tournament(fitness, rng, config.tournament)]
            if rng.random() < config.p_swap:
                parent[i] = other[i]
            else:
                parent[i] = crossover(parent[i], other[i], self.grammars[i], rng)
        elif draw < config.p_crossover + config.p_mutation:
            parent[i] = mutation(parent[i], self.grammars[i], rng)
        elif draw < config.p_crossover + config.p_mutation + config.p_perturbation:
            parent[i] = perturbation(parent[i], self.grammars[i], rng)
        return tuple(parent)

    def _next_population(self, parents, offspring, standing, rng) -> list[tuple]:
        """The local search's systems beside the offspring, the best new ones refined,
        the best ``population`` of all kept (distinct structures first)."""
        scorer, fitness = self.scorer, standing.objectives
        offspring = offspring + _local_search(parents, fitness, self.equations, scorer,
                                              self.config)
        pool = parents + offspring
        scorer.refine_best(pool, np.concatenate([fitness, scorer(offspring)]),
                           self.config.refine_top)
        scores = scorer(pool)
        order = np.argsort(scores, kind="stable")
        keys = [scorer.key(s) for s in pool]
        return [pool[i] for i in distinct_first(order, keys, self.config.population)]

    def _standing(self, population: list[tuple]) -> Standing:
        fitness = self.scorer(population)
        keys = [self.scorer.key(s) for s in population]
        order = [int(i) for i in np.argsort(fitness, kind="stable")]
        best = keys[order[0]]
        return Standing(objectives=fitness, usable=fitness < PENALTY, keys=keys, order=order,
                        best_key=key_text(best) if best is not None else "")

    # --- the caches as JSON -----------------------------------------------------------------
    @property
    def _evaluator(self):
        return self.scorer.evaluator

    def _variable_names(self) -> set[str]:
        return {*self.equations.names, *(f"{n}_dot" for n in self.equations.names),
                self.measurement.time_name, *self.measurement.input_names}

    @staticmethod
    def _individual_json(system: tuple) -> list:
        return [_trees.to_json(t) for t in system]

    @staticmethod
    def _individual(item) -> tuple:
        return tuple(_trees.from_json(t) for t in item)

    def _records_json(self) -> list[dict]:
        return self.scorer.records()

    def _load_records(self, items: list[dict], names: set[str]) -> None:
        self.scorer.load(items)

    def _record_json(self, system: tuple) -> dict:
        return self.scorer.record(self.scorer.key(system))

    def reset(self) -> None:
        """Forget every scored structure (a reused island engine)."""
        self.scorer.clear()

    # --- the reported system -------------------------------------------------------------
    def finish(self, state: RunState) -> SearchResult:
        """The reported system of a finished search: the population's best, simplified by
        the held-out test, fitted at converged integration, terms its fit cannot tell from
        0 dropped (module docstring).

        Raises:
            ValueError: the population holds no valid system.
        """
        config, scorer, measurement = self.config, self.scorer, self.measurement
        fitness = scorer(state.population)
        best = scorer.key(state.population[int(np.argmin(fitness))])
        if best is None:
            raise ValueError("no valid system was found; widen the search")
        selecting = time.perf_counter()
        _progress.stage("final model selection: one-term removals by the held-out test at "
                        f"level {config.selection_alpha}")
        best = simplest(best, scorer, config.selection_alpha, config.convergence_tolerance)
        fitting = time.perf_counter()
        settings = dict(max_degree=config.max_degree, third_law=config.third_law,
                        input_interpolation=config.input_interpolation,
                        substeps=None if config.substeps == "auto" else config.substeps,
                        tolerance=config.convergence_tolerance,
                        iterations=config.refine_iterations,
                        kinds=kinds_for(config.functions))
        best, fit = reported(best, scorer, measurement, settings, config.selection_alpha)
        fit, width, stopped = _narrowed(fit, scorer.normalised(best), measurement, settings)
        return SearchResult(fit, [dataclasses.asdict(h) for h in state.history], {
            "selection_s": fitting - selecting,
            "convergence_s": time.perf_counter() - fitting}, width, stopped)


def _narrowed(fit: SystemFit, structure, measurement: Measurement, settings: dict):
    """(fit, its width check's JSON, why the narrowing stopped): where the reported system
    depends on its smoothed signs' width, refitted with the signs narrower from the
    constants of the last fit, by one coordinate's rule and loop
    (:func:`gpjax._sign_width.next_narrowing`: the jump the check's measured rate
    projects, at the steps the narrower signs need). It stops,
    keeping the last fit, where the check converges or cannot be made (the reference
    solver fails on the narrower signs: a ratio of inf), where ``next_narrowing`` says why
    (returned; None otherwise) or where the narrower refit diverges."""
    tolerance, width, narrowings, stopped = settings["tolerance"], SIGN_WIDTH, 0, None
    check = _width_check(fit, measurement, tolerance, width)
    while check is not None and not check.converged and math.isfinite(check.ratio):
        step = next_narrowing(check, narrowings,
                              lambda factor: sharpened(fit.model, factor), measurement,
                              tolerance=tolerance)
        if isinstance(step, str):
            stopped = step
            break
        jump, steps = step
        _progress.stage(f"refitting the system with its smoothed signs {NARROWING ** jump}× "
                        f"narrower (ε = {width / NARROWING ** jump:.3g}·RMS z): its constants "
                        "carried the smoothing")
        start = sharpened(fit.model, NARROWING ** jump).system
        structure = tuple((tuple(c.state), forcing) for c, (_, forcing) in zip(start, structure))
        try:
            fit = fit_system(measurement, structure, start=start, first_substeps=steps,
                             carried=True, **settings)
        except ValueError:  # the narrower refit diverged: the last fit and check stand
            break
        width, narrowings = width / NARROWING ** jump, narrowings + jump
        check = _width_check(fit, measurement, tolerance, width)
    return fit, None if check is None else check.to_json(), stopped


def _width_check(fit: SystemFit, measurement: Measurement, tolerance: float, width: float):
    """:func:`gpjax._sign_width.width_check` of a fitted system at sign ``width`` (ε / RMS
    z): its reference response on the convergence check's samples (as that check solved
    it) against its signs' narrower ones, over that check's RMS residual; ``None`` without
    a sign."""
    model = fit.model
    return width_check(model, lambda factor: sharpened(model, factor), measurement,
                       fit.reference, fit.checks[-1].rms_reference, fraction=width,
                       tolerance=tolerance)


def _random_terms(i: int, equations: Equations, rng) -> tuple:
    """A random valid structure of equation ``i``: 1–4 state features, each input with
    probability 1/2, a constant force with probability 1/5."""
    state_basis, _ = equations.basis(i)
    picked = rng.choice(len(state_basis), size=int(rng.integers(1, 5)), replace=False)
    state = tuple(sorted((state_basis[k] for k in picked), key=str))
    forcing = [u for u in equations.inputs if rng.random() < 0.5]
    forcing += [sp.Integer(1)] if rng.random() < 0.2 else []
    return state, tuple(sorted(forcing, key=str))


def _local_search(trees, fitness, equations: Equations, scorer: SystemScorer,
                  config: GPConfig) -> list:
    """Descent by one-term changes from the ``local_search`` best distinct systems, at
    most ``local_steps`` steps each; every system it moves to, as trees."""
    out, seen = [], set()
    for index in np.argsort(fitness):
        key = scorer.key(trees[index])
        if len(seen) == config.local_search or fitness[index] >= PENALTY:
            break
        if key is None or key in seen:
            continue
        seen.add(key)
        current, value = key, fitness[index]
        for _ in range(config.local_steps):
            changed = list(dict.fromkeys([*_neighbours(current, equations),
                                          *_equation_error_steps(current, scorer)]))
            candidates = [as_trees(c, equations) for c in changed]
            scores = scorer(candidates)
            best = int(np.argmin(scores))
            if not scores[best] < value * (1 - 1e-3):
                break
            current, value = changed[best], scores[best]
            out.append(candidates[best])
    return out


def _neighbours(key, equations: Equations):
    for i, (state, forcing) in enumerate(key):
        state_basis, forcing_basis = equations.basis(i)
        for feature in state_basis:
            if feature not in state:
                part = (tuple(sorted(state + (feature,), key=str)), forcing)
                yield key[:i] + (part,) + key[i + 1:]
        for feature in forcing_basis:
            if feature not in forcing:
                part = (state, tuple(sorted(forcing + (feature,), key=str)))
                yield key[:i] + (part,) + key[i + 1:]
        yield from removals(key, i)


def _equation_error_steps(key, scorer: SystemScorer, steps: int = 4, longest: int = 8):
    """Multi-term moves by weak-form equation error, which is separable per equation and
    never gets worse with a term more: per equation, forward selection from the equation as
    it is, and the best selection of each size from nothing (:func:`_selections`), every
    equation along the way (the others kept); and jointly, every combination of the
    equations' selections from nothing (up to ``longest`` terms) that stop where the
    residual is within 5 % of the longest one's, one term less or one more (coupled
    equations are often right only together: a coupling term pays in output error once
    both ends have it)."""
    joint = []
    for i, (state, forcing) in enumerate(key):
        for part in _forward(scorer, key, i, list(state), list(forcing), steps):
            yield key[:i] + (part,) + key[i + 1:]
        fresh = _selections(scorer, key, i, longest)
        for part in fresh[:steps]:
            yield key[:i] + (part,) + key[i + 1:]
        residuals = [scorer.residual(key, i, part) for part in fresh]
        stop = next(k for k, r in enumerate(residuals) if r <= 1.05 * residuals[-1])
        joint.append(fresh[max(0, stop - 1):stop + 2])
    yield from itertools.product(*joint)


def _selections(scorer: SystemScorer, key, i: int, longest: int) -> list:
    """Equation ``i``'s feature sets of 1 … ``longest`` features, each the one of least
    weak-form residual that forward selection from nothing (:func:`_forward`) and
    backward elimination from the whole basis (:func:`_backward`) reach at that size.
    Both ways, since each misses what the other finds: forward selection adds one feature
    at a time and so misses features that explain the equation only together — a mass's
    own x_i and its couplings x_i − x_j to both neighbours, nearly collinear, each little
    use alone (a 3-mass chain with a light middle mass: its forward path took the input
    and never reached the truth); backward elimination starts from them all."""
    known = (i, longest, key if scorer.equations.third_law else None)
    if known not in scorer.selections:  # without the third law, one path per equation
        forward = list(_forward(scorer, key, i, [], [], longest))
        backward = _backward(scorer, key, i, longest)
        scorer.selections[known] = [min(pair, key=lambda part: scorer.residual(key, i, part))
                                    for pair in zip(forward, backward)]
    return scorer.selections[known]


def _backward(scorer: SystemScorer, key, i: int, longest: int) -> list:
    """Equation ``i``'s whole basis thinned one feature at a time by the least weak-form
    residual; the sets of 1 … ``longest`` features, the smallest first."""
    state, forcing = (list(b) for b in scorer.equations.basis(i))
    path = []
    while True:
        if len(state) + len(forcing) <= longest:
            path.append((tuple(sorted(state, key=str)), tuple(sorted(forcing, key=str))))
        if len(state) + len(forcing) == 1:
            return path[::-1]
        options = [([g for g in state if g != f], forcing) for f in state]
        options += [(state, [g for g in forcing if g != f]) for f in forcing]
        state, forcing = min(options, key=lambda o: scorer.residual(key, i, o))


def _forward(scorer: SystemScorer, key, i: int, state: list, forcing: list, steps: int):
    """Equation ``i`` of ``key`` grown one feature at a time by the least weak-form
    residual (:meth:`SystemScorer.residual`)."""
    state_basis, forcing_basis = scorer.equations.basis(i)
    for _ in range(steps):
        options = [([*state, f], forcing) for f in state_basis if f not in state]
        options += [(state, [*forcing, f]) for f in forcing_basis if f not in forcing]
        if not options:
            return
        state, forcing = min(options, key=lambda o: scorer.residual(key, i, o))
        yield tuple(sorted(state, key=str)), tuple(sorted(forcing, key=str))
