"""Diagnosis of a system (several coordinates): the effect library on every equation and
every relative coordinate, added while the held-out error falls significantly.

The one-coordinate diagnosis (:mod:`gpjax._diagnose`) in simulation mode, per round:

1. **Candidates.** Every effect of the library (:mod:`gpjax._effects`) is built on every
   coordinate x_i (its terms go to equation i) and on every relative coordinate
   x_i − x_j, i < j (a force between two bodies: its terms go to equation i and, mirrored
   in x_j − x_i, to equation j; with the model's third law, tied). Only terms a system's
   equation can hold are kept — powers, and the bank's tanh(θ·z), z·|z|, sin z, cos z
   (:mod:`gpjax._system_bank`; a friction's smoothing is the bank's width) for states,
   any function of time and inputs for forcing — so a time-varying stiffness or a
   backlash dead zone is not offered for several coordinates. Candidates are ranked by
   the share of their equation's weak-form equation-error residual they explain once the
   equation's own features are projected out (:func:`gpjax._diagnose_evidence.projected_share`;
   the larger share of the two equations of a relative coordinate), and the first
   ``shortlist`` go on.
2. **Refit.** The current structure is fitted on the *estimation* part of the record (the
   first 1 − ``holdout``) by :func:`gpjax._system_fit.fit_system` at converged integration
   (:mod:`gpjax._convergence`: its RK4 error would be a systematic residual that a
   flexible candidate absorbs), each shortlisted candidate at that RK4 step count, and
   each is simulated over the whole record from its fitted initial state by the reference
   solve.
3. **Acceptance at level ``alpha``**, Bonferroni over the round's candidates: the
   Diebold–Mariano test that the candidate predicts the held-out part better
   (:func:`gpjax._diagnose_acceptance.predictive_test`; the loss per sample is the sum
   over coordinates of the squared residual over the coordinate's standard deviation),
   intersected with the Wald test that its constants are not zero, on its fit to the
   estimation part (:func:`gpjax._system_final.added_terms_p`: the sandwich covariance of
   :mod:`gpjax._uncertainty`, whose intervals the report prints) — where the
   one-coordinate diagnosis uses a score test on the response's sensitivities. The passing
   candidate with the lowest held-out error, each added constant charged
   (1 − ``min_gain``)^−1, is added; rounds stop when none passes.
4. **The result** is fitted on the whole record at converged integration
   (:mod:`gpjax._convergence`), and each coordinate's residual is described against its
   noise floor (:func:`gpjax._system_diagnose.residual_statistics`).

The report names the effect, the coordinate or relative coordinate it acts on and its
equation(s). Not done for systems (yet): the pair look-ahead, equation-error mode for
drifting systems, the search of nonlinear parameters, and the reduction of inputs that are
sums of lines to their lines.

Why the Wald test and not a likelihood ratio. The held-out test alone can pass a term that
does not belong (it compares two fitted models, and a null term sometimes corrects the
base fit's own error in the held-out tail: :mod:`gpjax._diagnose_acceptance`), so the
second test must hold its level. A likelihood ratio of the two fits' residuals, each
coordinate's sample count reduced by its long-run variance (Andrews' AR(1) bandwidth),
did not: on a clean 2-mass chain with 1 % noise on the measured input (seed 8) it gave
p = 1e-7 for an x1³ whose constant is −0.31 ± 0.63 on the estimation part and −0.34 ± 0.59
on the whole record. The input's noise rings through the chain's resonances, and the
sandwich covariance (:mod:`gpjax._uncertainty`), which measures the residual per frequency
bin, finds that constant's information in a few bins (2.4 degrees of freedom): a
narrow-band residual whose variance a sample-count correction from the lag-1
autocorrelation misses, as the same estimator gave intervals 2–3 times too narrow there.
The Wald test on the sandwich gives that x1³ p = 0.19.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import sympy as sp

from . import _progress
from ._canonical import Symbols
from ._data import Measurement
from ._diagnose_acceptance import accepted
from ._diagnose_report import finite
from ._diagnose_evidence import projected_share
from ._effects import Context, Effect, Terms, effects
from ._errors import UserInputError
from ._model import Model
from ._system_bank import KINDS, bank_feature, match_bank, sign_scales, system_variables
from ._system_couplings import held_structure
from ._report import write_text_atomic
from ._system_diagnose import residual_statistics, summary_line
from ._system_final import added_terms_p
from ._system_fit import SystemFit, fit_system
from ._weak_form import WeakForm, design, smoothed_weak_form

#: Placeholder symbol of a relative coordinate while an effect builds its terms.
_RELATIVE = "gpjax_relative"


@dataclasses.dataclass(frozen=True)
class SystemCandidate:
    """An effect on one coordinate or relative coordinate: ``where`` (``"x2"``,
    ``"x1 - x2"``), ``added`` (equation index -> (state features, forcing features)) and
    ``explained`` (share of the equation-error residual, step 1)."""

    effect: Effect
    where: str
    added: dict[int, tuple[tuple[sp.Expr, ...], tuple[sp.Expr, ...]]]
    explained: float

    @property
    def n_terms(self) -> int:
        return sum(len(s) + len(f) for s, f in self.added.values())

    def describe(self) -> dict:
        return {"effect": self.effect.name, "acts_on": self.where,
                "equations": [i + 1 for i in sorted(self.added)],
                "terms": {str(i + 1): [str(f) for f in (*s, *f)]
                          for i, (s, f) in sorted(self.added.items())},
                "explained": self.explained}


@dataclasses.dataclass
class SystemDiagnosis:
    """:func:`diagnose_system`'s result: the steps taken, every round's ranking and tests,
    the starting and the final fit on the whole record, their residual statistics."""

    steps: list[dict]
    rankings: list[list[dict]]
    before: SystemFit
    after: SystemFit
    residuals: dict
    settings: dict

    @property
    def effects_added(self) -> list[str]:
        return [f"{s['effect']} on {s['acts_on']} (equation "
                f"{' and '.join(map(str, s['equations']))})" for s in self.steps]

    def model(self) -> Model:
        """The final model, with its uncertainty, convergence check and residuals."""
        fit = self.after
        return dataclasses.replace(
            fit.model, uncertainty=fit.uncertainty, convergence=fit.checks[-1].to_json(),
            metrics={"rms": {k: v["rms"] for k, v in self.residuals.items()},
                     "residuals": self.residuals},
            provenance={"diagnosis": {"effects_added": self.effects_added} | self.settings})

    def to_json(self) -> dict:
        return {"mode": "simulation", "coordinates": list(self.after.model.coordinates),
                "effects_added": self.effects_added, "steps": self.steps,
                "rankings": self.rankings, "settings": self.settings,
                "convergence": self.after.checks[-1].to_json(), "residuals": self.residuals}

    def markdown(self) -> str:
        """The report for a person: the effects added with their tests, the model before
        and after, each coordinate's residual against its noise floor."""
        before, after = self.before.model, self.model()
        lines = ["# Diagnosis of a system", "",
                 f"Effects added: {', '.join(self.effects_added) or 'none'}.", ""]
        for step in self.steps:
            test, rms = step["test"], step["heldout_rms_before"]
            was = (f"{rms:.4g}" if rms is not None and math.isfinite(rms)
                   else "none (the model before diverged on the estimation part)")
            lines.append(f"- {step['effect']} on {step['acts_on']}: held-out RMS (scaled) "
                         f"{was} -> {step['heldout_rms_after']:.4g}, "
                         f"p = {test['p_adjusted']:.3g} (held-out test and Wald test, "
                         "Bonferroni)")
        lines += ["", "## Model before", "", *(f"- `{before.sympy(i)}`"
                                                for i in range(before.n_coordinates)),
                  "", "## Model after", "", *(f"- `{after.sympy(i)}`"
                                              for i in range(after.n_coordinates)),
                  "", "## Residuals (reference solve)", "",
                  *(summary_line(name, statistics).strip()
                    for name, statistics in self.residuals.items())]
        return "\n".join(lines) + "\n"

    def write(self, out) -> None:
        """Write report.json, report.md and model.json into folder ``out``."""
        out = Path(out)
        write_text_atomic(out / "report.json", json.dumps(finite(self.to_json()), indent=2)
                          + "\n")
        write_text_atomic(out / "report.md", self.markdown())
        self.model().save(out / "model.json")


