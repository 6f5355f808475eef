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
error on its own (:class:`gpjax._system_fit.SystemWeakForm`, normalised by its first input,
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
:meth:`gpjax._system_fit.SystemWeakForm.held_out`; Diebold–Mariano by batch means), the
removals tried in the order of their held-out mean square, until none qualifies. So an input
in an equation that the data do not need, or a coupling term, goes unless the held-out
windows demonstrate it. Where the held-out test cannot tell the two apart either way (the
equation error has little power where the states' smoothing blurs a term's effect: a
gear's mesh damping), the removal must also not simulate significantly worse
(:meth:`_Scorer.simulates_better`: a likelihood-ratio test on the refined systems' simulated
residuals). That guard is in-sample, and a term that fits the measured input's noise as it
rings through the dynamics passes it; so a removal that predicts the held-out windows
significantly better is taken without it. The chosen system is refitted at converged
integration (:func:`gpjax._system_fit.fit_system`), and a term whose constant that fit
cannot tell from 0 (a Wald test at ``selection_alpha`` with the interval's standard error)
is dropped and the rest refitted, one at a time (:func:`without_insignificant`), unless
the refit simulates significantly worse (the likelihood-ratio test above, on the reference
solves): the Wald interval of a model that misses physics is wide, and does not show a
term to be spurious.

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
import time

import numpy as np
import sympy as sp

from . import _progress
from ._canonical import Symbols
from ._coefficients import Coefficients, from_system_population, to_system_population
from ._config import GPConfig, check_system_config
from ._data import Measurement
from ._diagnose_acceptance import predictive_test
from ._evaluator import PopulationEvaluator
from ._operators import crossover, initial_population, mutation, perturbation
from ._refine import Refiner
from ._system_bank import kinds_for, sign_scales
from ._system_couplings import (couple, coupled_least_squares, coupled_residual,
                                fixed_columns, normalisation, tie_columns)
from ._system_final import better_fit_p, scaled_residual, width_check, without_insignificant
from ._system_fit import SystemFit, SystemWeakForm, fit_system
from ._system_grammar import Equations

PENALTY = 1e12
#: Systems per compiled refinement call.
REFINE_BATCH = 4


@dataclasses.dataclass(frozen=True)
class SearchResult:
    """The final fit of the reported system; per generation (0 first) its number, best
    objective and seconds; its smoothed signs' width check
    (:func:`gpjax._system_final.width_check`, ``None`` without a sign); and the seconds of the stages (``search_s``, ``selection_s``,
    ``convergence_s``: the final fit at converged integration and its uncertainty) and the
    seconds and count of the programs compiled or loaded (``compile_s``, ``compiles``)."""

    fit: SystemFit
    history: list[dict]
    timings: dict
    sign_width: dict | None = None

    @property
    def model(self):
        return self.fit.model


def search_system(measurement: Measurement, *, config: GPConfig = GPConfig(),
                  seed: int = 0) -> SearchResult:
    """Identify one equation per coordinate of ``measurement`` by GP (module docstring),
    stopping after ``config.generations`` or once the best objective is at most its
    ``epsilon``.

    Raises:
        ConfigError: a :data:`gpjax._config.ONE_COORDINATE` field changed.
        ValueError: no valid system was found.
    """
    check_system_config(config)
    rng = np.random.default_rng(seed)
    weak = SystemWeakForm(measurement)
    kinds = kinds_for(config.functions)
    scales = (sign_scales(measurement.response_names, weak.rms) if "sign" in kinds
              else None)
    equations = Equations(measurement, config.max_degree, config.third_law,
                           config.functions, scales)
    count = len(equations.names)
    grammars = [equations.grammar(i, config) for i in range(count)]
    evaluator = PopulationEvaluator(
        measurement, Symbols(equations.names[0], measurement.time_name,
                             measurement.input_names),
        max_degree=config.max_degree, fit_initial_conditions=True, n_bins=config.n_bins,
        w_time=config.w_time, w_freq=config.w_freq,
        input_interpolation=config.input_interpolation, batch=config.population,
        kinds=kinds, sign_scales=scales)
    scorer = _Scorer(weak, equations, evaluator)
    trees = list(zip(*(initial_population(g, rng, config.population, config.init_depth)
                       for g in grammars)))
    for k in range(0, len(trees), 2):  # half of them sums of valid terms (see the docstring)
        trees[k] = _as_trees(tuple(_random_terms(i, equations, rng) for i in range(count)),
                             equations)
    _progress.stage(f"generation 0: compiling (or loading) the evaluator of {count} "
                    f"equations, scoring {config.population} systems")
    started = began = time.perf_counter()
    fitness = scorer(trees)
    history = [{"generation": 0, "best_objective": float(fitness.min()),
                "seconds": time.perf_counter() - began}]
    _progress.generation(0, config.generations, history[-1]["best_objective"],
                         history[-1]["seconds"])
    for generation in range(1, config.generations + 1):
        began = time.perf_counter()
        offspring = [_offspring(trees, fitness, grammars, rng, config)
                     for _ in range(config.population)]
        offspring += _local_search(trees, fitness, equations, scorer, config)
        pool = trees + offspring
        scores = np.concatenate([fitness, scorer(offspring)])
        scorer.refine_best(pool, scores, config.refine_top)
        scores = scorer(pool)
        trees, fitness = _survivors(pool, scores, scorer, config.population)
        history.append({"generation": generation, "best_objective": float(fitness.min()),
                        "seconds": time.perf_counter() - began})
        _progress.generation(generation, config.generations, history[-1]["best_objective"],
                             history[-1]["seconds"])
        if history[-1]["best_objective"] <= config.epsilon:
            break
    best = scorer.key(trees[int(np.argmin(fitness))])
    if best is None:
        raise ValueError("no valid system was found; widen the search")
    selecting = time.perf_counter()
    _progress.stage("final model selection: one-term removals by the held-out test at "
                    f"level {config.selection_alpha}")
    best = _simplest(best, scorer, config.selection_alpha, config.convergence_tolerance)
    start = scorer.coefficients(best)
    fitting = time.perf_counter()
    fit = fit_system(measurement, scorer.normalised(best), max_degree=config.max_degree,
                     input_interpolation=config.input_interpolation, start=start,
                     tolerance=config.convergence_tolerance, third_law=config.third_law)
    residual = None  # the current fit's scaled residual, solved once per fit
    while (smaller := without_insignificant(best, fit, config.selection_alpha)) is not None:
        _progress.stage(f"dropping a term its converged fit does not demonstrate (Wald test "
                        f"at level {config.selection_alpha}), then fitting again")
        trial = fit_system(measurement, scorer.normalised(smaller), max_degree=config.max_degree,
                           input_interpolation=config.input_interpolation,
                           start=scorer.coefficients(smaller), first_substeps=fit.model.substeps,
                           tolerance=config.convergence_tolerance, third_law=config.third_law)
        if residual is None:
            residual = scaled_residual(fit, measurement)
        trial_residual = scaled_residual(trial, measurement)
        if better_fit_p(trial_residual, residual, 1,
                        config.convergence_tolerance) < config.selection_alpha:
            break  # the refit without it simulates significantly worse: the term stays
        best, fit, residual = smaller, trial, trial_residual
    width = width_check(fit, measurement, config.convergence_tolerance)
    programs = [scorer.evaluator, *scorer.refiners()]
    return SearchResult(fit, history, {
        "search_s": selecting - started, "selection_s": fitting - selecting,
        "convergence_s": time.perf_counter() - fitting,
        "compile_s": fit.compile_s + sum(p.compile_seconds for p in programs),
        "compiles": fit.compiles + sum(p.compile_count for p in programs)}, width)


def _random_terms(i: int, equations: Equations, rng) -> tuple:
    """A random valid structure of equation ``i``: 1–4 state features, each input with
    probability 1/2, a constant force with probability 1/5."""
    state_basis, _ = equations.basis(i)
    picked = rng.choice(len(state_basis), size=int(rng.integers(1, 5)), replace=False)
    state = tuple(sorted((state_basis[k] for k in picked), key=str))
    forcing = [u for u in equations.inputs if rng.random() < 0.5]
    forcing += [sp.Integer(1)] if rng.random() < 0.2 else []
    return state, tuple(sorted(forcing, key=str))




class _Scorer:
    """Objective of systems by structure, with least-squares and refined constants cached."""

    def __init__(self, weak: SystemWeakForm, equations: Equations,
                 evaluator: PopulationEvaluator):
        self.equations, self.evaluator, self.weak = equations, evaluator, weak
        self.objective: dict[tuple, float] = {}
        self.refined: dict[tuple, list[Coefficients]] = {}
        self._refiners: dict[int, Refiner] = {}
        self._residuals: dict[tuple, float] = {}

    def key(self, system) -> tuple | None:
        parts = [self.equations.structure(i, tree) for i, tree in enumerate(system)]
        return None if any(p is None for p in parts) else tuple(parts)

    def normalised(self, key):
        """``key`` as a :data:`gpjax._system_fit.Structure`: the forcing held at 1 marked
        (:func:`gpjax._system_couplings.normalisation`)."""
        ties = self.coupled(key)[1]
        held = normalisation(key, ties, self.equations.inputs)
        return tuple((state, {f: 1.0 if f == h else None for f in forcing})
                     for (state, forcing), h in zip(key, held))

    def coupled(self, key):
        """(structure with every coupling's mirror, ties): with the third law
        (:func:`gpjax._system_couplings.couple`), else (``key``, ())."""
        if not self.equations.third_law:
            return key, ()
        return couple(key, self.equations.names)

    def residual(self, key, i: int, part) -> float:
        """Weak-form equation error of ``key`` with equation ``i`` as ``part`` (state,
        forcing features): that equation's own (:meth:`SystemWeakForm.residual`), or with
        the third law that of all equations together
        (:func:`gpjax._system_couplings.coupled_residual`)."""
        if not self.equations.third_law:
            return self.weak.residual(i, *part)
        changed = key[:i] + (tuple(tuple(p) for p in part),) + key[i + 1:]
        if changed not in self._residuals:
            self._residuals[changed] = coupled_residual(self.weak, changed,
                                                        self.equations.names)
        return self._residuals[changed]

    def held_out(self, key) -> np.ndarray:
        """Held-out weak-form residual of ``key`` with every coupling's mirror
        (:meth:`gpjax._system_fit.SystemWeakForm.held_out`)."""
        return self.weak.held_out(self.coupled(key)[0])

    def simulates_better(self, current, simpler, alpha: float, resolution: float) -> bool:
        """Whether ``current``'s simulated responses fit the measured ones significantly
        better than ``simpler``'s at level ``alpha``, both refined: a likelihood-ratio test,
        χ² with one degree of freedom per dropped term, each coordinate's Gaussian
        log-likelihood counted with its residual's effective sample size
        n·γ₀/LRV (Newey–West, :func:`gpjax._diagnose_acceptance.long_run_variance`; a
        simulated residual is strongly autocorrelated). Not the held-out test's
        Diebold–Mariano: the two systems are nested and fitted to the same samples, so
        their loss differential is positive by construction and that test's null does not
        hold (a 2-mass chain kept two quartic terms that improved its objective by 0.14 %).
        The guard exists because the equation error is blind where the states' smoothing
        blurs a weak term's effect: a gear's mesh damping at 5 % of critical, whose removal
        moves the fitted inertia by 80 %. A worsening of the simulated mean square by less
        than ``resolution`` (the run's ``convergence_tolerance``: the accuracy to which the
        fixed-step objective is claimed, :mod:`gpjax._convergence`) is not evidence
        either."""
        trees = [_as_trees(k, self.equations) for k in (simpler, current)]
        self.refine_best(trees, self(trees), 2)
        responses, _ = self.evaluator.simulate(to_system_population(
            [self.coefficients(k) for k in (simpler, current)], self.evaluator))
        measured = self.evaluator.measurement.responses.T
        residual = (responses - measured) / measured.std(axis=1, keepdims=True)  # (2, D, N)
        dropped = sum(len(a) + len(b) for a, b in current) - sum(
            len(a) + len(b) for a, b in simpler)
        return better_fit_p(residual[0], residual[1], dropped, resolution) < alpha

    def coefficients(self, key) -> list[Coefficients]:
        if key in self.refined:
            return self.refined[key]
        structure, ties = self.coupled(self.normalised(key))
        if ties:
            return coupled_least_squares(self.weak, structure, ties)
        return [self.weak.equation(i, state, forcing)
                for i, (state, forcing) in enumerate(structure)]

    def __call__(self, systems) -> np.ndarray:
        keys = [self.key(s) for s in systems]
        new = list({k for k in keys if k is not None and k not in self.objective})
        if new:
            starts = [self.coefficients(k) for k in new]
            usable = [all(np.isfinite(c.mass) and all(np.isfinite(list(c.state.values())))
                          for c in start) for start in starts]
            chosen = [k for k, ok in zip(new, usable) if ok]
            for k, ok in zip(new, usable):
                if not ok:
                    self.objective[k] = PENALTY
            if chosen:
                population = to_system_population([self.coefficients(k) for k in chosen],
                                                  self.evaluator)
                scores = self.evaluator.score(population)
                for k, value in zip(chosen, scores.objective):
                    self.objective[k] = float(value)
        return np.array([PENALTY if k is None else self.objective[k] for k in keys])

    def refiners(self) -> list:
        """The refiners compiled so far (one per Jacobian width)."""
        return list(self._refiners.values())

    def refine_best(self, systems, scores, top: int) -> None:
        """Levenberg–Marquardt on the best ``top`` distinct systems not refined yet."""
        chosen = []
        for index in np.argsort(scores):
            key = self.key(systems[index])
            if scores[index] >= PENALTY or len(chosen) == top:
                break
            if key is not None and key not in self.refined and key not in chosen:
                chosen.append(key)
        if not chosen:
            return
        starts = [self.coefficients(k) for k in chosen]
        population = to_system_population(starts, self.evaluator)
        coupled = [self.coupled(self.normalised(k)) for k in chosen]
        fixed = np.array([fixed_columns(structure, ties, self.evaluator.forcing_index)
                          for structure, ties in coupled])
        free = max(sum(1 + len(s) + len(f) + 2 for s, f in structure)
                   for structure, _ in coupled)
        width = -(-free // 8) * 8  # few distinct Jacobian widths: few compiles
        if width not in self._refiners:
            self._refiners[width] = Refiner(self.evaluator, iterations=20, max_free=width,
                                            batch=REFINE_BATCH)
        ties = [tie_columns(t, self.evaluator) for _, t in coupled]
        refined = self._refiners[width].refine(population, fixed, ties=ties).population
        scores = self.evaluator.score(refined)
        for k, start, coefficients, value in zip(
                chosen, starts, from_system_population(refined, self.evaluator, starts),
                scores.objective):
            if value < self.objective[k]:
                self.refined[k], self.objective[k] = coefficients, float(value)
            else:
                self.refined[k] = start


def _offspring(trees, fitness, grammars, rng, config: GPConfig):
    parent = list(trees[_tournament(fitness, rng, config.tournament)])
    i = int(rng.integers(len(parent)))
    draw = rng.random()
    if draw < config.p_crossover:
        other = trees[_tournament(fitness, rng, config.tournament)]
        if rng.random() < config.p_swap:
            parent[i] = other[i]
        else:
            parent[i] = crossover(parent[i], other[i], grammars[i], rng)
    elif draw < config.p_crossover + config.p_mutation:
        parent[i] = mutation(parent[i], grammars[i], rng)
    elif draw < config.p_crossover + config.p_mutation + config.p_perturbation:
        parent[i] = perturbation(parent[i], grammars[i], rng)
    return tuple(parent)


def _tournament(fitness, rng, size: int) -> int:
    entrants = rng.integers(len(fitness), size=min(size, len(fitness)))
    return int(entrants[np.argmin(fitness[entrants])])


def _local_search(trees, fitness, equations: Equations, scorer: _Scorer,
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
            as_trees = [_as_trees(c, equations) for c in changed]
            scores = scorer(as_trees)
            best = int(np.argmin(scores))
            if not scores[best] < value * (1 - 1e-3):
                break
            current, value = changed[best], scores[best]
            out.append(as_trees[best])
    return out


def _as_trees(key, equations: Equations) -> tuple:
    return tuple(equations.tree(i, *part) for i, part in enumerate(key))


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
        yield from _removals(key, i)


def _equation_error_steps(key, scorer: "_Scorer", steps: int = 4, longest: int = 8):
    """Multi-term moves by weak-form equation error, which is separable per equation and
    never gets worse with a term more: per equation, forward selection from the equation as
    it is and from nothing, every equation along the way (the others kept); and jointly,
    every combination of the equations' selections from nothing (up to ``longest`` terms)
    that stop where the residual is within 5 % of the longest one's, one term less or one
    more (coupled equations are often right only together: a coupling term pays in output
    error once both ends have it)."""
    joint = []
    for i, (state, forcing) in enumerate(key):
        for part in _forward(scorer, key, i, list(state), list(forcing), steps):
            yield key[:i] + (part,) + key[i + 1:]
        fresh = list(_forward(scorer, key, i, [], [], longest))
        for part in fresh[:steps]:
            yield key[:i] + (part,) + key[i + 1:]
        residuals = [scorer.residual(key, i, part) for part in fresh]
        stop = next(k for k, r in enumerate(residuals) if r <= 1.05 * residuals[-1])
        joint.append(fresh[max(0, stop - 1):stop + 2])
    yield from itertools.product(*joint)


def _forward(scorer: "_Scorer", key, i: int, state: list, forcing: list, steps: int):
    """Equation ``i`` of ``key`` grown one feature at a time by the least weak-form
    residual (:meth:`_Scorer.residual`)."""
    state_basis, forcing_basis = scorer.equations.basis(i)
    for _ in range(steps):
        options = [([*state, f], forcing) for f in state_basis if f not in state]
        options += [(state, [*forcing, f]) for f in forcing_basis if f not in forcing]
        if not options:
            return
        state, forcing = min(options, key=lambda o: scorer.residual(key, i, o))
        yield tuple(sorted(state, key=str)), tuple(sorted(forcing, key=str))


def _removals(key, i: int):
    state, forcing = key[i]
    for k in range(len(state)):
        yield key[:i] + ((state[:k] + state[k + 1:], forcing),) + key[i + 1:]
    for k in range(len(forcing)):
        yield key[:i] + ((state, forcing[:k] + forcing[k + 1:]),) + key[i + 1:]


def _survivors(pool, scores, scorer: _Scorer, count: int):
    """The best ``count`` of ``pool``: distinct structures first, then repeats."""
    order = np.argsort(scores, kind="stable")
    seen, first, repeats = set(), [], []
    for index in order:
        key = scorer.key(pool[index])
        (repeats if key in seen else first).append(index)
        seen.add(key)
    chosen = (first + repeats)[:count]
    return [pool[i] for i in chosen], scores[chosen]


def _simplest(best, scorer: _Scorer, alpha: float, resolution: float):
    """From ``best``, one-term removals by the held-out test (module docstring), tried in
    the order of their held-out mean square. A removal replaces the current system when
    it predicts the held-out windows significantly better (level ``alpha``: the term
    demonstrably hurts), or when neither predicts significantly better and it does not
    simulate significantly worse once refined (:meth:`_Scorer.simulates_better`). Ends when
    no removal qualifies."""
    current = best
    while True:
        candidates = [c for i in range(len(current)) for c in _removals(current, i)
                      if all(part[0] or part[1] for part in c)]
        base = scorer.held_out(current)
        residuals = [scorer.held_out(c) for c in candidates]
        order = np.argsort([np.mean(r ** 2) for r in residuals], kind="stable")
        for index in order:
            if predictive_test(base, residuals[index])["p_value"] < alpha or (
                    predictive_test(residuals[index], base)["p_value"] >= alpha
                    and not scorer.simulates_better(current, candidates[index], alpha,
                                                    resolution)):
                current = candidates[index]
                break
        else:
            return current
