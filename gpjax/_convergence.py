"""Converged integration: RK4 steps per sample chosen so the model does not depend on them.

A model fitted with too coarse an integrator has constants that compensate the
integrator's error: the ODE it names is another system. The fixed-step RK4 of the run is
therefore checked on the reported model against the reference solve
(:mod:`gpjax._reference`, adaptive 8th order, tight tolerances): the RMS difference of the
two simulated responses must stay below ``tolerance`` (default 1 %) of the RMS residual
of the model against the data. Otherwise the step count grows and the model is refitted.

* **Start** (:func:`initial_substeps`): from the data's bandwidth. The highest frequency
  f_max below which :data:`BANDWIDTH_FRACTION` of the input's and the response's AC
  power lies must satisfy ω·h ≤ :data:`STEP_PHASE` (ω = 2π·f_max, h = Δt / substeps),
  where RK4's relative local error, ~(ωh)⁵/120, is 3e-4.
* **Stability** (:func:`stable_substeps`): the RMS check alone passes a step that is
  unstable where the model is stiff but bounded: a mass that sticks on a smoothed sign
  tanh(z/ε) sees a damping rate F/(m·ε) that RK4 amplifies when h·|λ| exceeds its stability
  interval, :data:`RK4_STABILITY`; the response chatters within the sign's width, which
  the check does not see, but the sensitivities that refinement and the standard errors
  integrate beside it grow without bound. So a check also needs h·ρ ≤ RK4_STABILITY, ρ
  the largest rate of the model's linearisation where its response dwells.
* **Window**: records longer than :data:`CHECK_SAMPLES` are checked on their first
  :data:`CHECK_SAMPLES` samples: the reference solve costs ~40–60 µs a sample on 2
  cores with held or linear inputs and ~200 µs with band-limited ones, whose steps end on
  the spline's knots (linear in the samples), and the ODE a model names is the same on any stretch of
  the record.
* **Estimate on the way** (``estimate="doubling"``): a rung of the ladder that fails only
  says how many steps to try next, and the checks of a diagnosis's rounds only choose the
  steps its candidates are fitted at; none of them is reported. Their reference is RK4 at
  twice the steps, extrapolated (Richardson: RK4's global error at h is, to leading order,
  16/15 of the difference between its responses at h and h/2), a fraction of the Dopri8
  solve's cost on a band-limited record, whose steps end on the spline's 16 knots per
  sample (Silverbox's estimation part: 1.4 s against 12 s). That holds where RK4 is in its
  h⁴ regime, so an estimate that passes is confirmed against the Dopri8 reference, which
  then decides (:func:`fit_converged`'s ``confirm``; the diagnosis's rounds take the
  estimate), and a rung that ends the ladder at its cap is checked against the reference
  too: the check a model reports is always the reference's. Where a failed reference solve
  ends the ladder (``unsolved_ends``), a failing estimate is checked against the reference
  as well, as only it can say that it fails (a model that blows up can have RK4 responses
  at h and h/2 that agree).
* **Growth** (:func:`needed_substeps`): RK4's global error falls as h⁴, so a measured
  ratio r at s substeps needs s·(r / (tolerance/2))^(1/4) — half the tolerance as margin
  (:func:`next_substeps`). That law holds only once the steps resolve the model's
  sharpest feature: a smoothed sign's transition is far narrower than the record's band,
  and on a Coulomb + viscous record (8,000 samples) the law asked for 3, then 6, then 12
  steps, refitting the Pareto front at each. So the count is *measured* before the refit:
  the reported model, its constants unchanged, is checked at the law's count, and at the
  law's next count from there, until it passes with the margin. As each count is
  measured, the law's is tried as it is (at least one step more), not rounded up to twice
  the last (:func:`next_substeps`). Each trial is one RK4 solve of one model (two for a
  doubling estimate; the failed check's Dopri8 response is reused, as no step count
  changes it); a refit of the front at a count that then fails is the compiling of four
  programs and the refinement of every front model.
"""

