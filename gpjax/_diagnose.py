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
   in rounds of ``iterations`` steps until a round lowers the objective by less than
   0.1 % (:func:`gpjax._refine.refined_to_convergence`: the effects are compared at
   their converged constants, not at a step count), and the refit is simulated over the
   whole record from its fitted initial state.
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
5. **Acceptance at level ``alpha``** (default 0.05; :mod:`gpjax._diagnose_acceptance`):
   a Diebold–Mariano test that the candidate predicts the held-out segment better than the
   current model (loss differential of squared residuals, batch means longer than
   Andrews' bandwidth, Wilcoxon signed-rank, one-sided) and a score test on the
   estimation part that the candidate's coefficients are not zero (prewhitened HAC; on the
   simulated response's sensitivities in simulation mode, on the weak-form columns in
   equation-error mode); both must pass (an intersection–union test), each Bonferroni over
   the candidates of the round: a correct model gains a spurious term with probability at
   most ``alpha``. The best-ranked passing candidate is added (equation-error mode: the
   passing one with the lowest charged held-out error; there the round also tests the
   pairs of effects that together explain most of the residual, in the same Bonferroni
   family, each also against its members alone: :mod:`gpjax._diagnose_pairs`). Rounds
   stop when none passes, so the first round whose model is already right is the only
   one that can add a spurious term: over a whole run that chance stays ≤ ``alpha`` (no
   spending across rounds).
   ``min_gain`` only orders the candidates (a parsimony charge), it decides nothing.

