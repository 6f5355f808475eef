"""Diagnosis, steps 2 and 4: which effect explains the residual, and which helps most.

:func:`rank_effects` searches each effect's nonlinear parameters on a grid (and polishes
the best by Nelder–Mead) to maximise the share of the weak-form equation-error residual
its regressors explain (:func:`explained_fraction`; cheap and linear).
:func:`rank_by_output_error` ranks refitted candidates by their held-out output error,
with one Gauss–Newton step of look-ahead for pairs (see :mod:`gpjax._diagnose`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy.optimize import minimize

from ._data import Measurement
from ._diagnose_acceptance import score_test
from ._diagnose_fits import Fit, FitProblem, Structure
from ._effects import Context, Effect, Terms
from ._objective import amplitude_spectrum
from ._weak_form import WeakForm, design, scaled_lstsq

#: Strongest spectral lines of each input offered to frequency-dependent effects.
INPUT_LINES = 6
#: Best grid points polished by Nelder–Mead for effects of two or more nonlinear
#: parameters (one start for one parameter, whose grid is dense).
POLISH_STARTS = 3


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



def explained_fraction(weak: WeakForm, structure: Structure, terms: Terms) -> float:
    """Fraction of the weak-form equation-error residual energy that ``terms`` explain
    after the structure's own regressors are projected out (0 … 1)."""
    matrix, target, _ = design(weak, structure.lhs, structure.forcing)
    new = [weak.column(f) for f in terms.state + terms.parametric + terms.forcing]
    return projected_share(matrix, target, new)


def projected_share(matrix: np.ndarray, target: np.ndarray, new: list[np.ndarray]) -> float:
    """Fraction of the energy of ``target``'s least-squares residual on ``matrix``'s columns
    that the ``new`` columns explain once ``matrix``'s columns are projected out of them
    (0 … 1; non-finite new columns are left out)."""
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


def rank_by_output_error(problem: FitProblem, candidates: list[Candidate], results: list[Fit],
                         min_gain: float) -> list[int]:
    """Order (indices, best first) of the candidates whose refits are ``results``, ranked
    on the held-out output error with one step of look-ahead (module docstring, 4.); the
    candidates' evidence is rewritten to say so. While the leader owes its place to a
    predicted pair, that pair is refitted and its prediction replaced by the refit."""
    factors = [charge(c, min_gain) for c in candidates]
    alone = [r.criterion * k for r, k in zip(results, factors)]
    pairs: dict[tuple[int, int], float] = {}
    for i, fit in enumerate(results):
        if not math.isfinite(fit.criterion):
            continue
        predict = _gauss_newton(problem, fit, [c.terms for c in candidates])
        for j, other in enumerate(candidates):
            if j != i:
                key = (min(i, j), max(i, j))
                pairs[key] = min(pairs.get(key, math.inf), predict(other.terms))
    refitted: set[tuple[int, int]] = set()
    while True:
        best = [(value, None, None) for value in alone]  # (score, partner, pair error)
        for (i, j), value in pairs.items():
            charged = value * factors[i] * factors[j]
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


def _gauss_newton(problem: FitProblem, fit: Fit, extra: list[Terms]):
    """A function: the terms of one more effect (one of ``extra``) -> the held-out
    mean-square error that one Gauss–Newton step from ``fit`` predicts with them added
    (their coefficients from 0, the fit's own parameters free): least squares of the
    residual measured − simulated on the estimation part, applied to the held-out part."""
    jacobian, base, columns, _ = sensitivities(problem, fit, extra)
    residual = problem.measurement.response - fit.simulated
    n = problem.n_train

    def predicted(terms: Terms) -> float:
        a = jacobian[:, base + [c for c in columns(terms) if c not in base]]
        scale = np.linalg.norm(a[:n], axis=0)
        a = a / np.where(scale > 0, scale, 1.0)
        step = np.linalg.lstsq(a[:n], residual[:n], rcond=None)[0]
        return float(np.mean((residual[n:] - a[n:] @ step) ** 2))

    return predicted


