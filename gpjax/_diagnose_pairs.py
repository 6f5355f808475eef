"""Diagnosis, equation-error mode: pairs of effects, and the joint search of the chosen
effects' nonlinear parameters.

Why pairs. Forward selection adds one effect a round, and an effect enters only if it
helps on its own. Two effects can each be weak alone and exact together: a stage's dry
friction and its constant offset. With the offset missing, friction that differs by the
direction of motion is fitted by a symmetric law, and the viscous constant and the
friction's smoothing take up the rest (a drawn stage: friction alone explains 15 % of the
equation-error residual, the offset 41 %, both 99.98 %; or friction is accepted with a
smoothing so wide that the viscous constant turns negative, and the offset then fails its
test against that wrong fit). So each equation-error round also tests the ``shortlist``
pairs of effects whose terms together explain most of the residual, their nonlinear
parameters searched jointly (:func:`joint_parameters`).

How a pair is accepted, at the same level. The singles and the pairs of a round are one
Bonferroni family (m = their number). A pair must predict the held-out windows better
than the current model *and* better than each of its members alone (the same
Diebold–Mariano test, each Bonferroni-adjusted), and its added coefficients must pass the
score test against each of the three too (:func:`gpjax._diagnose_evidence.equation_error_scores`):
each member adds to the other, so a strong effect cannot carry a spurious partner in.
Requiring all of them (an intersection–union test) keeps the level. Among the passing singles and pairs the one
with the lowest charged held-out error is added; a pair enters as two steps.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy.optimize import minimize

from ._diagnose_acceptance import predictive_test
from ._diagnose_evidence import (Candidate, charge, equation_error_scores,
                                 explained_fraction)
from ._diagnose_fits import Fit, FitProblem, Structure, fit_structures
from ._effects import Context, Terms
from ._weak_form import WeakForm, least_squares_residual


def joint_parameters(weak: WeakForm, context: Context, start: Structure,
                     chosen: list[Candidate]) -> tuple[Structure, list[Candidate]]:
    """``start`` plus the ``chosen`` effects with their numeric nonlinear parameters (a
    friction smoothing, a dead zone) searched jointly: Nelder–Mead on the weak-form
    least-squares residual of ``weak``, within the effects' bounds, from their current
    values (kept where the search does not improve on them). Returns the structure and
    the candidates with their parameters and terms."""
    slots = [(k, p.name) for k, c in enumerate(chosen) for p in c.effect.parameters
             if isinstance(c.parameters.get(p.name), float)]

    def built(values) -> tuple[Structure, list[Candidate]] | None:
        out, structure = [], start
        for k, candidate in enumerate(chosen):
            parameters = dict(candidate.parameters)
            for (j, name), value in zip(slots, values):
                if j == k:
                    parameters[name] = float(np.clip(value, *candidate.effect.bounds(context)[name]))
            terms = candidate.effect.build(context, parameters)
            if terms is None:
                return None
            out.append(dataclasses.replace(candidate, parameters=parameters, terms=terms))
            structure = structure.plus(terms)
        return structure, out

    def residual(values) -> float:
        made = built(values)
        return (math.inf if made is None else
                least_squares_residual(weak, made[0].lhs, made[0].forcing))

    start_values = np.array([chosen[k].parameters[name] for k, name in slots])
    if slots:
        simplex = np.vstack([start_values] + [start_values * (1 + 0.5 * np.eye(len(slots))[i])
                                              for i in range(len(slots))])
        found = minimize(residual, start_values, method="Nelder-Mead",
                         options={"initial_simplex": simplex, "maxfev": 60 * len(slots)})
        if found.fun < residual(start_values):
            return built(found.x)
    return built(start_values)


@dataclasses.dataclass
class Pair:
    """Two effects tested together: ``first`` (the one better alone), ``second``, their
    joint share of the residual, the pair's fit, each member's fit alone and the test."""

    first: Candidate
    second: Candidate
    explained: float
    fit: Fit | None = None
    alone: tuple[Fit, Fit] | None = None
    test: dict | None = None


def rank_pairs(weak: WeakForm, context: Context, structure: Structure,
               ranked: list[Candidate], count: int) -> list[Pair]:
    """The ``count`` pairs of ``ranked`` effects whose terms together explain most of the
    equation-error residual, each with its parameters searched jointly
    (:func:`joint_parameters`); the member better alone first."""
    shares = []
    for i, a in enumerate(ranked):
        for b in ranked[i + 1:]:
            shares.append((explained_fraction(weak, structure, _together(a, b)), a, b))
    shares.sort(key=lambda item: -item[0])
    pairs = []
    for _, a, b in shares[:count]:
        first, second = joint_parameters(weak, context, structure, [a, b])[1]
        pairs.append(Pair(first, second,
                          explained_fraction(weak, structure, _together(first, second))))
    return pairs


def _together(a: Candidate, b: Candidate) -> Terms:
    """The terms of two candidates as one."""
    return Terms(a.terms.state + b.terms.state, a.terms.parametric + b.terms.parametric,
                 a.terms.forcing + b.terms.forcing)


def fit_and_test_pairs(problem: FitProblem, structure: Structure, current: Fit, pairs: list[Pair],
               family: int, alpha: float) -> None:
    """Fit every pair and each of its members alone, and test the pair against the current
    model and against each member alone (module docstring); ``family``: the Bonferroni
    count of the round (singles and pairs)."""
    structures = [s for p in pairs for s in (structure.plus(p.first.terms).plus(p.second.terms),
                                             structure.plus(p.first.terms),
                                             structure.plus(p.second.terms))]
    fits = fit_structures(problem, "equation_error", structures) if structures else []
    for k, pair in enumerate(pairs):
        pair.fit, pair.alone = fits[3 * k], (fits[3 * k + 1], fits[3 * k + 2])
        bases = (current, *pair.alone)
        tests = [predictive_test(base.holdout, pair.fit.holdout) for base in bases]
        scores = [equation_error_scores(problem, base, [pair.fit])[0] for base in bases]
        p = min(1.0, family * max(t["p_value"] for t in tests + scores))
        pair.test = tests[0] | {"p_adjusted": p, "passed": bool(p < alpha),
                                "p_against_members": [min(1.0, family * max(
                                    t["p_value"], score["p_value"]))
                                    for t, score in zip(tests[1:], scores[1:])],
                                "score": scores[0]}


def pair_criterion(pair: Pair, min_gain: float) -> float:
    """The pair's held-out mean square, charged for both members' parameters."""
    return pair.fit.criterion * charge(pair.first, min_gain) * charge(pair.second, min_gain)