from __future__ import annotations

import dataclasses
import math
import threading
from concurrent.futures import Future
from typing import Callable

import numpy as np

from ._data import Measurement

#: Fraction of the AC power of the input and the response that sets the bandwidth.
BANDWIDTH_FRACTION = 0.999
#: Largest ω·h at the top of the band for the starting step.
STEP_PHASE = 0.5
#: Most RK4 steps per sample interval.
MAX_SUBSTEPS = 64
#: Longest stretch of a record the reference solve checks (see the module docstring).
CHECK_SAMPLES = 65_536
#: RK4's stability interval on the negative real axis: a mode λ is not amplified by a
#: step h with h·|λ| ≤ 2.785.
RK4_STABILITY = 2.785


@dataclasses.dataclass(frozen=True)
class Convergence:
    """Outcome of one check of a model's integration (responses in the data's units).

    Attributes:
        substeps: RK4 steps per sample interval checked.
        rms_rk4: RMS residual of the RK4 response against the data.
        rms_reference: RMS residual of the reference response against the data.
        difference_rms: RMS difference between the RK4 and the reference responses.
        ratio: ``difference_rms / rms_reference`` (inf if the reference solve failed).
        tolerance: the largest ratio accepted.
        samples: the samples compared (the record's first, at most :data:`CHECK_SAMPLES`).
        stable_substeps: the fewest steps per sample at which RK4 is stable on the model
            along the record (:func:`stable_substeps`); fewer do not converge.
        estimate: what the reference response was: ``"reference"`` the Dopri8 solve,
            ``"doubling"`` RK4 at twice the steps, Richardson-extrapolated.
    """

    substeps: int
    rms_rk4: float
    rms_reference: float
    difference_rms: float
    ratio: float
    tolerance: float
    samples: int = 0
    stable_substeps: int = 1
    estimate: str = "reference"

    @property
    def converged(self) -> bool:
        return self.ratio < self.tolerance and self.substeps >= self.stable_substeps

    def to_json(self) -> dict:
        return dataclasses.asdict(self) | {"converged": self.converged}


def check_line(check: dict) -> str:
    """One line on a check (:meth:`Convergence.to_json`, as a model file records it)."""
    stable = check.get("stable_substeps", 1)
    unstable = (f"; RK4 is stable from {stable} steps per sample on"
                if check["substeps"] < stable else "")
    by = ("RK4 at twice the steps, extrapolated" if check.get("estimate") == "doubling"
          else "the reference solve (diffrax Dopri8)")
    return (f"RMS by {by} {check['rms_reference']:.4g}; RK4 at "
            f"{check['substeps']} step(s) per sample differs by {check['ratio']:.2%} of it"
            f"{unstable} ({'converged' if check['converged'] else 'NOT converged'}, tolerance "
            f"{check['tolerance']:.0%})")


def bandwidth_hz(measurement: Measurement) -> float:
    """Highest frequency (Hz) below which :data:`BANDWIDTH_FRACTION` of the AC power of
    the response and of every input lies."""
    highest = 0.0
    frequency = np.fft.rfftfreq(measurement.n_samples, measurement.dt)
    for values in (*measurement.responses.T, *measurement.inputs.values()):
        power = np.abs(np.fft.rfft(values - np.mean(values))) ** 2
        total = power.sum()
        if total > 0:
            index = int(np.searchsorted(np.cumsum(power) / total, BANDWIDTH_FRACTION))
            highest = max(highest, float(frequency[min(index, frequency.size - 1)]))
    return highest


def initial_substeps(measurement: Measurement) -> int:
    """RK4 steps per sample interval for the search (see the module docstring)."""
    phase = 2 * math.pi * bandwidth_hz(measurement) * measurement.dt
    return int(min(MAX_SUBSTEPS, max(1, math.ceil(phase / STEP_PHASE))))


