"""Choosing the reported model: the Pareto front's models, simplified by a held-out test,
and the Pareto table.

Least-squares coefficients make every additive term free to help a little, and with
functions that carry inner constants several structures fit a record to its noise floor:
k·x + K·sin(a·x + b) with huge cancelling k and K mimics k·x + k₃·x³ (x − sin x ≈ x³/6),
405·x³ + 39.6·sin(1.01·x) mimics x³ + x. Their objectives on the record tie, so the
objective alone cannot choose; what separates them is what they spend. After the run a
local search starts from each model of the Pareto front and walks to simpler neighbours
(:mod:`gpjax._select_moves`: removals, swaps, snapping an inner constant to its simple
value, a function for powers and back).

**Complexity** is the number of fitted constants (:attr:`Record.complexity`): one per term
and m, plus the inner constants (sin/cos(a·z + b) two, tanh(a·z) and exp(a·z) one), less
those held at a snapped value; then the terms, then the held constants (a snapped sin(x)
still assumes a scale that x³ does not). So sin(a·x + b) costs 3, x³ costs 1: a count of
what the data must determine, not of how the equation is written. A smoothed sign's held
scale is not a held constant: sign(z) has none, and tanh(z/ε) is how it is integrated
(:mod:`gpjax._sign_width`), so c·sign(x') and c·x'·|x'| are equally complex. Counted, it
made x'·|x'| the simpler of the two, and on ``stribeck_resolved`` (suite seed 4) the walk
left the Stribeck law for x'·|x'| in place of its Coulomb level (the law predicted the
held-out windows better, but not significantly: p = 0.08), and the run ended at Coulomb +
viscous + x'·|x'|.

**The test.** A simpler neighbour replaces the current model unless the current model
predicts held-out data significantly better at level ``alpha``, by the diagnosis's
Diebold–Mariano test (:func:`gpjax._diagnose_acceptance.predictive_test`: one-sided,
batch means, Wilcoxon). The held-out residual is the diagnosis's equation-error one
(:func:`gpjax._diagnose_fits.blocked_cv_residual`): the weak-form windows in five
contiguous blocks, each predicted by the least-squares coefficients of the windows that
share no sample with it, so every block is held out once and all of the record is tested.
Why the equation error and not the simulated response: the simulation is driven by the
*measured* input, whose noise rings through the model's dynamics, and a needless term can
cancel part of that ringing in every batch of a held-out tail — on Duffing (seed 0 of the
physics suite, 1 % input noise) a constant force beat the true structure at p = 0.0004 on
the simulated tail (p = 0.04 with the noise-free input, p = 0.28 on the equation error).
In the equation error the input noise is an additive force that no term can predict.
Inner constants (the a, b of sin(a·x + b)) keep their values from the fit to the whole
record; per block only the coefficients are refitted — a head start for the model with
more inner constants, so the test errs towards keeping the current model.

**Where the test takes x'.** A feature nonlinear in x' (a sign, x'·|x'|, a Stribeck bump)
needs x' at every sample. The fit's weak form takes it from the smoothed measurement
(Savitzky–Golay over the response's band), which blurs what is sharp in velocity: a
reversal, a bump a quarter of RMS x' wide, a stick phase where the true x' is zero and the
estimate is noise. There every friction law's equation error is mostly the estimate's
error: on ``stribeck_resolved`` (suite seeds 0–2) the Stribeck law predicted the held-out
windows better than Coulomb + viscous at p = 0.90, 0.14, 0.03 only. So the test evaluates
those features at the simulated velocity of the walk's start (:func:`selection_weak_form`;
in :func:`select`, the best-fitting front member for every walk): noise-free, sharp where
the model sticks, and the same for both models of a comparison (p = 0.014, 0.0005, 0.001
on the same records). Not neutral: it leans towards the reference's own features (README,
known limitations); the simpler model's velocity, a score test's null, would not. This is the instrumental-variable
idea of system identification — a noise-free state simulated by an auxiliary model in
place of the noisy measured one. x and the linear x' still come from the measured response
(the latter by integration by parts), and the coefficients per block are still the least
squares of the other blocks.

The null hypothesis is the simpler model, so an adequate simpler model is kept with
probability ≥ 1 − α at each move: the constants a model keeps are the ones the held-out
data demonstrably need, not those under a tolerance on the objective. No correction over
neighbours: each test is of its own simpler model, and a correction would only make the
current model harder to keep. When no simpler neighbour qualifies, a neighbour as complex
or more must earn its place as the diagnosis's candidates do: it replaces the current
model when it predicts the held-out part significantly better, at level ``alpha``
Bonferroni-corrected over those neighbours (so a GP best that lacks the physics, x where
sin x belongs, is still corrected; of two stand-ins that fit equally well the walk keeps
the one it reached, not a coin flip on the noise). Neighbours are tried in the order
(complexity, objective on the whole record) and the first that qualifies is taken, so the
walk goes to the simplest model the test cannot reject. A forward move passes a test that
the way back fails (p·m < α implies p < α) and no model is visited twice, so it ends.
Neighbours are refined as the test reaches them, one complexity at a time while simpler
than the current model, then the rest together: a step that takes a simpler neighbour
refines none more complex than it. Order and outcome are those of refining all first; the
cost is not (saturating spring, suite seed 3: 173 models refined in the whole fit instead
of 1,088; ``benchmarks/select_cost.json``).

**Converged constants before a walk ends.** Neighbours are refined one round
(``refine_iterations`` Levenberg–Marquardt steps from their least-squares start), enough
to rank them but not always to bring a swapped function's inner constant into its basin:
on the saturating spring (suite seed 4) the swap sin → tanh from the stand-in
k·x + K·sin(a·x) stopped at tanh(2.54·x), objective 0.29 against the stand-in's 0.158, and
the walk ended at the stand-in (16 % error on a larger input); refined further, the scale
goes to 2.0 and the objective below the stand-in's, and the walk reaches k·tanh(x/a).
So when no neighbour replaces the current model, the simpler neighbours that were refined
and the current model itself are refined to convergence (:meth:`Fitness.refine` with
``to_convergence``: rounds until one lowers the objective by less than 0.1 %) and the test
is run again; only then does the walk end. The test compares models at their best
constants on the record, not at a step count. In a walk from another front member, a
current model whose objective exceeds :data:`REFINE_WITHIN` × the best member's is left as
it is, as such neighbours are: it competes with no end (on the Duffing record of issue 43
three refinement calls, 1 s, went to converging a model 100× worse than the best); so is
such an end in the walk among the ends (there m·x'' = 0 was converged, twice).

**Where the walk starts.** A walk only removes, swaps and replaces terms, so it cannot
reach a simpler law that is not a few moves from its start: from the stand-in
k·x + k₃·x³ + k₂·x·|x| + K·tanh(9.55·x) (saturating spring, held-out seed 7, the best fit
of its run) no sequence of adequate one-round-refined neighbours led to k·tanh(x/a),
while from two other members of the same front the walks ended there (refined to
convergence, the stand-in's own walk now gets there too; the test in
``tests/test_select.py`` keeps that case). So a walk starts from every member of the
refined Pareto front (the best model of each complexity), and the ends compete by the
same rule, starting from the end of the best-fitting member's walk: a simpler end replaces it unless it predicts the held-out part
significantly better, an end as complex or more replaces it if it predicts significantly
better (Bonferroni over those ends). A simpler end must also not simulate significantly
worse: the same test on the two models' simulated residuals over the record. The equation
error is weak where a model's sticking phases matter, and there a distant end can pass it
while its response is far off (Coulomb + viscous, suite seed 1: the linear model's walk
ends at k·x + K·tanh(0.53·x'), objective 0.526, which the equation-error test could not
tell from the truth at 0.173). The guard is one-sided by design: in-sample it favours the
more complex model, so it can only keep the best's end, never add a term; where both tests
let a simpler end through, it replaces the best's end. The measured input's noise rings
through every simulation, and a model that rings less at it fits better by that much:
each model's share of it is taken out of its mean square before the test
(:func:`input_noise_shares`). The walks share the scored and refined
records, and the other walks refine only neighbours within :data:`REFINE_WITHIN` of the
best member's objective (a neighbour of a free oscillator, say, that fits five times worse
than the best model found competes with no end).

**The walks run in lockstep.** Every compiled call of the selection costs a fixed ~0.05 s
on an 8,000-sample record (a scan of 16,000 RK4 stages; ``benchmarks/call_cost.json``)
beside ~1.4 ms per model, and a walk's steps are sequential: scoring a step's neighbours,
then refining them a complexity at a time, each refinement followed by a scoring of the
refined constants. Walked one after another, the front's walks made 47 scoring calls and
15 refinements on a pendulum record, most of them carrying one or two models (in lockstep:
26 and 10). So the walks advance together (:func:`_lockstep`): each is a generator that
yields what it needs scored or refined next, and one tick serves every live walk's
requests as one scoring batch and one refinement. The ranks stay: a walk whose path meets
an earlier-ranked walk's path (the best member's first) stops without an end — from the
shared model on it would retrace the other — where walked in turn a member on an earlier
walk's path started none.

A difference from the paper, which reports the best tree as found.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ._coefficients import Coefficients
from ._diagnose_acceptance import predictive_test
from ._diagnose_fits import blocked_cv_residual
from ._diagnose_noise import PROPORTIONAL_FROM, models_input_noise
from ._evaluator import OK
from ._fitness import Fitness, Record
from ._select_moves import move_key, neighbours
from ._weak_form import WeakForm, design

#: Neighbours are refined on the whole record when their least-squares start scores within
#: this factor of the current model's objective (a cost cut: a start five times worse is
#: not a competitor after a 10-step refinement).
REFINE_WITHIN = 5.0


def held_out_residual(fitness: Fitness, record: Record, weak: WeakForm | None = None
                      ) -> np.ndarray:
    """Blocked cross-validated weak-form residual of ``record``'s features, one value per
    window (force units; module docstring), on ``weak`` (default: the fit's weak form)."""
    weak = fitness.weak_form if weak is None else weak
    c = record.coefficients
    matrix, target, _ = design(weak, tuple(c.state), tuple(c.forcing))
    return blocked_cv_residual(matrix, target, weak)


def selection_weak_form(fitness: Fitness, reference: Record) -> WeakForm:
    """The weak form of the selection's test: the fit's windows, with the features
    nonlinear in x' evaluated at ``reference``'s simulated velocity (central differences of
    its noise-free response, m/s) instead of the smoothed measurement's (module
    docstring). The fit's own weak form if the simulation is not finite."""
    responses, _ = fitness.evaluator.simulate(fitness.population([reference]))
    position = np.asarray(responses[0], dtype=float)
    if not np.all(np.isfinite(position)):
        return fitness.weak_form
    velocity = np.gradient(position, fitness.measurement.dt, edge_order=2)
    return WeakForm(fitness.measurement, velocity, fitness.weak_form.half_width)


@dataclasses.dataclass(frozen=True)
class _Score:
    """A walk's request: score these forms at their least-squares start
    (:meth:`Fitness.score_forms`'s arguments)."""

    forms: dict
    held: dict
    kept: dict


@dataclasses.dataclass(frozen=True)
class _Refine:
    """A walk's request: refine these records one round, or to convergence."""

    records: list
    to_convergence: bool = False


def _serve(fitness: Fitness, requests: list) -> None:
    """Serve one tick's requests of every live walk together: one scoring batch of the
    forms not yet scored, one refinement round, one refinement to convergence."""
    forms, held, kept, rounds, converge = {}, {}, {}, {}, {}
    for request in requests:
        if isinstance(request, _Score):
            for key, form in request.forms.items():
                if key not in fitness.records and key not in forms:
                    forms[key] = form
                    held[key], kept[key] = request.held[key], request.kept[key]
        else:
            chosen = converge if request.to_convergence else rounds
            chosen.update((id(r), r) for r in request.records)
    if forms:
        fitness.score_forms(forms, held, kept)
    if rounds:
        fitness.refine(list(rounds.values()))
    if converge:
        fitness.refine(list(converge.values()), to_convergence=True)


def _drive(fitness: Fitness, walk):
    """Run one walk (a generator of :func:`_walk`) to its end; returns what it returns."""
    try:
        while True:
            _serve(fitness, [walk.send(None)])  # send(None) also starts it
    except StopIteration as done:
        return done.value


def _lockstep(fitness: Fitness, walks: list) -> list:
    """Run ``walks`` ((generator, path) pairs, in rank order) together: each tick serves
    the requests of every live walk at once (:func:`_serve`). A walk whose path meets an
    earlier walk's stops without an end (module docstring). Returns each walk's (end,
    path), or None for one that stopped."""
    results, live = [None] * len(walks), {}

    def advance(i: int) -> None:  # send(None) also starts a walk
        try:
            live[i] = walks[i][0].send(None)
        except StopIteration as done:
            results[i] = done.value
            live.pop(i, None)

    for i in range(len(walks)):
        advance(i)
    while live:
        _serve(fitness, list(live.values()))
        for i in sorted(live):
            advance(i)
        met = set()
        for i, (walk, path) in enumerate(walks):
            keys = {r.key for r in path}
            if i in live and keys & met:
                walk.close()
                del live[i]
            met |= keys
    return results


def _neighbour_records(fitness: Fitness, current: Record, simpler: bool):
    """The neighbours of ``current`` that are simpler than it (``simpler``) or not, scored
    (new ones in one batch) at their least-squares start; :func:`_first_replacing` refines
    them as its test reaches them, and asks for the others only once no simpler one
    replaces ``current`` (a step down never needs them). A generator: yields the scoring
    request (:class:`_Score`) and returns the records."""
    tree_mode = fitness.config.coefficients == "tree"
    mass = current.coefficients.mass
    keys, new, held, kept = [], {}, {}, {}
    for m in neighbours(fitness, current):
        form = m.form(mass)
        shape = Record(key="", valid=True, coefficients=Coefficients.from_canonical(form),
                       held=m.held, held_signs=fitness.held_signs(m.held))
        if (shape.complexity < current.complexity) != simpler:
            continue
        key = move_key(m, mass, tree_mode)
        keys.append(key)
        if key not in fitness.records:
            new[key], held[key], kept[key] = form, m.held, m.kept
    if new:
        yield _Score(new, held, kept)
    return [fitness.records[k] for k in dict.fromkeys(keys)]


def _refine_below(fitness: Fitness, current: Record, refine_below: float) -> float:
    """The objective below which ``current``'s neighbours are refined: ``refine_below``, and
    within :data:`REFINE_WITHIN` of the current model's (tree mode: no second bound)."""
    # Tree mode always refines: with no least-squares refit a dropped term's share of the
    # fit shifts the phase until Levenberg–Marquardt moves the other constants.
    tree_mode = fitness.config.coefficients == "tree"
    return min(refine_below, math.inf if tree_mode else REFINE_WITHIN * current.objective)


def select(fitness: Fitness, front: list[Record], alpha: float) -> tuple[Record, list[Record]]:
    """The reported model: a walk from every member of the (refined) Pareto ``front``, in
    lockstep, then the same walk among the walks' ends, from the end of the best-fitting
    member's walk (module docstring); every test evaluates x'-features at the best
    member's simulated velocity (:func:`selection_weak_form`). Returns the final record
    and that last walk's path."""
    best, *others = sorted(front, key=lambda r: (r.objective, r.complexity))
    weak = selection_weak_form(fitness, best)
    walks = []
    for start, below in [(best, math.inf)] + [(r, REFINE_WITHIN * best.objective)
                                              for r in others]:
        path = [start]
        walks.append((_walk(fitness, start, alpha, path, weak=weak, refine_below=below), path))
    ends = {}
    for result in _lockstep(fitness, walks):
        if result is not None:
            ends.setdefault(result[0].key, result[0])
    first = walks[0][1][-1]
    return _drive(fitness, _walk(fitness, first, alpha, [first],
                                 options=lambda current: list(ends.values()),
                                 refine_below=REFINE_WITHIN * best.objective,
                                 simulated=True, weak=weak))


def simplify(fitness: Fitness, best: Record, alpha: float, *, options=None,
             refine_below: float = math.inf, simulated: bool = False,
             weak: WeakForm | None = None) -> tuple[Record, list[Record]]:
    """Walk from ``best`` to the simplest model the held-out test at level ``alpha`` cannot
    reject (module docstring); ``options(current)`` gives the models a step may take, as
    they are (default: the current model's neighbours, scored, and refined where their
    objective is below ``refine_below`` too); with ``simulated`` a simpler model must also
    not be significantly worse on the simulated response (the ends' guard); ``weak``: the
    test's weak form (default :func:`selection_weak_form` of ``best``). Returns the final
    record and the path taken."""
    weak = selection_weak_form(fitness, best) if weak is None else weak
    return _drive(fitness, _walk(fitness, best, alpha, [best], options=options,
                                 refine_below=refine_below, simulated=simulated, weak=weak))


def _walk(fitness: Fitness, best: Record, alpha: float, path: list[Record], *, weak: WeakForm,
          options=None, refine_below: float = math.inf, simulated: bool = False):
    """:func:`simplify`'s walk as a generator: yields its scoring and refinement requests
    (:class:`_Score`, :class:`_Refine`; served by :func:`_drive` or :func:`_lockstep`),
    appends each model it steps to to ``path`` (which starts as ``[best]``), and returns
    (final record, path)."""
    current, seen = best, {best.key}
    while True:
        if options is None:
            candidates = yield from _neighbour_records(fitness, current, simpler=True)
            below = _refine_below(fitness, current, refine_below)

            def others(current=current):
                return (yield from _neighbour_records(fitness, current, simpler=False))
        else:
            everything = options(current)
            below = -math.inf
            candidates = [r for r in everything if r.complexity < current.complexity]

            def others(current=current, everything=everything):
                yield from ()
                return [r for r in everything if r.complexity >= current.complexity]
        candidates = [r for r in candidates if r.key not in seen]

        def rest(seen=seen, others=others):
            return [r for r in (yield from others()) if r.key not in seen]

        base = held_out_residual(fitness, current, weak)
        chosen = yield from _first_replacing(fitness, candidates, rest, current, base, alpha,
                                             simulated, below, weak)
        if chosen is None:
            # Before the walk ends here: the simpler neighbours' constants (and the current
            # model's) refined to convergence, then the same test again — a swapped
            # function's inner constant can stop short of its basin after one round.
            # A model above ``refine_below`` (REFINE_WITHIN × the best member's objective),
            # the current one or a candidate (an end of a walk from a poor member), is not
            # converged: like such a neighbour, it competes with no end.
            unconverged = [r for r in candidates
                           if r.refined and not r.converged and r.objective <= refine_below]
            if not unconverged:
                return current, path
            near = [current] if current.objective <= refine_below else []
            yield _Refine(unconverged + near, to_convergence=True)
            base = held_out_residual(fitness, current, weak)
            chosen = yield from _first_replacing(fitness, candidates, rest, current, base,
                                                 alpha, simulated, below, weak)
            if chosen is None:
                return current, path
        seen.add(chosen.key)
        current = chosen
        path.append(current)


def _first_replacing(fitness: Fitness, simpler: list[Record], rest, current: Record,
                     base: np.ndarray, alpha: float, simulated: bool,
                     refine_below: float, weak: WeakForm):
    """The first candidate (valid ones, in the order (complexity, objective)) that replaces
    ``current`` (held-out residual ``base``) by :func:`_replaces`, and with ``simulated`` by
    the ends' guard too; None if none does. The candidates are ``simpler`` (those simpler
    than ``current``), then ``rest()`` (the others, scored only if none of ``simpler``
    replaces it). Candidates whose objective is below ``refine_below`` are refined as the
    test reaches them: one complexity at a time while simpler than ``current``, then all
    the others together (the Bonferroni count needs them all), so none more complex than
    the one taken is refined — the order and the outcome are those of refining all
    first. A generator: yields the refinement requests (:class:`_Refine`)."""
    levels = sorted({r.complexity for r in simpler})
    groups = [[r for r in simpler if r.complexity == c] for c in levels] + [rest]
    for group in groups:
        if callable(group):
            group = yield from group()
        pending = [r for r in group if r.valid and not r.refined and r.objective <= refine_below]
        if pending:
            yield _Refine(pending)
        ready = sorted((r for r in group if r.valid and r.status == OK),
                       key=lambda r: (r.complexity, r.objective))
        peers = sum(r.complexity >= current.complexity for r in ready)
        chosen = next((r for r in ready if _replaces(
            r, held_out_residual(fitness, r, weak), current, base, alpha, peers) and not (
                simulated and r.complexity < current.complexity
                and _simulates_better(fitness, current, r, alpha))), None)
        if chosen is not None:
            return chosen
    return None


def _simulates_better(fitness: Fitness, current: Record, simpler: Record, alpha: float) -> bool:
    """Whether ``current``'s simulated response fits the measured one significantly better
    than ``simpler``'s at level ``alpha`` (:func:`simulates_better` on the two refined
    models' simulated residuals over the whole record; module docstring)."""
    population = fitness.population([simpler, current])
    responses, _ = fitness.evaluator.simulate(population)
    measured = fitness.measurement.response
    shares = input_noise_shares(fitness.evaluator, population)
    return simulates_better(responses[0] - measured, responses[1] - measured, alpha,
                            offset=float(shares[0] - shares[1]))


def simulates_better(simpler: np.ndarray, current: np.ndarray, alpha: float, *,
                     offset: float = 0.0) -> bool:
    """The selection's guard: whether the residual ``current`` (a simulated response's,
    over the whole record) has a significantly lower mean square than ``simpler`` at level
    ``alpha``, by the held-out test's Diebold–Mariano test
    (:func:`gpjax._diagnose_acceptance.predictive_test`; batch means, so a residual's
    autocorrelation, the measured input's noise ringing through the dynamics, counts), the
    difference of their input-noise shares (``offset``, :func:`input_noise_shares`) taken
    out first."""
    return predictive_test(simpler, current, offset=offset)["p_value"] < alpha


def input_noise_shares(evaluator, population, scale=1.0) -> np.ndarray:
    """(P,) each model's share of its simulated residual's mean square that is the measured
    inputs' noise rung through it: the mean square of its response to that noise
    (:func:`gpjax._diagnose_noise.models_input_noise`), each coordinate divided by
    ``scale`` (its (D,) or one scale) and summed. Errors in variables: the residual of a
    simulation driven by the measured input holds the model's response to the input's noise,
    so a model that rings less at that noise (a needless damper on a lightly damped mode)
    fits better by that much, not by its physics; comparing mean squares less these shares
    removes that bias. Zeros where no input has a noise floor, or where any model's response
    is not proportional to the noise (:data:`gpjax._diagnose_noise.PROPORTIONAL_FROM`:
    there the share is not a linear propagation)."""
    rms, scaling = models_input_noise(evaluator, population)
    if not rms.size or np.any(scaling < PROPORTIONAL_FROM):
        return np.zeros(np.shape(population.mass)[0])
    return np.sum((rms / scale) ** 2, axis=1)


def _replaces(record: Record, residual: np.ndarray, current: Record, base: np.ndarray,
              alpha: float, peers: int) -> bool:
    """Whether a neighbour replaces the current model (module docstring); ``peers``: the
    neighbours at least as complex as the current model (the Bonferroni count)."""
    if record.complexity < current.complexity:
        return predictive_test(residual, base)["p_value"] >= alpha
    return predictive_test(base, residual)["p_value"] * peers < alpha


def pareto_front(records: list[Record]) -> list[Record]:
    """For each complexity (:attr:`Record.complexity`), the best record if it beats every
    simpler one."""
    front: list[Record] = []
    for record in sorted((r for r in records if r.valid and r.status == OK),
                         key=lambda r: (r.complexity, r.objective)):
        if not front or (record.complexity > front[-1].complexity
                         and record.objective < front[-1].objective):
            front.append(record)
        elif record.complexity == front[-1].complexity and record.objective < front[-1].objective:
            front[-1] = record
    return front