def diagnose_system(measurement: Measurement, model: Model, *,
                    library: dict[str, Effect] | None = None, holdout: float = 0.25,
                    max_steps: int = 4, shortlist: int = 4, min_gain: float = 0.02,
                    alpha: float = 0.05, convergence_tolerance: float = 0.01,
                    input_interpolation: str | None = None) -> SystemDiagnosis:
    """Add missing effects to the system ``model`` while its held-out error falls
    significantly (module docstring); only its structure is used, constants are refitted.
    ``input_interpolation``: inputs between samples (default: the model's).

    Raises:
        UserInputError: the record's responses are not the model's coordinates, or a
            setting is out of range.
    """
    names = tuple(model.coordinates)
    if tuple(measurement.response_names) != names:
        raise UserInputError(f"the record's responses {list(measurement.response_names)} are "
                             f"not the model's coordinates {list(names)}; pass one "
                             "--response per coordinate, in the model's order")
    if not (0.05 <= holdout <= 0.5 and 0 < alpha < 1 and max_steps >= 0 and shortlist >= 1
            and min_gain >= 0):
        raise UserInputError("0.05 <= holdout <= 0.5, 0 < alpha < 1, max_steps >= 0, "
                             "shortlist >= 1 and min_gain >= 0 are required; fix the setting")
    library = effects() if library is None else dict(library)
    n_train = int(round((1.0 - holdout) * measurement.n_samples))
    train = measurement.segment(0, n_train)
    scale = train.responses.std(axis=0)
    weak = smoothed_weak_form(train)
    # Every bank kind in every fit's evaluator: the candidates' refits share its programs.
    settings = dict(third_law=model.third_law, max_degree=_max_degree(model),
                    input_interpolation=input_interpolation or model.input_interpolation,
                    kinds=KINDS)

    inputs = tuple(sp.Symbol(u) for u in measurement.input_names)

    def structure(key):
        return held_structure(key, names, inputs, model.third_law)

    def residual_of(key, steps: int | None) -> tuple[np.ndarray, int, SystemFit | None]:
        """((D, N) scaled residual, RK4 steps per sample, the fit) of ``key`` fitted on the
        estimation part at ``steps``, or (``None``) at the converged step count from the
        current one: the current model's integration error would be a systematic residual
        that a candidate's flexible term absorbs. NaN (and no fit) where the fit diverges."""
        try:
            result = fit_system(train, structure(key), substeps=steps,
                                first_substeps=substeps, tolerance=convergence_tolerance,
                                **settings)
        except ValueError:
            return np.full((len(names), measurement.n_samples), np.nan), substeps, None
        simulated = np.reshape(result.model.simulate(
            measurement, initial_conditions=result.model.initial_states),
            measurement.responses.shape)
        return ((simulated - measurement.responses) / scale).T, result.model.substeps, result

    substeps = model.substeps
    start = key = tuple((tuple(c.state), tuple(c.forcing)) for c in model.system)
    _progress.stage("diagnosis of the system: fitting the starting structure on the "
                    "estimation part, converged")
    residual, substeps, _ = residual_of(key, None)
    steps, rankings = [], []
    for round_number in range(max_steps):
        ranked = _candidates(key, weak, train, library)
        shortlisted = ranked[:shortlist]
        _progress.stage(f"diagnosis of the system: step {round_number + 1}: fitting "
                        f"{len(shortlisted)} candidate effect(s)")
        keys = [_plus(key, c) for c in shortlisted]
        refits = [residual_of(k, substeps) for k in keys]
        results = [r for r, _, _ in refits]
        held = [_loss(r[:, n_train:]) for r in results]
        scores = [{"p_value": 1.0 if fit is None else added_terms_p(fit, c.added)}
                  for c, (_, _, fit) in zip(shortlisted, refits)]
        tests = accepted(_loss(residual[:, n_train:]), held, alpha=alpha, scores=scores)
        charged = [float(np.mean(h ** 2)) / (1 - min_gain) ** c.n_terms
                   for h, c in zip(held, shortlisted)]
        rankings.append([c.describe() | ({"heldout_ms": charged[i], "test": tests[i]}
                                         if i < len(tests) else {})
                         for i, c in enumerate(ranked)])
        passing = [i for i, t in enumerate(tests) if t["passed"] and math.isfinite(charged[i])]
        if not passing:
            break
        best = min(passing, key=charged.__getitem__)
        steps.append(shortlisted[best].describe() | {
            "test": tests[best], "heldout_rms_before": _rms(residual[:, n_train:]),
            "heldout_rms_after": _rms(results[best][:, n_train:])})
        key = keys[best]
        residual, substeps, _ = residual_of(key, None)  # the new current model, converged
    _progress.stage("diagnosis of the system: fitting the result on the whole record, "
                    "converged")
    fits = {k: fit_system(measurement, structure(k), first_substeps=substeps,
                          tolerance=convergence_tolerance, **settings)
            for k in dict.fromkeys([start, key])}
    before, after = fits[start], fits[key]
    residuals = residual_statistics(after.model, measurement, alpha=alpha)
    return SystemDiagnosis(steps, rankings, before, after, residuals, {
        "holdout": holdout, "max_steps": max_steps, "shortlist": shortlist,
        "min_gain": min_gain, "alpha": alpha, "substeps": after.model.substeps,
        "input_interpolation": settings["input_interpolation"]})