def search_substeps(measurement: Measurement, setting: int | str) -> int:
    """RK4 steps per sample of a search with ``GPConfig.substeps`` = ``setting``: a number
    as given, ``"auto"`` the data's bandwidth rule (:func:`initial_substeps`)."""
    return initial_substeps(measurement) if setting == "auto" else int(setting)


def stable_substeps(model, measurement: Measurement, responses: np.ndarray) -> int:
    """The fewest RK4 steps per sample with h·ρ ≤ :data:`RK4_STABILITY` wherever the
    model's ``responses`` (N,) or (N, D) on ``measurement`` dwell (module docstring).

    ρ_k bounds the rates of each equation's linearisation at sample k, Σ|∂a/∂v| +
    √Σ|∂a/∂x| (a the acceleration, v every velocity and x every position it depends on:
    the rate of a damped oscillator; velocities by central differences, slopes by central
    differences of the features). A perturbation grows without bound only where the rate
    stays high, as while a mass sticks on a smoothed sign; a response that crosses the
    sign's narrow transition within one sample interval amplifies it by a bounded factor
    once. So the bound is taken where two consecutive samples both have it:
    max_k min(ρ_k, ρ_k+1)."""
    import sympy as sp  # not at import: the CLI reads its settings before sympy loads

    dt, names = measurement.dt, measurement.response_names
    positions = np.reshape(responses, (measurement.n_samples, len(names)))
    positions = np.where(np.isfinite(positions), positions, np.nan)  # a diverged stretch
    velocities = np.gradient(positions, dt, axis=0)
    values = {}
    for i, name in enumerate(names):
        values[sp.Symbol(name)] = positions[:, i]
        values[sp.Symbol(f"{name}_dot")] = velocities[:, i]
    speeds = {sp.Symbol(f"{name}_dot") for name in names}
    states = set(values)
    values[sp.Symbol(measurement.time_name)] = measurement.time
    values |= {sp.Symbol(n): u for n, u in measurement.inputs.items()}
    rate = np.zeros(measurement.n_samples)
    for coefficients in model.system:
        damping = stiffness = 0.0
        for feature, value in coefficients.state.items():
            symbols = sorted(feature.free_symbols, key=str)
            f = sp.lambdify(symbols, feature, "numpy")
            args = [values[s] for s in symbols]
            for k, symbol in enumerate(symbols):
                if symbol not in states:
                    continue
                spread = float(np.nanstd(args[k]))
                step = 1e-7 * (spread if spread > 0 else 1.0)
                up, down = list(args), list(args)
                up[k], down[k] = args[k] + step, args[k] - step
                with np.errstate(all="ignore"):
                    slope = np.abs(value * (f(*up) - f(*down)) / (2 * step * coefficients.mass))
                if symbol in speeds:
                    damping = damping + slope
                else:
                    stiffness = stiffness + slope
        rate = np.fmax(rate, damping + np.sqrt(stiffness))
    rate = np.where(np.isfinite(rate), rate, 0.0)
    dwelling = float(np.max(np.minimum(rate[:-1], rate[1:]), initial=0.0))
    return max(1, math.ceil(dt * dwelling / RK4_STABILITY))


def next_substeps(check: Convergence) -> int:
    """The step count a failed check asks for: the h⁴ law's with half the tolerance as
    margin (4× where the reference failed), more than the last and at least the stable
    count, at most MAX_SUBSTEPS. It is only ever tried, never taken on trust
    (:func:`needed_substeps` checks it before anything is refitted), so it is not rounded
    up to twice the last: that floor took Silverbox's estimation part from 5 steps (ratio
    1.04 %) to 10 (0.06 %) where the law's 7 pass with the margin (0.27 %), and every
    later fit and simulation of the run and its diagnosis paid 10/7 of the time."""
    if not math.isfinite(check.ratio):
        wanted = 4 * check.substeps
    else:
        wanted = math.ceil(check.substeps * (check.ratio / (0.5 * check.tolerance)) ** 0.25)
    return int(min(MAX_SUBSTEPS, max(check.substeps + 1, wanted, check.stable_substeps)))