Before each round's test the current model's integration is converged (``substeps``
"auto": the check of :mod:`gpjax._convergence` on the current fit, or on the starting
structure's weak-form fit in the first round, before anything is compiled): an RK4 error
of a fraction of the noise is a systematic residual that a flexible term absorbs and then
really predicts better. These checks only choose the steps a round fits at: one that RK4's
step-doubling estimate of its own error passes ends there, one that it fails is made against
the Dopri8 reference, which alone can say that a model does not integrate
(:mod:`gpjax._convergence`); the reported model's check, after the whole-record refit, is
always against the reference. Inputs reduced to their lines are simulated band-limited unless an
interpolation is given: a sum of lines is exact between samples that way, where linear
interpolation leaves a systematic force error near the resonance (several σ on a stiff
case).

The noise is estimated from the data (:mod:`gpjax._diagnose_noise`): measured inputs that
are sums of lines are reduced to their significant lines before any fit (their sensor
noise would otherwise ring through a resonance of the simulation and reward a spurious
damping term), and the final residual's noise floor — its spectrum above the response's
band — is reported with the final model's distance from it.

Drifting systems (a free mass with friction, a positioning stage, a pure integrator): if
the starting model has no restoring term (no term in x alone), the whole diagnosis runs on
the **equation error** instead (mode ``"equation_error"``): fits are weak-form least
squares; the held-out residual is every window's, by blocked 5-fold cross-validation
(:func:`gpjax._diagnose_fits.blocked_cv_residual`); derivatives and windows follow the
wider of the position's and the rate's band, windows where the measured position is at
rest are left out (set-valued dry friction), and once chosen the effects' nonlinear
parameters are searched again jointly; the reported ``rms`` is the RMS of the pointwise
generalised-force residual (force units, not response units).

Modules: this one holds the loop and its result (:class:`Diagnosis`); the refits are
:mod:`gpjax._diagnose_fits`, the evidence and rankings :mod:`gpjax._diagnose_evidence`,
the acceptance test :mod:`gpjax._diagnose_acceptance`, the equation-error mode's pairs
of effects :mod:`gpjax._diagnose_pairs`, the noise
:mod:`gpjax._diagnose_noise`, the unexplained residual :mod:`gpjax._diagnose_residual`, the
written report :mod:`gpjax._diagnose_report`.
"""

from __future__ import annotations

import dataclasses
import math
import types
from concurrent.futures import Future

import numpy as np

from . import _progress
from ._canonical import Symbols
from ._config import GPConfig
from ._convergence import MAX_SUBSTEPS, fit_converged, initial_substeps, reference_started
from ._data import INPUT_INTERPOLATIONS, Measurement
from ._diagnose_acceptance import accepted
from ._diagnose_ambiguity import indistinguishable, separating_input
from ._diagnose_evidence import (Candidate, charge, input_lines, rank_by_output_error,
                                 equation_error_scores, rank_effects, score_statistics,
                                 sensitivities)
from ._diagnose_fits import (Fit, FitProblem, Structure, consensus_refits, drifts,
                             fit_structures)
from ._diagnose_pairs import (Pair, fit_and_test_pairs, joint_parameters, pair_criterion,
                              rank_pairs)
from ._diagnose_noise import input_lines_only, noise_floor
from ._diagnose_residual import FAR_ABOVE, describe_residual
from ._effects import Effect, effects
from ._errors import ModelFileError, UserInputError
from ._memory import release_memory
from ._coefficients import to_population
from ._model import Model
from ._system_diagnose import count_input_noise, gate_ratio, input_noise_response
from ._uncertainty import Uncertainty, model_names, sandwich_covariance
from ._weak_form import design, scaled_lstsq


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
        measurement, symbols: the data (inputs reduced to their lines where
            ``settings["input_noise"]`` says so) and its names.
        noise: the final and the starting residual's noise floor (:func:`noise_floor`).
        unexplained: where the final residual stays far above its noise floor, its
            description (:func:`describe_residual`), else ``None``.
        uncertainty: the final model's standard errors and 95 % intervals on the whole
            record (:mod:`gpjax._uncertainty`; simulation mode only, else ``None``).
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
    noise: dict | None = None
    unexplained: dict | None = None
    uncertainty: Uncertainty | None = None

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
        model = dataclasses.replace(model, uncertainty=self.uncertainty)
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
        return {"mode": self.mode, "criterion": CRITERION[self.mode],
                "settings": self.settings, "n_samples": self.measurement.n_samples,
                "n_estimation": self.n_train, "frequencies_hz": list(self.frequencies),
                "effects_added": self.effects_added,
                "before": _summary(self.before), "after": _summary(self.after),
                "noise": self.noise, "unexplained": self.unexplained, "steps": self.steps,
                "rankings": self.rankings,
                "convergence": self.convergence, "model": self.model().to_json()}


_TEST = ("a one-sided Diebold-Mariano test (squared-error loss, batch means longer than "
         "Andrews' AR(1) bandwidth, Wilcoxon signed-rank) that it predicts the held-out segment better "
         "than the current model and a score test (prewhitened HAC) that its "
         "coefficients are not zero on the estimation part, both required "
         "(p = the larger), Bonferroni over the candidates of the round, at level alpha")
CRITERION = {
    "simulation": "effects ranked by held-out output error charged (1 - min_gain)^-p, "
                  "refitted alone and, one Gauss-Newton step ahead, with the best partner "
                  "effect; the model is fitted on the first part of the record and "
                  "simulated over all of it; the best-ranked effect that passes " + _TEST
                  + " is kept",
    "equation_error": "weak-form equation error (the starting model drifts in open-loop "
                      "simulation), fitted on the first part of the record; an effect is "
                      "kept when it passes " + _TEST + " (held-out windows)",
}


def _summary(fit: Fit) -> dict:
    return {k: fit.metrics.get(k) for k in ("rms", "objective", "spectral_error",
                                            "rms_estimation", "rms_holdout")}


def structure_of(model: Model) -> Structure:
    """The features of a model (its constants are ignored: they are refitted)."""
    symbols, coefficients = model.symbols, model.coefficients
    lhs = tuple(coefficients.state)
    return Structure(tuple(f for f in lhs if symbols.t not in f.free_symbols),
                     tuple(f for f in lhs if symbols.t in f.free_symbols),
                     tuple(coefficients.forcing))


def diagnose(measurement: Measurement, model: Model, *, library: dict[str, Effect] | None = None,
             frequencies: tuple[float, ...] = (), holdout: float = 0.25, max_steps: int = 4,
             shortlist: int = 4, min_gain: float = 0.02, alpha: float = 0.05,
             denoise_inputs: bool = True, iterations: int = GPConfig.refine_iterations,
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
        min_gain: parsimony charge in the ranking: each added parameter's held-out mean
            square is weighed by (1 − min_gain)^−1 (orders candidates, decides nothing).
        alpha: level of the acceptance test (:mod:`gpjax._diagnose_acceptance`), the
            chance that a correct model gains a spurious term in a round.
        denoise_inputs: reduce inputs that are sums of spectral lines to their significant
            lines at level ``alpha`` before fitting (:func:`input_lines_only`).
        iterations: Levenberg–Marquardt steps per round of a refit (rounds repeat while
            a model's objective falls by more than 0.1 %, at most 10:
            :func:`gpjax._refine.until_converged`).
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

    A model of several coordinates is diagnosed by
    :func:`gpjax._system_effects.diagnose_system` (``holdout``, ``max_steps``,
    ``shortlist``, ``min_gain``, ``alpha``, ``convergence_tolerance`` and
    ``input_interpolation`` apply) and gives its :class:`SystemDiagnosis`.

    Raises:
        UserInputError: the data's names differ from the model's, or a setting is out of
            range.
    """
    names = (measurement.time_name, tuple(measurement.response_names),
             tuple(measurement.input_names))
    if names != (model.time, tuple(model.coordinates), tuple(model.inputs)):
        raise ModelFileError(
            f"the model's variables (time {model.time!r}, responses {list(model.coordinates)}, "
            f"inputs {list(model.inputs)}) differ from the data's columns (time {names[0]!r}, "
            f"responses {list(names[1])}, inputs {list(names[2])}); pass matching --time, "
            "--response and --input or edit the model's \"variables\"")
    if model.n_coordinates > 1:
        from ._system_effects import diagnose_system

        return diagnose_system(measurement, model, library=library, holdout=holdout,
                               max_steps=max_steps, shortlist=shortlist, min_gain=min_gain,
                               alpha=alpha, convergence_tolerance=convergence_tolerance,
                               input_interpolation=input_interpolation)
    symbols = model.symbols
    if not 0.05 <= holdout <= 0.5:
        raise UserInputError(f"holdout must lie in [0.05, 0.5], got {holdout}; use e.g. 0.25")
    if mode not in ("auto", "simulation", "equation_error"):
        raise UserInputError(f"mode {mode!r} is unknown; use auto, simulation or equation_error")
    given_interpolation = input_interpolation
    input_interpolation = input_interpolation or model.input_interpolation
    if input_interpolation not in INPUT_INTERPOLATIONS:
        raise UserInputError(f"input interpolation {input_interpolation!r} is unknown; use "
                             f"{' or '.join(INPUT_INTERPOLATIONS)}")
    automatic = substeps == "auto"
    if automatic:
        substeps = max(initial_substeps(measurement), model.substeps)
    if (max_steps < 0 or shortlist < 1 or min_gain < 0 or iterations < 1 or not 0 < alpha < 1
            or not isinstance(substeps, int) or not 1 <= substeps <= MAX_SUBSTEPS
            or not 0 < convergence_tolerance < 1):
        raise UserInputError(f"max_steps >= 0, shortlist >= 1, min_gain >= 0, 0 < alpha < 1, "
                             "iterations >= 1, "
                             f"substeps \"auto\" or 1 … {MAX_SUBSTEPS} and 0 < "
                             "convergence_tolerance < 1 are required; fix the setting")
    library = effects() if library is None else dict(library)
    input_noise = None
    if denoise_inputs:
        measurement, input_noise = input_lines_only(measurement, alpha=alpha)
        if (given_interpolation is None and input_interpolation == "linear" and input_noise
                and all(entry["denoised"] for entry in input_noise.values())):
            input_interpolation = "bandlimited"  # a sum of lines: exact between samples
    structure = start = structure_of(model)
    chosen: list[Candidate] = []
    drifting = drifts(structure, symbols)
    chosen_mode = "equation_error" if mode == "equation_error" or (
        mode == "auto" and drifting) else "simulation"
    def problem_at(steps: int) -> FitProblem:
        return FitProblem(measurement, symbols, holdout=holdout, iterations=iterations,
                          substeps=steps, batch=shortlist + 1,
                          input_interpolation=input_interpolation, rate_band=drifting)

    problem = problem_at(substeps)
    lines = tuple(dict.fromkeys([*map(float, frequencies), *input_lines(problem.train)]))
    current = None
    steps, rankings, fits = [], [], []
    for round_number in range(max_steps + 1):
        release_memory()  # the last round's candidates and simulators
        _progress.stage(f"diagnosis: step {round_number + 1}: ranking the effects")
        context = problem.context(structure, lines)
        taken = {c.effect.name for c in chosen}  # an effect enters once
        ranked = rank_effects(problem.weak, structure, context,
                              {k: e for k, e in library.items() if k not in taken},
                              polish=round_number == 0)
        if round_number == 0:  # parameters found on the starting residual are kept
            library = {c.effect.name: _frozen(c) for c in ranked}
            problem.pool_lhs = tuple(dict.fromkeys(
                f for c in ranked for f in c.terms.state + c.terms.parametric))
            problem.pool_forcing = tuple(dict.fromkeys(f for c in ranked for f in c.terms.forcing))
        shortlisted = ranked[:shortlist] if round_number < max_steps else []
        candidates = [structure.plus(c.terms) for c in shortlisted]
        pairs = (rank_pairs(problem.weak, context, structure, ranked, shortlist)
                 if chosen_mode == "equation_error" and shortlisted else [])
        if chosen_mode == "simulation" and automatic:  # integrate the current model
            def fit_at(steps: int, previous: Model | None) -> Model:
                nonlocal problem, current
                if previous is not None:  # a finer step: the problem again (the old
                    # one's arrays released first), the last accepted structure refitted on it
                    pools = problem.pool_lhs, problem.pool_forcing
                    problem.simulator = None
                    problem = problem_at(steps)
                    problem.pool_lhs, problem.pool_forcing = pools
                    if current is not None:
                        current = fits[-1] = fit_structures(problem, chosen_mode, [structure])[0]
                _progress.stage(f"diagnosis: step {round_number + 1}: convergence check at "
                                f"{steps} substeps")
                return _integrated(current or problem.fit_equation_error([structure])[0],
                                   problem)  # the equation-error fit is converged

            fit_converged(fit_at, problem.train, substeps=None, first=substeps,
                          tolerance=convergence_tolerance, unsolved_ends=True, confirm=False)
            substeps = problem.substeps
        also = f" and {len(pairs)} pair(s)" if pairs else ""
        _progress.stage(f"diagnosis: step {round_number + 1}: fitting {len(candidates)} "
                        f"candidate effect(s){also} ({chosen_mode} mode) and testing them")
        if current is None:
            results = fit_structures(problem, chosen_mode, [structure] + candidates)
            current, results = results[0], results[1:]
            fits.append(current)
        else:
            results = fit_structures(problem, chosen_mode, candidates) if candidates else []
        if chosen_mode == "simulation" and results:
            order = rank_by_output_error(problem, shortlisted, results, min_gain)
            ranked = [shortlisted[i] for i in order] + ranked[len(shortlisted):]
            shortlisted, results = ranked[:len(order)], [results[i] for i in order]
        # the score test needs a current fit that simulates; where it does not, the
        # held-out test alone decides (any finite candidate beats a diverged model)
        scores = None
        if chosen_mode == "simulation" and results and math.isfinite(current.criterion):
            scores = score_statistics(problem, current, shortlisted, results)
        elif chosen_mode == "equation_error" and results:
            scores = equation_error_scores(problem, current, results)
        # one Bonferroni family: the singles and the pairs of the round (_diagnose_pairs)
        family = len(results) + len(pairs)
        tests = accepted(current.holdout, [r.holdout for r in results], alpha=alpha,
                         scores=scores, family=family)
        fit_and_test_pairs(problem, structure, current, pairs, family, alpha)
        rankings.append([{"effect": c.effect.name, "explained": c.explained,
                          "parameters": c.parameters, "evidence": c.evidence,
                          **({"predicted": c.predicted} if c.predicted else {}),
                          **({"test": tests[i]} if i < len(tests) else {})}
                         for i, c in enumerate(ranked)]
                        + [{"effect": f"{p.first.effect.name} + {p.second.effect.name}",
                            "explained": p.explained,
                            "parameters": {p.first.effect.name: p.first.parameters,
                                           p.second.effect.name: p.second.parameters},
                            "evidence": f"together explain {100 * p.explained:.1f} % of the "
                                        "equation-error residual energy", "test": p.test}
                           for p in pairs])
        passing = [i for i, test in enumerate(tests) if test["passed"]]
        # simulation: the best-ranked passing candidate; equation error: the passing single
        # or pair with the lowest charged held-out error
        penalised = [r.criterion * charge(c, min_gain) for r, c in zip(results, shortlisted)]
        paired = [p for p in pairs if p.test["passed"]]
        pair = min(paired, key=lambda p: pair_criterion(p, min_gain), default=None)
        if pair is not None and (not passing or pair_criterion(pair, min_gain) <
                                 min(penalised[i] for i in passing)):
            structure, current = _add_pair(pair, ranked, current, steps, chosen, fits)
            continue
        if not passing:
            break
        best = passing[0] if chosen_mode == "simulation" else min(passing,
                                                                   key=penalised.__getitem__)
        step = _step(shortlisted[best], ranked, current, results[best], chosen_mode)
        steps.append(step | {"test": tests[best]} | _ambiguity(
            problem, symbols, shortlisted, results, passing, best, alpha=alpha,
            simulate=chosen_mode == "simulation",
            settings={"input_interpolation": input_interpolation, "substeps": substeps}))
        structure, current = results[best].structure, results[best]
        chosen.append(shortlisted[best])
        fits.append(current)
    if chosen_mode == "equation_error" and chosen:
        fits[-1] = _repolished(problem, start, chosen, steps, lines)
    settings = {"holdout": holdout, "max_steps": max_steps, "shortlist": shortlist,
                "min_gain": min_gain, "alpha": alpha, "iterations": iterations,
                "input_interpolation": input_interpolation, "input_noise": input_noise}
    last = {}  # the last refit: its diagnosis and its whole-record problem

    def refit_at(count: int, previous=None) -> tuple[Model, Future | None]:
        """The chosen structures refitted on the whole record at ``count`` RK4 steps per
        sample (their diagnosis kept in ``last``): the last structure's model and, in
        simulation mode, its reference response for the convergence check, solved in the
        background while the residuals and the uncertainty are computed
        (:func:`gpjax._convergence.reference_started`)."""
        _progress.stage(f"diagnosis: refitting {len(fits)} model(s) on the whole record at "
                        f"{count} substeps")
        # the steps' evaluators, and a coarser rung's, are done with: their arrays go
        # before the whole record's are built
        problem.simulator = None
        last.pop("whole", None)
        release_memory()
        whole = FitProblem(measurement, symbols, holdout=0.0, iterations=iterations,
                           substeps=count, batch=len(fits),
                           input_interpolation=input_interpolation, rate_band=drifting)
        whole.pool_lhs, whole.pool_forcing = problem.pool_lhs, problem.pool_forcing
        structures = [fit.structure for fit in fits]
        refits = (consensus_refits(whole, structures)
                  if chosen_mode == "equation_error" and drifting
                  else fit_structures(whole, chosen_mode, structures))
        result = Diagnosis(mode=chosen_mode, steps=steps, rankings=rankings, fits=fits,
                           refits=refits, frequencies=lines, n_train=problem.n_train,
                           measurement=measurement, symbols=symbols,
                           settings=settings | {"substeps": count})
        _progress.stage("diagnosis: the refits' residuals, "
                        + ("convergence check and " if chosen_mode == "simulation" else "")
                        + "uncertainty")
        model = result.model()
        started = (reference_started(model, measurement) if chosen_mode == "simulation"
                   else None)
        result.noise = _noise(result, problem)
        result.unexplained = _unexplained(result, problem, alpha)
        if chosen_mode == "simulation":
            result.uncertainty = _uncertainty(result, whole)
        last.update(result=result, whole=whole)
        return model, started

    if chosen_mode != "simulation":  # an equation-error fit integrates nothing
        refit_at(substeps)
        last["result"].uncertainty = _equation_error_uncertainty(last["result"])
        return last["result"]
    # the structures are chosen; refit them on the whole record, converged
    _, checks, _ = fit_converged(refit_at, measurement, first=substeps,
                                 substeps=None if automatic else substeps,
                                 tolerance=convergence_tolerance)
    result = last["result"]
    result.convergence = checks[-1].to_json()
    return result


def _uncertainty(result: Diagnosis, whole: FitProblem) -> Uncertainty:
    """The final fit's constants' intervals on the whole record, from the sensitivities
    the score test uses (the fit's free parameters)."""
    fit = result.after
    jacobian, positions, _, base = sensitivities(whole, fit)
    covariance, dof = sandwich_covariance(fit.simulated - whole.measurement.response,
                                          jacobian[:, positions])
    evaluator = whole.simulator_for([fit.structure]).full
    free = types.SimpleNamespace(columns=np.array(base), layout=evaluator.layout)
    flat = evaluator.layout.pack(to_population([fit.coefficients], evaluator))[0]
    return Uncertainty(names=tuple(model_names(free, result.model(), evaluator,
                                               [fit.coefficients])),
                       values=flat[base], covariance=covariance, dof=dof,
                       n_samples=whole.measurement.n_samples)


def _ambiguity(problem: FitProblem, symbols: Symbols, shortlisted: list[Candidate],
               results: list[Fit], passing: list[int], best: int, *, alpha: float,
               simulate: bool, settings: dict) -> dict:
    """The passing candidates this record cannot separate from the accepted one and, in
    simulation mode, the input change that would (:mod:`gpjax._diagnose_ambiguity`); empty
    when the accepted effect predicts better than every other."""
    tied = indistinguishable(results, passing, best, alpha=alpha)
    if not tied:
        return {}
    out = {"indistinguishable": [{"effect": shortlisted[i].effect.name, "p_value": p,
                                  "rms_holdout": results[i].metrics.get("rms_holdout")}
                                 for i, p in tied]}
    if simulate:
        models = [results[i].model(symbols, {}, **settings) for i in [best] + [i for i, _ in tied]]
        noise = float(np.sqrt(np.mean(results[best].holdout ** 2)))
        out["separating_input"] = separating_input(models, problem.measurement.time,
                                                   problem.measurement.inputs, noise)
    return out


def _equation_error_uncertainty(result: Diagnosis) -> Uncertainty | None:
    """The final equation-error fit's constants' intervals: the sandwich covariance
    (:mod:`gpjax._uncertainty`) of the weak-form least squares it solved, over its sequence
    of windows; ``None`` where that fit is not finite. The interval does not count the bias
    that noise in the smoothed derivatives puts into the weak-form regressors."""
    fit = result.after
    s = fit.structure
    matrix, target, normalise = design(fit.weak, s.lhs, s.forcing)
    solution = scaled_lstsq(matrix, target)
    if not np.all(np.isfinite(solution)):
        return None
    covariance, dof = sandwich_covariance(target - matrix @ solution, matrix)
    by_feature = {feature: name for name, (_, part, feature)
                  in result.model().constant_names().items() if part != "mass"}
    names = (["m"] if normalise else []) + [by_feature[str(f)] for f in s.lhs] + [
        by_feature[str(g)] for g in s.forcing if not (normalise and g == fit.weak.u0)]
    return Uncertainty(names=tuple(names), values=solution, covariance=covariance, dof=dof,
                       n_samples=result.measurement.n_samples)


def _integrated(fit: Fit, problem: FitProblem) -> Model:
    """``fit``'s constants and initial state as a model at the problem's step count and
    input interpolation, for the integration check on the estimation part."""
    return Model.from_coefficients(problem.symbols, fit.coefficients,
                                   input_interpolation=problem.input_interpolation,
                                   substeps=problem.substeps)


def _noise(d: Diagnosis, problem: FitProblem) -> dict:
    """The noise floor of the final and the starting residual (simulation mode), or of the
    measured response about its smoothed value (equation-error mode, whose residual is a
    force)."""
    band = problem.band_hz
    if d.mode != "simulation":
        floor = noise_floor(d.measurement.response - problem.derivatives.x, d.measurement.dt,
                            band)
        return {"response": floor}
    floors = {when: noise_floor(d.measurement.response - fit.simulated, d.measurement.dt, band)
              for when, fit in (("after", d.after), ("before", d.before))}
    if floors["after"] is not None:  # the measured input's noise in the final residual
        count_input_noise(floors["after"], input_noise_response(_integrated(d.after, problem),
                                                                d.measurement), 0)
    return floors


def _unexplained(d: Diagnosis, problem: FitProblem, alpha: float) -> dict | None:
    """The final residual described, where it stays far above its noise floor (simulation
    mode: :data:`FAR_ABOVE` × σ̂, and the measured input's noise rung through the model
    where it is counted, :func:`gpjax._system_diagnose.gate_ratio`; and a significant
    in-band excess)."""
    floor = (d.noise or {}).get("after")
    if floor is None or gate_ratio(floor) < FAR_ABOVE or floor["p_excess"] >= alpha:
        return None
    noise = list((d.settings["input_noise"] or {}).values())
    lines = ([f for entry in noise for f in entry["lines_hz"]]
             if noise and all(entry["denoised"] for entry in noise)
             else input_lines(d.measurement))
    return describe_residual(d.measurement.response - d.after.simulated,
                             x=problem.derivatives.x, x_dot=problem.derivatives.x_dot,
                             dt=d.measurement.dt, input_lines=lines, alpha=alpha)


def _repolished(problem: FitProblem, start: Structure, chosen: list[Candidate],
                steps: list[dict], lines: tuple[float, ...]) -> Fit:
    """Equation-error mode: the fit of the final structure with the chosen effects'
    numeric nonlinear parameters searched again, jointly, on the whole record
    (:func:`gpjax._diagnose_pairs.joint_parameters`): each was set in the round that found
    it, before the later effects were in the model (a friction smoothing chosen while an
    offset is missing absorbs part of it). ``steps`` get the new parameters."""
    structure, polished = joint_parameters(problem.weak_full, problem.context(start, lines),
                                           start, chosen)
    for step, candidate in zip(steps, polished):
        step["parameters"] = step["parameters"] | candidate.parameters
    return fit_structures(problem, "equation_error", [structure])[0]


def _add_pair(pair: Pair, ranked: list[Candidate], current: Fit, steps: list[dict],
              chosen: list[Candidate], fits: list[Fit]) -> tuple[Structure, Fit]:
    """Add an accepted pair (:mod:`gpjax._diagnose_pairs`) as two steps, the member better
    alone first (its fit alone), then the pair, each with the pair's test; returns the new
    (structure, fit)."""
    for candidate, other, before, after in ((pair.first, pair.second, current, pair.alone[0]),
                                            (pair.second, pair.first, pair.alone[0], pair.fit)):
        step = _step(candidate, ranked, before, after, "equation_error")
        step["evidence"] += (f"; accepted with {other.effect.name}: together "
                             f"{100 * pair.explained:.1f} %")
        steps.append(step | {"test": pair.test, "pair": [pair.first.effect.name,
                                                         pair.second.effect.name]})
        chosen.append(candidate)
        fits.append(after)
    return pair.fit.structure, pair.fit


def _frozen(candidate: Candidate) -> Effect:
    """The candidate's effect with its parameters fixed (a one-point grid)."""
    parameters = dict(candidate.parameters)
    return dataclasses.replace(candidate.effect, grid=lambda context: [parameters])


def _step(candidate: Candidate, ranked: list[Candidate], before: Fit, after: Fit,
          mode: str) -> dict:
    added = candidate.terms.state + candidate.terms.parametric + candidate.terms.forcing
    values = after.coefficients.state | after.coefficients.forcing
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

