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
from typing import Callable

import numpy as np
import sympy as sp

from ._coefficients import Coefficients
from ._convergence import MAX_SUBSTEPS, check_model, coordinate_weights, needed_substeps
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
        when the ratio does not fall as the sign narrows or cannot be checked; 1 when the
        rate is unknown (the reference solve failed on the sign NARROWING² times narrower:
        that says nothing of convergence, so one narrowing at a time)."""
        if self.converged:
            return 0
        if math.isfinite(self.ratio) and not math.isfinite(self.next_ratio):
            return 1
        rate = self.rate
        if not rate > 1:
            return math.inf
        if math.isinf(rate):
            return 1
        return math.ceil(math.log(self.ratio / self.tolerance) / math.log(rate))

    def to_json(self) -> dict:
        return dataclasses.asdict(self) | {"converged": self.converged}


def fitted_signs(fitness: Fitness) -> Callable[[sp.Expr], bool]:
    """Which tanh of one coordinate's model is one of ``fitness``'s smoothed signs: a
    tanh(a·z) of the response or its rate whose a is that variable's sign scale (to 1e-9
    relative); a tanh law whose scale was fitted is a law of its own."""
    variables = [(z, fitness.sign_scale(role)) for role, z in
                 (("x", fitness.symbols.x), ("x_dot", fitness.symbols.x_dot))]

    def is_sign(tanh: sp.Expr) -> bool:
        return any((a := tanh.args[0] / z).is_Number
                   and math.isclose(float(a), scale, rel_tol=1e-9) for z, scale in variables)
    return is_sign


def narrowed_coefficients(coefficients: Coefficients, factor: float,
                          is_sign: Callable[[sp.Expr], bool] | None = None
                          ) -> Coefficients | None:
    """``coefficients`` with every smoothed sign tanh(θ·z) ``factor`` times narrower,
    tanh(factor·θ·z), the values unchanged; None if they hold none. ``is_sign`` says
    which tanh is a smoothed sign (one coordinate's: :func:`fitted_signs`); by default
    every tanh, as in a system's bank (:mod:`gpjax._system_bank`)."""
    replacements = {tanh: sp.tanh(sp.expand(factor * tanh.args[0]))
                    for feature in coefficients.state for tanh in feature.atoms(sp.tanh)
                    if is_sign is None or is_sign(tanh)}
    if not replacements:
        return None
    return coefficients.replace(state={f.xreplace(replacements): v
                                       for f, v in coefficients.state.items()})


def narrowed(record: Record, old: Fitness, new: Fitness) -> Record:
    """A copy of ``record`` (scored by ``old``) for ``new``, a fitness at a narrower sign
    width: its smoothed signs rewritten at ``new``'s width and held there (not refined)."""
    factor = old.sign_width / new.sign_width
    coefficients = narrowed_coefficients(record.coefficients, factor, fitted_signs(old))
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


def sharpened(model: Model, factor: float,
              is_sign: Callable[[sp.Expr], bool] | None = None) -> Model | None:
    """``model`` (any number of coordinates) with its smoothed signs ``factor`` times
    narrower (:func:`narrowed_coefficients`; ``is_sign`` as there), its constants, initial
    states and step count unchanged; None if it has none."""
    equations = [narrowed_coefficients(c, factor, is_sign) for c in model.system]
    if all(e is None for e in equations):
        return None
    return Model.from_equations(model.coordinates, model.time, model.inputs,
                                [e or c for e, c in zip(equations, model.system)],
                                input_interpolation=model.input_interpolation,
                                substeps=model.substeps)


def narrowed_steps(sharper: Model, measurement, *, tolerance: float) -> int | None:
    """RK4 steps per sample for ``sharper``, a model with its signs narrowed at the step
    count of the model it came from (:func:`sharpened`): that count if the step check
    (:func:`gpjax._convergence.check_model`) passes there, else the count that check asks
    for — measured, not assumed to grow with the sign's steepness; ``None`` where no count
    up to the cap keeps RK4 stable on it."""
    check, reference = check_model(sharper, measurement, tolerance=tolerance)
    if check.stable_substeps > MAX_SUBSTEPS:
        return None
    return (sharper.substeps if check.converged else
            needed_substeps(sharper, measurement, check, reference))


def width_check(model: Model, sharpen: Callable[[float], Model | None], measurement,
                reference: np.ndarray, rms_reference: float, *, fraction: float,
                tolerance: float) -> WidthCheck | None:
    """The width check of a model of any number of coordinates (module docstring):
    ``model``'s ``reference`` response ((n,) or (n, D), on the first n samples of
    ``measurement``, as the convergence check solved it) against the reference response of
    ``sharpen(NARROWING)`` (the same model with its smoothed signs :data:`NARROWING` times
    narrower, its constants and initial state unchanged), and that one against
    ``sharpen(NARROWING ** 2)``'s (:attr:`WidthCheck.next_ratio`), over ``rms_reference``,
    the convergence check's RMS residual; coordinates are weighted as there
    (:func:`gpjax._convergence.coordinate_weights`). ``fraction``: the width the model was
    fitted at (ε / RMS z). None if ``sharpen`` finds no sign."""
    sharper = sharpen(NARROWING)
    if sharper is None:
        return None
    sharpest = sharpen(NARROWING ** 2)
    window = measurement.segment(0, len(reference))
    weights = coordinate_weights(window.responses if np.ndim(reference) == 2
                                 else window.response)
    response, further = (m.simulate(window, initial_conditions=model.initial_states)
                         for m in (sharper, sharpest))

    def rms(a, b) -> float:
        return float(np.sqrt(np.mean(((np.reshape(a, np.shape(reference))
                                       - np.reshape(b, np.shape(reference))) * weights) ** 2)))

    def ratio(a, b) -> float:
        difference = rms(a, b)
        return (difference / rms_reference if rms_reference > 0 and math.isfinite(difference)
                else math.inf)

    return WidthCheck(fraction, rms(response, reference), rms_reference,
                      ratio(response, reference), tolerance, next_ratio=ratio(further, response))


def next_narrowing(check: WidthCheck, narrowings: int,
                   sharpen: Callable[[float], Model | None], measurement, *,
                   tolerance: float) -> tuple[int, int] | str:
    """(jump, steps) of the next refit of a model whose width ``check`` failed after
    ``narrowings`` narrowings (module docstring, **Refit**): as many narrowings at once as
    the check's rate projects (at least one, at most those left of :data:`MAX_NARROWINGS`;
    the constants barely move between widths, and each intermediate refit is a whole fit
    at more steps), shortened while no step count up to the cap integrates the narrower
    signs stably (:func:`narrowed_steps` of ``sharpen(NARROWING ** jump)``, the model with
    its signs that much narrower); the steps per sample are those the narrower signs need.
    Else why the narrowing stops: ``"narrowest sign"``, ``"width not converging"`` (the
    change does not fall as the sign narrows) or ``"unstable sign"``."""
    if narrowings >= MAX_NARROWINGS:
        return "narrowest sign"
    if math.isinf(check.narrowings_needed):
        return "width not converging"
    most = int(min(MAX_NARROWINGS - narrowings, max(1, check.narrowings_needed)))
    for jump in range(most, 0, -1):
        steps = narrowed_steps(sharpen(NARROWING ** jump), measurement, tolerance=tolerance)
        if steps is not None:
            return jump, steps
    return "unstable sign"


def check_width(model: Model, reference: np.ndarray, rms_reference: float,
                fitness: Fitness, *, tolerance: float) -> WidthCheck | None:
    """:func:`width_check` of one coordinate's reported ``model`` (signs found by
    :func:`fitted_signs` at ``fitness``'s width)."""
    signs = fitted_signs(fitness)
    return width_check(model, lambda factor: sharpened(model, factor, signs),
                       fitness.measurement, reference, rms_reference,
                       fraction=fitness.sign_width, tolerance=tolerance)


def why_stopped(stopped: str | None) -> str | None:
    """Why the convergence loop (steps and sign width, :meth:`gpjax.Identifier.fit` or a
    system's) ended unconverged, in words, for its ``stopped`` reason; None for another."""
    return {"fixed substeps": "substeps is fixed; use substeps = \"auto\" or more substeps",
            "substeps cap": f"at the cap of {MAX_SUBSTEPS} steps per sample",
            "narrowest sign": f"at the narrowest sign, {NARROWING ** MAX_NARROWINGS}× "
                              "narrower than the default",
            "width not converging": "narrowing the sign further would not converge",
            "unstable sign": f"a narrower sign would need more than {MAX_SUBSTEPS} steps "
                             "per sample for a stable RK4 step where the mass sticks",
            "refit failed": "the refit at more steps or a narrower sign failed"}.get(stopped)


def width_line(check: dict, stopped: str | None = None) -> str:
    """One line of a width check's JSON (:meth:`WidthCheck.to_json`) for a report;
    ``stopped``: the convergence loop's reason for ending (:func:`why_stopped`)."""
    head = f"  smoothed sign tanh(z/ε), ε = {check['fraction']:.3g}·RMS z: "
    if not math.isfinite(check["ratio"]):
        return (head + f"NOT checked, the reference solver fails on the signs {NARROWING}× "
                "narrower")
    why = why_stopped(stopped)
    verdict = ("converged: the constants do not carry the smoothing" if check["converged"]
               else "NOT converged: the constants carry some of the smoothing"
               + (f"; {why}" if why else ""))
    return (head + f"{NARROWING}× narrower changes the response by {check['ratio']:.2%} of "
            f"the residual RMS (tolerance {check['tolerance']:.0%}), {verdict}")