def needed_substeps(model, measurement: Measurement, check: Convergence,
                    reference: np.ndarray) -> int:
    """RK4 steps per sample at which ``model`` itself (constants unchanged) passes the
    check of a failed ``check`` with half its tolerance as margin, measured (module
    docstring): :func:`next_substeps` of the last trial until one passes or the steps
    reach :data:`MAX_SUBSTEPS`, each trial estimated as ``check`` was. ``reference``: the
    Dopri8 response that ``check`` solved (:func:`check_model`), which no step count
    changes, so it is not solved again (a doubling estimate is made anew per count)."""
    steps = next_substeps(check)
    doubling = check.estimate == "doubling"  # its reference belongs to one step count
    while steps < MAX_SUBSTEPS:
        trial, reference = check_model(dataclasses.replace(model, substeps=steps),
                                       measurement, tolerance=check.tolerance,
                                       reference=None if doubling else reference,
                                       stable=check.stable_substeps, estimate=check.estimate)
        if trial.ratio < 0.5 * check.tolerance and trial.converged:
            break
        steps = next_substeps(trial)
    return steps


def coordinate_weights(measured: np.ndarray):
    """Weights of a system's coordinates in the checks, s_1/s_d (s the spread of the
    ``measured`` responses (N, D), as in the objective), so their figures are in the first
    response's units; 1.0 for one coordinate's (N,)."""
    if np.ndim(measured) == 1:
        return 1.0
    spread = np.std(measured, axis=0)
    return spread[0] / np.where(spread > 0, spread, 1.0)


def reference_started(model, measurement: Measurement) -> Future:
    """The Dopri8 response :func:`check_model` compares ``model`` against (its fitted
    initial state, the first :data:`CHECK_SAMPLES` samples), compiled or loaded here and
    solved in a background thread: the solve is sequential and keeps one core busy, so a
    caller with other work for the rest of the machine starts it first and hands the
    future to :func:`fit_converged` (``fit_at`` returning (model, future)). A daemon
    thread: an interrupted run does not wait for it."""
    window = measurement.segment(0, min(measurement.n_samples, CHECK_SAMPLES))
    solve = model.prepared_simulation(window, initial_conditions=model.initial_states)
    future = Future()

    def run():
        try:
            future.set_result(solve())
        except BaseException as error:  # noqa: BLE001 - raised again by future.result()
            future.set_exception(error)

    threading.Thread(target=run, name="gpjax-reference", daemon=True).start()
    return future