def sensitivities(problem: FitProblem, fit: Fit, extra: list[Terms] = ()):
    """(Jacobian of the simulated response over the record at ``fit``, the positions of
    its columns of the fit's free parameters — mass where the first input's gain is held
    at 1, the coefficients, the initial state —, a function: terms -> the positions of
    their coefficients' columns, and the free parameters' columns of the flat layout).
    Only those columns and the ``extra`` terms' are computed
    (:meth:`gpjax._diagnose_fits._Simulator.jacobian`)."""
    structure = fit.structure
    simulator = problem.simulator_for([structure])
    ev = simulator.full
    layout = ev.layout

    def columns(lhs, forcing, fixed=None):
        return ([layout.state_column(c) for c, _, _ in ev.state_columns(lhs)]
                + [layout.forcing_column(ev.forcing_index(g)) for g in forcing if g != fixed])

    def of(terms):
        return columns(terms.state + terms.parametric, terms.forcing)

    normalised = problem.u0 is not None and problem.u0 in structure.forcing
    base = (([0] if normalised else [])
            + columns(structure.state + structure.parametric, structure.forcing,
                      problem.u0 if normalised else None)
            + [layout.width - 2, layout.width - 1])
    wanted = list(dict.fromkeys(base + [c for terms in extra for c in of(terms)]))
    position = {c: i for i, c in enumerate(wanted)}
    jacobian = simulator.jacobian(fit, wanted)
    return jacobian, [position[c] for c in base], lambda terms: list(dict.fromkeys(
        position[c] for c in of(terms))), base


def score_statistics(problem: FitProblem, current: Fit, candidates: list[Candidate],
                     results: list[Fit]) -> list[dict]:
    """Per candidate, the robust score test (:func:`gpjax._diagnose_acceptance.score_test`)
    that its coefficients are zero, on the estimation part of the current fit's residual
    with the simulated response's sensitivities at the current fit, the variance from the
    candidate's refit (``results``, same order) residual.

    Where those sensitivities give the candidate's terms no column outside the current
    fit's (``dof`` 0: the test has no information, e.g. a dead zone that the current
    fit's simulated response never leaves), the same test is taken in the weak form on
    the measured response instead (:func:`equation_error_scores`, marked ``"weak_form"``),
    which does not depend on the fit's trajectory: "no information" is not "zero"."""
    problem.simulator_for([current.structure] + [current.structure.plus(c.terms)
                                                 for c in candidates])
    jacobian, base, columns, _ = sensitivities(problem, current,
                                               [c.terms for c in candidates])
    n, measured = problem.n_train, problem.measurement.response
    residual = (measured - current.simulated)[:n]
    out = []
    for candidate, fit in zip(candidates, results):
        added = [k for k in columns(candidate.terms) if k not in base]
        out.append(score_test(residual, jacobian[:n, base], jacobian[:n, added],
                              noise=(measured - fit.simulated)[:n]))
    blind = [k for k, test in enumerate(out) if test["dof"] == 0]
    if blind:  # one weak-form design of the current structure for all of them
        for k, test in zip(blind, equation_error_scores(problem, current,
                                                        [results[k] for k in blind])):
            out[k] = test | {"weak_form": True}
    return out


def equation_error_scores(problem: FitProblem, current: Fit, results: list[Fit]) -> list[dict]:
    """Per candidate fit (equation-error mode), the same robust score test as
    :func:`score_statistics` that the coefficients its effect adds are zero, on the
    estimation part's weak form: the current structure's weak-form least-squares residual,
    its design columns as the base, the added features' columns as the extra ones, the
    variance from the candidate's own least-squares residual."""
    weak = problem.weak
    base, target, _ = design(weak, current.structure.lhs, current.structure.forcing)
    residual = target - base @ scaled_lstsq(base, target)
    out = []
    for fit in results:
        full, _, _ = design(weak, fit.structure.lhs, fit.structure.forcing)
        added = ([weak.column(f) for f in fit.structure.lhs if f not in current.structure.lhs]
                 + [weak.column(g) for g in fit.structure.forcing
                    if g not in current.structure.forcing])
        extra = np.stack(added, axis=1) if added else np.zeros((target.size, 0))
        out.append(score_test(residual, base, extra,
                              noise=target - full @ scaled_lstsq(full, target)))
    return out


def charge(candidate: Candidate, min_gain: float) -> float:
    """(1 − min_gain)^−p, p = the coefficients plus nonlinear parameters the effect adds:
    the factor on its held-out mean square for the parameters it spends."""
    terms = candidate.terms
    added = len(terms.state + terms.parametric + terms.forcing) + len(candidate.effect.parameters)
    return (1.0 - min_gain) ** -added
