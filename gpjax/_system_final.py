"""The reported system at converged integration: a structure the reference solver cannot
integrate gives way to its nearest one that it can (:func:`integrable`), and a term its fit
does not demonstrate is dropped where the fit is at its noise floor
(:func:`insignificant_removals`, :func:`flagged`; :func:`added_terms_p` tests a
diagnosis's candidate the same way)."""

from __future__ import annotations

import math
from typing import Callable

import numpy as np
from scipy import special

from . import _progress
from ._data import Measurement
from ._system_diagnose import residual_statistics
from ._system_fit import SystemFit, fit_system
from ._system_scorer import SystemScorer
from ._system_select import removals


def reported(best, scorer: SystemScorer, measurement: Measurement, settings: dict,
             alpha: float) -> tuple:
    """(key, fit) of the reported system: the selection's ``best`` fitted at converged
    integration (:func:`gpjax._system_fit.fit_system` with ``settings``), replaced by its
    nearest structure the reference solver integrates where it cannot
    (:func:`integrable`), then its terms that fit does not demonstrate dropped one at a
    time (:func:`insignificant_removals` at level ``alpha``) while the refit stays
    unflagged (:func:`flagged`; a refit that diverges or is flagged keeps the term).

    Raises:
        ValueError: the converged fit of ``best`` diverged.
    """
    def fit_of(key, first: int | None) -> SystemFit | None:
        try:
            return fit_system(measurement, scorer.normalised(key),
                              start=scorer.coefficients(key), first_substeps=first, **settings)
        except ValueError:  # the refit diverged
            return None

    fit = fit_system(measurement, scorer.normalised(best), start=scorer.coefficients(best),
                     **settings)
    if not integrates(fit):
        _progress.stage("the reference solver cannot integrate the selected system: "
                        "fitting its one-term removals at converged integration")
        best, fit = integrable(best, lambda key: fit_of(key, fit.checks[0].substeps)) or (
            best, fit)
    candidates = [sum(map(len, scorer.equations.basis(i)))
                  for i in range(len(scorer.equations.names))]
    untested = (insignificant_removals(best, fit, alpha, candidates)
                if not flagged(fit, measurement) else [])
    while untested:
        smaller = untested.pop(0)
        _progress.stage(f"dropping a term its converged fit does not demonstrate (Wald test "
                        f"at level {alpha} over its equation's candidates), then fitting again")
        trial = fit_of(smaller, fit.model.substeps)
        if trial is not None and not flagged(trial, measurement):  # else the term stays
            best, fit = smaller, trial
            untested = insignificant_removals(best, fit, alpha, candidates)
    return best, fit


def flagged(fit: SystemFit, measurement: Measurement) -> bool:
    """Whether the report flags ``fit``: a coordinate's residual far above its noise floor
    with a significant in-band excess, or the model diverging on its record
    (:func:`gpjax._system_diagnose.residual_statistics`)."""
    statistics = residual_statistics(fit.model, measurement).values()
    return any(s["rms"] is None or s["unexplained"] is not None for s in statistics)


def integrates(fit: SystemFit) -> bool:
    """Whether the reference solver integrates ``fit``'s model over the samples of its last
    convergence check (a finite reference RMS residual)."""
    return math.isfinite(fit.checks[-1].rms_reference)


def integrable(key, fit_of: Callable) -> tuple | None:
    """(key, fit) of the one-term removal of ``key`` that the reference solver integrates
    with the smallest RMS residual at converged integration (``fit_of(key)``: that fit, or
    None where it diverged; a removal that would empty an equation is not fitted); None
    where no removal integrates. For a ``key`` whose converged fit the reference solver
    cannot integrate: the search ranks structures by RK4 at its own step count, whose numerical damping can hold back a term that makes the
    exact ODE blow up (a −c₃·x'³ standing in for a friction on a record whose speed passes
    √(c₁/c₃)). Such a structure is no model of the record — only the discretisation makes
    it one — and its one-term removals are the structures nearest to it."""
    fits = []
    for i in range(len(key)):
        for smaller in removals(key, i):
            if not (smaller[i][0] or smaller[i][1]):  # an emptied equation is no model
                continue
            fit = fit_of(smaller)
            if fit is not None and integrates(fit):
                fits.append((fit.checks[-1].rms_reference, len(fits), smaller, fit))
    if not fits:
        return None
    _, _, smaller, fit = min(fits)
    return smaller, fit