def _max_degree(model: Model) -> int:
    """The highest power of a variable in ``model``'s state features, at least 3 (the
    library's cubic stiffness)."""
    powers = [int(power) for c in model.system for feature in c.state
              for power in [feature.as_base_exp()[1]] if power.is_Integer]
    return max([3, *powers])


def _loss(residual: np.ndarray) -> np.ndarray:
    """Per sample, the root sum over coordinates of the squared scaled residuals: its
    square is the loss :func:`gpjax._diagnose_acceptance.predictive_test` compares."""
    return np.sqrt(np.sum(residual ** 2, axis=0))


def _rms(residual: np.ndarray) -> float:
    return float(np.sqrt(np.mean(residual ** 2)))


def _plus(key, candidate: SystemCandidate):
    return tuple((state + candidate.added.get(i, ((), ()))[0],
                  forcing + candidate.added.get(i, ((), ()))[1])
                 for i, (state, forcing) in enumerate(key))


def _candidates(key, weak: WeakForm, train: Measurement,
                library: dict[str, Effect]) -> list[SystemCandidate]:
    """Every effect on every coordinate and relative coordinate whose terms the equations
    can hold and lack, ranked by the equation-error residual they explain (step 1)."""
    names = train.response_names
    variables = system_variables(names)
    scales = sign_scales(names, weak.rms).reshape(len(names), -1)
    positions = [row[0] for row in variables]  # x_i, x_i' as system_variables names them
    velocities = [row[len(names)] for row in variables]
    places = [(names[i], (i,), weak.values(positions[i]), weak.values(velocities[i]))
              for i in range(len(names))]
    places += [(f"{names[i]} - {names[j]}", (i, j), weak.values(positions[i] - positions[j]),
                weak.values(velocities[i] - velocities[j]))
               for i in range(len(names)) for j in range(i + 1, len(names))]
    out = []
    for where, equations, x, x_dot in places:
        symbols = Symbols(names[equations[0]] if len(equations) == 1 else _RELATIVE,
                          train.time_name, train.input_names)
        context = Context(symbols=symbols, x=x, x_dot=x_dot, time=train.time,
                          inputs=train.inputs, frequencies=(), forcing=())
        for effect in library.values():
            found = {}
            for parameters in effect.grid(context):
                terms = effect.build(context, parameters)
                added = terms and _in_equations(terms, equations, key, names, variables, scales)
                if added:
                    found[tuple(sorted(map(str, (f for s, g in added.values()
                                                 for f in (*s, *g)))))] = added
            for added in found.values():
                share = max(_explained(weak, key, i, *added[i]) for i in added)
                out.append(SystemCandidate(effect, where, added, share))
    out.sort(key=lambda c: -c.explained)
    return out