def check_model(model, measurement: Measurement, *, tolerance: float,
                reference: np.ndarray | None = None, stable: int | None = None,
                estimate: str = "reference") -> tuple[Convergence, np.ndarray]:
    """Simulate ``model`` (its fitted initial state, its ``substeps``) by RK4 and by the
    reference solve over the first :data:`CHECK_SAMPLES` samples at most, and compare
    them: (:class:`Convergence`, the reference response on those samples, NaN if that
    solve failed). A system's responses (N, D) are compared with coordinate d weighted
    by s_1/s_d as in the objective, so the figures are in the first response's units.
    ``reference``: that response from an earlier check of the same model (constants and
    initial state), which the step count does not change; solved when ``None``; likewise
    ``stable``, its :func:`stable_substeps`. ``estimate="doubling"``: the reference is RK4
    at twice the steps, Richardson-extrapolated (module docstring), not the Dopri8 solve.

    Raises:
        ValueError: an unknown ``estimate``."""
    if estimate not in ("reference", "doubling"):
        raise ValueError(f"estimate must be 'reference' or 'doubling', got {estimate!r}")
    measurement = measurement.segment(0, min(measurement.n_samples, CHECK_SAMPLES))
    y0 = model.initial_states
    rk4 = model.simulate(measurement, initial_conditions=y0, solver="rk4")
    if reference is None and estimate == "doubling":
        finer = dataclasses.replace(model, substeps=2 * model.substeps).simulate(
            measurement, initial_conditions=y0, solver="rk4")
        reference = finer + (finer - rk4) / 15.0  # RK4: error(h) ≈ 16·error(h/2)
    elif reference is None:
        reference = model.simulate(measurement, initial_conditions=y0)
    ok = bool(np.all(np.isfinite(reference)))
    if stable is None:
        stable = stable_substeps(model, measurement, reference if ok else rk4)
    measured = measurement.response if np.ndim(rk4) == 1 else measurement.responses
    returned = reference
    weights = coordinate_weights(measured)
    measured, rk4, reference = measured * weights, rk4 * weights, reference * weights
    rms_rk4 = float(np.sqrt(np.mean((measured - rk4) ** 2)))
    if not ok:
        return Convergence(model.substeps, rms_rk4, math.inf, math.inf, math.inf,
                           tolerance, measurement.n_samples, stable, estimate), returned
    rms_reference = float(np.sqrt(np.mean((measured - reference) ** 2)))
    difference = float(np.sqrt(np.mean((rk4 - reference) ** 2)))
    ratio = difference / rms_reference if rms_reference > 0 else (0.0 if difference == 0
                                                                  else math.inf)
    return Convergence(model.substeps, rms_rk4, rms_reference, difference, ratio,
                       tolerance, measurement.n_samples, stable, estimate), returned


def fit_converged(fit_at: Callable, measurement: Measurement, *, substeps: int | None,
                  tolerance: float, first: int | None = None, unsolved_ends: bool = False,
                  confirm: bool = True):
    """(model, checks, reference): ``fit_at(steps, previous)`` (``previous``: the last fit,
    ``None`` at first) at the record's initial step count (or ``first``), checked, and fitted
    again at :func:`needed_substeps` until the check passes or the steps reach
    :data:`MAX_SUBSTEPS`; with ``substeps`` given, that count, checked once. A rung is
    checked by the doubling estimate first; one that it passes, and the last, against the
    Dopri8 reference solve, whose check then stands (module docstring). ``confirm=False``
    (a diagnosis's rounds, whose checks choose steps and are not reported): an estimate
    that passes stands.
    ``fit_at`` returning ``None`` is a failed fit: the last model, its checks and reference
    are returned as they stand (``None`` and no checks where the first fit failed); returning
    (model, future), the model and its reference response already being solved
    (:func:`reference_started`), which a Dopri8 check of it then takes.
    ``unsolved_ends``: a check whose reference solve failed (ratio not finite) ends the
    ladder, as no RK4 step count brings a response the reference cannot integrate closer
    to it (the diagnosis, whose test does not rank a diverged model; the estimator and
    systems refit at more steps instead, which can move the constants to where it can).
    ``reference``: the last check's reference response of the model (:func:`check_model`),
    for a check that compares against it (:func:`gpjax._sign_width.width_check`)."""
    steps = substeps or first or initial_substeps(measurement)
    checks, model, reference = [], None, None
    while True:
        fitted = fit_at(steps, model)
        if fitted is None:
            return model, checks, reference
        model, started = fitted if isinstance(fitted, tuple) else (fitted, None)
        ends = bool(substeps) or steps >= MAX_SUBSTEPS
        check = None
        if not (ends and confirm):
            check, reference = check_model(model, measurement, tolerance=tolerance,
                                           estimate="doubling")
        if (check is None or (confirm and check.converged)
                or (unsolved_ends and not check.converged)):
            check, reference = check_model(
                model, measurement, tolerance=tolerance,
                reference=None if started is None else started.result())
        checks.append(check)
        if (ends or check.converged
                or (unsolved_ends and not math.isfinite(check.ratio))):
            return model, checks, reference
        steps = needed_substeps(model, measurement, check, reference)
