"""Converged sign smoothing: the reported model must not depend on its sign's width.

A sign(z) of a candidate is integrated as tanh(z/ε), ε a fraction (``sign_width``, default
:data:`gpjax._features.SIGN_WIDTH`) of RMS z (:mod:`gpjax._features`). With ε > 0 a
sticking mass creeps and a reversal is rounded, and the constants fitted at that width
make up for it: on ``stribeck_resolved`` (suite seed 2, the true law refitted) the
Stribeck velocity came out at 0.449 with ε = 1 % of RMS x' and 0.482 at 0.25 % (truth 0.5;
``python benchmarks/sign_width.py --first-seed 2 --seeds 1 --refit``). That is the
smoothing's error absorbed into the constants, as a coarse RK4 step's would be
(:mod:`gpjax._convergence`), and it is checked the same way:

* **Check** (:func:`check_width`): the reported model's reference response with every
  smoothed sign narrowed :data:`NARROWING` times, its constants unchanged, against its
  reference response as fitted. The RMS difference must stay below the convergence
  tolerance (default 1 %) of the model's RMS residual against the data. Passing means a
  sharper sign would not change what the model predicts, so a refit at it would not move
  the constants either: the objective is the same function of them.
* **Refit** (:func:`narrowed`, in :meth:`gpjax.Identifier.fit`): otherwise ε is divided by
  :data:`NARROWING` to the power k — the reported model's smoothed signs rewritten and held at
  the narrower scale — at the RK4 steps per sample that the narrower sign needs by the
  step check (:func:`narrowed_steps`: measured on the model with the sharper sign), and
  the reported model alone is refitted to convergence (a sign's width moves the constants
  of the models that have one, not the ranking). k is the number of narrowings the rate
  below projects, at least one and at most those left: the constants barely move between
  widths, and every intermediate refit is a fit at more steps (on a Coulomb + viscous
  record of 8,000 samples one at 12 steps per sample took 2.5 minutes). Only with
  ``substeps="auto"``, at most :data:`MAX_NARROWINGS` narrowings in all, and none to a
  sign that no step count up to the cap integrates stably where the mass sticks
  (:func:`gpjax._convergence.stable_substeps`).
* **Rate** (:attr:`WidthCheck.narrowings_needed`): the check also compares the sign
  NARROWING and NARROWING² times narrower, so it knows how fast its change falls and
  how many narrowings the check needs (geometric convergence, as the step check projects
  its order). Where the change does not fall as the sign narrows the loop stops, and a
  model left unconverged is reported with a warning that gives the rate, like an
  unconverged step.

A smoothed sign is a tanh(a·z) whose scale is the width's, a = 1/(ε·RMS z) (a tanh law
whose scale was fitted is a law of its own and stays). Beyond the paper, which has no
discontinuous functions.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import sympy as sp

from ._coefficients import Coefficients
from ._convergence import MAX_SUBSTEPS, check_model, needed_substeps
from ._fitness import Fitness, Record, structure_key
from ._model import Model

#: Factor by which each refit divides the sign's width.
NARROWING = 4
#: Most narrowings of a run: the narrowest sign is NARROWING³ = 64 times narrower than
#: the default (ε = 0.016 % of RMS z), the depth the step cap of 64 allowed when every
#: narrowing multiplied the steps by NARROWING.
MAX_NARROWINGS = 3


@dataclasses.dataclass(frozen=True)
class WidthCheck:
    """Outcome of one check of the reported model's sign width.

    Attributes:
        fraction: the width ε as a fraction of RMS z (z the sign's variable).
        difference_rms: RMS difference of the reference responses at ε and ε/NARROWING.
        rms_reference: RMS residual of the model's reference response against the data.
        ratio: ``difference_rms / rms_reference`` (inf if a solve failed).
        tolerance: the largest ratio accepted.
        next_ratio: the same ratio one narrowing further, the constants unchanged: the
            responses at ε/NARROWING and ε/NARROWING² (what the check after one refit
            would see, were the constants not to move).
    """

    fraction: float
    difference_rms: float
    rms_reference: float
    ratio: float
    tolerance: float
    next_ratio: float = math.nan

    @property
    def converged(self) -> bool:
        return self.ratio < self.tolerance

    @property
    def rate(self) -> float:
        """Factor by which one narrowing divides the ratio (``ratio / next_ratio``; NaN
        if either is not finite)."""
        if not (math.isfinite(self.ratio) and math.isfinite(self.next_ratio)):
            return math.nan
        return self.ratio / self.next_ratio if self.next_ratio > 0 else math.inf

    @property
    def narrowings_needed(self) -> float:
        """Narrowings until the check passes, projected from :attr:`rate` (geometric
        convergence, as the steps' check projects its own order): 0 when converged, inf
        when the ratio does not fall as the sign narrows."""
        if self.converged:
            return 0
        rate = self.rate
        if not rate > 1:
            return math.inf
        if math.isinf(rate):
            return 1
        return math.ceil(math.log(self.ratio / self.tolerance) / math.log(rate))

    def to_json(self) -> dict:
        return dataclasses.asdict(self) | {"converged": self.converged}


def _sign_replacements(features, fitness: Fitness, factor: float) -> dict[sp.Expr, sp.Expr]:
    """tanh(a·z) → tanh(factor·a·z) for each smoothed sign (a = the width's scale, to
    1e-9 relative) inside ``features``."""
    out = {}
    for role, z in (("x", fitness.symbols.x), ("x_dot", fitness.symbols.x_dot)):
        scale = fitness.sign_scale(role)
        for feature in features:
            for tanh in feature.atoms(sp.tanh):
                a = (tanh.args[0] / z)
                if a.is_Number and math.isclose(float(a), scale, rel_tol=1e-9):
                    out[tanh] = sp.tanh(sp.Float(factor * float(a)) * z)
    return out


def narrowed_coefficients(coefficients: Coefficients, fitness: Fitness,
                          factor: float) -> Coefficients | None:
    """``coefficients`` with every smoothed sign (module docstring) ``factor`` times
    narrower, the values unchanged; None if they hold none."""
    replacements = _sign_replacements(coefficients.state, fitness, factor)
    if not replacements:
        return None
    return coefficients.replace(state={f.xreplace(replacements): v
                                       for f, v in coefficients.state.items()})


def narrowed(record: Record, old: Fitness, new: Fitness) -> Record:
    """A copy of ``record`` (scored by ``old``) for ``new``, a fitness at a narrower sign
    width: its smoothed signs rewritten at ``new``'s width and held there (not refined)."""
    factor = old.sign_width / new.sign_width
    coefficients = narrowed_coefficients(record.coefficients, old, factor)
    if coefficients is None:
        return record
    held = set(record.held)
    for feature in coefficients.state:
        slots, theta = new.evaluator.inner_of(feature)
        role = "x_dot" if feature.has(new.symbols.x_dot) else "x"
        sign = new.sign_scale(role)
        held.update(slots.start + k for k, value in enumerate(theta)
                    if math.isclose(value, sign, rel_tol=1e-9))
    key = structure_key(coefficients.canonical(), new.config.coefficients == "tree")
    return dataclasses.replace(record, key=key, coefficients=coefficients,
                               held=tuple(sorted(held)), held_signs=new.held_signs(held))


def sharpened(model: Model, fitness: Fitness, factor: float) -> Model | None:
    """``model`` with its smoothed signs ``factor`` times narrower, its constants, initial
    state and step count unchanged; None if it has none."""
    coefficients = narrowed_coefficients(model.coefficients, fitness, factor)
    if coefficients is None:
        return None
    return Model.from_coefficients(model.symbols, coefficients,
                                   input_interpolation=model.input_interpolation,
                                   substeps=model.substeps)


def narrowed_steps(sharper: Model, measurement, *, tolerance: float) -> int | None:
    """RK4 steps per sample for ``sharper``, a model with its signs narrowed at the step
    count of the model it came from (:func:`sharpened`; a system's
    :func:`gpjax._system_final.sharpened_model`): that count if the step check
    (:func:`gpjax._convergence.check_model`) passes there, else the count that check asks
    for — measured, not assumed to grow with the sign's steepness; ``None`` where no count
    up to the cap keeps RK4 stable on it."""
    check, reference = check_model(sharper, measurement, tolerance=tolerance)
    if check.stable_substeps > MAX_SUBSTEPS:
        return None
    return (sharper.substeps if check.converged else
            needed_substeps(sharper, measurement, check, reference))


def check_width(model: Model, reference: np.ndarray, rms_reference: float,
                fitness: Fitness, *, tolerance: float) -> WidthCheck | None:
    """Compare ``model``'s ``reference`` response (on the convergence check's samples)
    with the reference response of the same model with its smoothed signs
    :data:`NARROWING` times narrower (module docstring), and that one with the signs
    NARROWING² times narrower (:attr:`WidthCheck.next_ratio`); None if it has none."""
    sharper = sharpened(model, fitness, NARROWING)
    if sharper is None:
        return None
    sharpest = sharpened(model, fitness, NARROWING ** 2)
    measurement = fitness.measurement.segment(0, reference.size)
    response, further = (m.simulate(measurement, initial_conditions=model.initial_conditions)
                         for m in (sharper, sharpest))

    def ratio(a, b) -> float:
        difference = float(np.sqrt(np.mean((a - b) ** 2)))
        return (difference / rms_reference if rms_reference > 0 and math.isfinite(difference)
                else math.inf)

    return WidthCheck(fitness.sign_width, float(np.sqrt(np.mean((response - reference) ** 2))),
                      rms_reference, ratio(response, reference), tolerance,
                      next_ratio=ratio(further, response))