def _in_equations(terms: Terms, equations: tuple[int, ...], key, names, variables, scales):
    """{equation: (state, forcing) it gains} for an effect's ``terms`` on a coordinate
    (one equation) or a relative coordinate (two, mirrored), or ``None`` where a term is
    no system feature (a time-varying one, a dead zone) or a relative effect forces."""
    if terms.parametric or (len(equations) == 2 and terms.forcing):
        return None
    out = {}
    for i in equations:
        other = [j for j in equations if j != i]
        swap = {}
        if other:
            z, z_dot = sp.symbols(f"{_RELATIVE} {_RELATIVE}_dot")
            swap = {z: sp.Symbol(names[i]) - sp.Symbol(names[other[0]]),
                    z_dot: sp.Symbol(f"{names[i]}_dot") - sp.Symbol(f"{names[other[0]]}_dot")}
        state = []
        for term in terms.state:
            feature = term.subs(swap) if swap else term
            base, power = feature.as_base_exp()
            if not (power.is_Integer and power > 0 and base in variables[i]):
                found = match_bank(feature, variables[i])
                if found is None:
                    return None
                kind, position, _ = found
                feature = bank_feature(kind, variables[i][position],
                                       float(scales[i, position]) if kind == "sign" else 1.0)
            state.append(feature)
        state = tuple(f for f in state if f not in key[i][0])
        forcing = tuple(f for f in terms.forcing if f not in key[i][1])
        if state or forcing:
            out[i] = (state, forcing)
    return out or None


def _explained(weak: WeakForm, key, i: int, state, forcing) -> float:
    matrix, target, _ = design(weak, tuple(key[i][0]), tuple(key[i][1]), equation=i, held={})
    new = [weak.column(f) for f in state] + [-weak.column(f) for f in forcing]
    return projected_share(matrix, target, new)