def _term_constants(fit: SystemFit, terms: dict[int, tuple[tuple, tuple]]) -> dict:
    """Name -> (equation, whether forcing, the term) of each constant of ``fit``'s model
    that multiplies one of ``terms`` (equation index -> (state features, forcing
    features)); the model names its features as text."""
    out = {}
    for name, (i, part, feature) in fit.model.constant_names().items():
        if part not in ("state", "forcing") or i not in terms:
            continue
        by_text = {str(f): f for f in terms[i][part == "forcing"]}
        if str(feature) in by_text:
            out[name] = (i, part == "forcing", by_text[str(feature)])
    return out


def insignificant_removals(key, fit: SystemFit, alpha: float, candidates=None) -> list:
    """``key`` without one term, for each term whose constant the converged output-error
    fit's Wald test (t = c/se with the interval's degrees of freedom,
    :mod:`gpjax._uncertainty`) cannot tell from 0 at level ``alpha`` (an infinite standard
    error: the record does not determine it, p = 1), least significant first (ties in the
    model's order). Reason: the selection before it runs at the search's step count,
    whose discretisation error a spurious term can absorb (a stiff smoothed sign wants a
    damping term beside it at one RK4 step per sample); only the converged fit says what
    the record demonstrates. A removal that would empty an equation is not offered.
    ``candidates``: per equation, how many features the search chose its terms from; a
    term of equation i is then tested at ``alpha`` / candidates[i] (Bonferroni: the term
    was selected from them after seeing the data, so its test is post-selection)."""
    uncertainty = fit.uncertainty
    if uncertainty is None:
        return []
    errors = uncertainty.standard_errors
    tested = []
    for name, term in _term_constants(fit, dict(enumerate(key))).items():
        se = errors.get(name)
        if se is None or not se > 0:  # held (no error) or not computed
            continue
        value = float(uncertainty.values[uncertainty.names.index(name)])
        dof = float(uncertainty.dof[uncertainty.names.index(name)])
        # an infinite error: the record does not determine the constant at all (p = 1)
        p = 2.0 * float(special.stdtr(dof, -abs(value) / se)) if math.isfinite(se) else 1.0
        level = alpha / (candidates[term[0]] if candidates else 1)
        if p >= level:
            tested.append((p, term))
    out = []
    for _, (i, forcing, feature) in sorted(tested, key=lambda pair: -pair[0]):
        part = tuple(tuple(f for f in key[i][k] if not (k == forcing and f == feature))
                     for k in (0, 1))
        if part[0] or part[1]:
            out.append(key[:i] + (part,) + key[i + 1:])
    return out


def added_terms_p(fit: SystemFit, added: dict[int, tuple[tuple, tuple]]) -> float:
    """p-value of the Wald test that the constants of the ``added`` terms (equation index
    -> (state features, forcing features)) are all zero at ``fit``, on the sandwich
    covariance of :mod:`gpjax._uncertainty` that the reported intervals use: W = cᵀΣ⁻¹c
    over those constants, W/k against F(k, ν), k the rank of Σ (a pair tied by the third
    law counts once), ν the fewest degrees of freedom among them (k = 1: the two-sided t
    test of :func:`insignificant_removals`). 1 where the fit has no uncertainty or an added
    constant has no finite standard error (the record does not determine it)."""
    uncertainty = fit.uncertainty
    if uncertainty is None:
        return 1.0
    index = [uncertainty.names.index(name) for name in _term_constants(fit, added)
             if name in uncertainty.names]
    if not index:
        return 1.0
    values = uncertainty.values[index]
    covariance = uncertainty.covariance[np.ix_(index, index)]
    if not (np.all(np.isfinite(covariance)) and np.all(np.diag(covariance) > 0)):
        return 1.0
    k = int(np.linalg.matrix_rank(covariance))
    statistic = float(values @ np.linalg.pinv(covariance) @ values)
    dof = float(np.min(uncertainty.dof[index]))
    if not math.isfinite(dof):
        return float(special.chdtrc(k, statistic))
    return float(special.fdtrc(k, dof, statistic / k))
