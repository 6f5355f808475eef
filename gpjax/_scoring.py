"""The converged simulator and the scores of the physics benchmark, independent of
gpjax's own integrators.

:func:`solve` integrates x'' = f(x, x', u, t) with scipy's DOP853 (rtol 1e-10, atol
1e-12); :func:`simulate_equations` does so for any sympy equations (the truth, gpjax's
``model_.sympy()``, a peer's), the input reconstructed from its samples by a cubic spline
(``"cubic"``, for band-limited inputs) or held for one sample (``"hold"``, for a
controller's output; then one solve per sample interval). :func:`compare_structure`
decides whether a model has the truth's terms and constants, :func:`nrms` scores a
simulation.

Structure rule. Both equations are written as lhs − rhs = 0, normalised so that the
input's coefficient is −1 (the form m·x'' + … = u), rewritten (sinh and cosh as
exponentials; tanh(y/ε) with ε ≤ :data:`SIGN_EPSILON` × RMS(y) as sign(y)), expanded, and
split into terms coefficient × feature. The structure is right when the two sets of
features match one to one — the same sympy expression with numbers inside a feature within
:data:`TOLERANCE`, or (an equivalent expression) two features of the same variable z that
agree over the exercised range, RMS difference ≤ :data:`TOLERANCE` × the truth feature's RMS
on |z| ≤ :data:`RANGE_RMS` × RMS(z) (sin(1.0007·x − 2e-5) matches sin(x)) — and the
constants are right when every matched coefficient (x'' included) is within
:data:`TOLERANCE` of the truth's.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np
import sympy as sp
from scipy.integrate import solve_ivp
from scipy.interpolate import CubicSpline

from ._systems import U, accelerations

RTOL, ATOL = 1e-10, 1e-12
#: Relative tolerance of constants, and of numbers inside features.
TOLERANCE = 0.02
#: Features are compared numerically on |z| ≤ RANGE_RMS × RMS(z).
RANGE_RMS = 2.5
#: Points of that comparison: spaced 0.00125·RMS(z), so a feature as narrow as a Stribeck
#: bump of width 1 % of RMS(z) is sampled 8 times across it.
GRID_POINTS = 4001
#: tanh(y/ε) counts as sign(y) when ε is at most this fraction of RMS(y).
SIGN_EPSILON = 0.01
INTERPOLATIONS = ("cubic", "hold")


class SimulationError(RuntimeError):
    """A model's simulation failed: it diverged, or took more steps than allowed."""


def solve(acceleration: Callable, n: int, time: np.ndarray, force: Callable, *,
          state0: np.ndarray, rtol: float = RTOL, max_step: float | None = None,
          bound: float = math.inf, max_evaluations: int | None = None
          ) -> tuple[np.ndarray, np.ndarray]:
    """(positions, velocities), each (n, N) on ``time`` (s), of x'' =
    ``acceleration(x, x', u, t)`` driven by ``force(t)``, from ``state0``, by DOP853.

    A single coordinate whose acceleration jumps at x' = 0 (sign(x'), dry friction) is
    solved as a Filippov system, since an event-free solve chatters and stalls once the
    mass sticks: each motion ends at the event x' = 0; there, with a± the acceleration at
    x' = ±0, the mass moves on up if a+ > 0, down if a− < 0, and else sticks (x' = 0,
    x fixed) until a+ or a− changes sign (an event, steps of at most ``max_step``).

    Raises:
        SimulationError: the solve failed, a state left [−bound, bound], or the right-hand
            side was evaluated more than ``max_evaluations`` times.
    """
    calls = [0]
    checked = math.isfinite(bound)

    def counted(x, v, t):
        calls[0] += 1
        if max_evaluations is not None and calls[0] > max_evaluations:
            raise SimulationError(f"more than {max_evaluations} evaluations by t = {t:.4g} s")
        if checked and not (np.abs(x).max() <= bound and np.abs(v).max() <= bound):
            raise SimulationError(f"diverged (|state| > {bound:.3g}) at t = {t:.4g} s")
        return acceleration(x, v, force(t), t)

    state0 = np.asarray(state0, dtype=np.float64)
    if n == 1 and _jumps_at_rest(acceleration):
        return _solve_filippov(counted, time, state0, rtol=rtol, max_step=max_step)
    solution = solve_ivp(lambda t, y: np.concatenate([y[n:], counted(y[:n], y[n:], t)]),
                         (time[0], time[-1]), state0, method="DOP853", t_eval=time,
                         rtol=rtol, atol=ATOL, max_step=max_step or np.inf)
    if not solution.success:
        raise SimulationError(f"solve failed: {solution.message}")
    return solution.y[:n], solution.y[n:]


#: The velocity at which "x' = ±0" is evaluated.
_ZERO = 1e-300


def _jumps_at_rest(acceleration: Callable) -> bool:
    """Whether the acceleration at x = 0, u = 0 differs between x' = +0 and x' = −0."""
    with np.errstate(all="ignore"):
        up, down = (acceleration(np.zeros(1), np.full(1, v), 0.0, 0.0) for v in (_ZERO, -_ZERO))
    return bool(np.all(np.isfinite([up, down])) and up[0] != down[0])


def _solve_filippov(accelerate: Callable, time: np.ndarray, state0: np.ndarray, *,
                    rtol: float, max_step: float | None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`solve` for one coordinate whose acceleration jumps at x' = 0."""
    out = np.empty((2, time.size))
    t, (x, v) = float(time[0]), state0
    done = 0  # samples written
    step = max_step or np.inf

    def side(t, x, s):  # the acceleration at x' = s·0
        return float(accelerate(np.array([x]), np.array([s * _ZERO]), t)[0])

    released = 0.0  # the direction of a release from sticking, else 0
    while done < time.size:
        if v == 0.0 and not released:
            up, down = side(t, x, 1.0), side(t, x, -1.0)
            if up <= 0.0 <= down:  # stuck until a+ > 0 or a− < 0
                def release_up(s, y):
                    return side(s, x, 1.0)

                def release_down(s, y):
                    return side(s, x, -1.0)

                release_up.terminal = release_down.terminal = True
                release_up.direction, release_down.direction = 1.0, -1.0
                solution = _segment(lambda s, y: np.zeros(2), t, np.array([x, 0.0]), time[done:],
                                    (release_up, release_down), rtol, step)
            else:
                solution = _move(accelerate, t, x, 1.0 if up > 0.0 else -1.0, time[done:],
                                 rtol, step)
        else:
            direction = released or math.copysign(1.0, v)
            solution = _move(accelerate, t, x, direction, time[done:], rtol, step, v=v)
        reached = len(solution.t)
        if reached:
            out[:, done:done + reached] = np.asarray(solution.y)
        done += reached
        released = 0.0
        if solution.status == 1:  # an event: the motion or the sticking ended there
            which = 0 if solution.t_events[0].size else 1
            t = float(solution.t_events[which][0])
            x, v = float(solution.y_events[which][0][0]), 0.0
            if len(solution.t_events) == 2:  # sticking ended: move off up or down
                released = 1.0 if which == 0 else -1.0
        elif done < time.size:
            raise SimulationError("solve stopped before the end of the record")
    return out[:1], out[1:]


#: A motion from rest ignores reversals in its first nanosecond (where the acceleration
#: is ~0 and rounding alone could reverse it).
_START = 1e-9


def _move(accelerate, t, x, direction, times, rtol, step, *, v=0.0):
    """A motion in ``direction`` from (t, x, v) until x' = 0 (a terminal event); the law
    is that of this direction throughout (a velocity of the other sign, possible only in
    the first nanosecond, does not flip it)."""
    def rhs(s, y):
        velocity = y[1] if y[1] * direction > 0.0 else direction * _ZERO
        return np.array([y[1], accelerate(y[:1], np.array([velocity]), s)[0]])

    def stops(s, y):
        return y[1] if v != 0.0 or s > t + _START else direction

    stops.terminal, stops.direction = True, -direction
    return _segment(rhs, t, np.array([x, v]), times, (stops,), rtol, step)


def _segment(rhs, t, y0, times, events, rtol, step):
    solution = solve_ivp(rhs, (t, float(times[-1])), y0, method="DOP853",
                         t_eval=times[times >= t], rtol=rtol, atol=ATOL, max_step=step,
                         events=events)
    if solution.status == -1:
        raise SimulationError(f"solve failed: {solution.message}")
    return solution


def simulate_equations(equations, coordinates, time: np.ndarray, inputs: np.ndarray, *,
                       state0: np.ndarray, interpolation: str = "cubic",
                       bound: float = math.inf, evaluations_per_sample: int = 200
                       ) -> np.ndarray:
    """Positions (C, N) of ``equations`` (one sympy ``Eq`` per coordinate, numeric) driven
    by the input samples ``inputs`` (N,) reconstructed by ``interpolation``.

    Raises:
        ValueError: an unknown interpolation, or equations :func:`accelerations` refuses.
        SimulationError: as :func:`solve` (budget: ``evaluations_per_sample`` × N).
    """
    if interpolation not in INTERPOLATIONS:
        raise ValueError(f"interpolation must be one of {INTERPOLATIONS}, got {interpolation!r}")
    acceleration = accelerations(equations, coordinates)
    n = len(coordinates)
    budget = evaluations_per_sample * time.size
    if interpolation == "cubic":
        return solve(acceleration, n, time, CubicSpline(time, inputs), state0=state0,
                     bound=bound, max_evaluations=budget)[0]
    positions = np.empty((n, time.size))
    state = np.asarray(state0, dtype=np.float64)
    positions[:, 0] = state[:n]
    for i in range(time.size - 1):
        held = float(inputs[i])
        x, v = solve(acceleration, n, time[i:i + 2], lambda t: held, state0=state,
                     bound=bound, max_evaluations=evaluations_per_sample)
        state = np.concatenate([x[:, -1], v[:, -1]])
        positions[:, i + 1] = state[:n]
    return positions


def nrms(simulated: np.ndarray, true: np.ndarray) -> float:
    """RMS(simulated − true) / RMS(true) over all samples and coordinates."""
    return float(np.sqrt(np.mean((simulated - true) ** 2) / np.mean(true ** 2)))


def features(equation: sp.Eq, *, scales: dict[sp.Symbol, float] | None = None
             ) -> dict[sp.Expr, float]:
    """Feature -> coefficient of ``equation`` in the canonical form of the module
    docstring (the input ``u`` itself is left out).

    Raises:
        ValueError: the equation has no term in u alone to normalise by.
    """
    residual = equation.lhs - equation.rhs
    residual = residual.replace(lambda e: isinstance(e, (sp.sinh, sp.cosh)),
                                lambda e: e.rewrite(sp.exp))
    residual = residual.replace(lambda e: isinstance(e, sp.tanh),
                                lambda e: _sharp_tanh(e, scales or {}))
    terms: dict[sp.Expr, float] = {}
    for term in sp.Add.make_args(sp.expand(residual)):
        coefficient, feature = term.as_coeff_Mul()
        terms[feature] = terms.get(feature, 0.0) + float(coefficient)
    gain = terms.pop(U, 0.0)
    if gain == 0.0:
        raise ValueError(f"equation {equation} has no term in {U} alone to normalise by")
    return {f: -c / gain for f, c in terms.items() if c != 0.0}


def _sharp_tanh(expression: sp.tanh, scales: dict[sp.Symbol, float]) -> sp.Expr:
    """sign(y) for tanh(y/ε) with ε small against RMS(y), else ``expression``."""
    slope, y = expression.args[0].as_coeff_Mul()
    if y in scales and slope != 0 and 1.0 / abs(float(slope)) <= SIGN_EPSILON * scales[y]:
        return sp.sign(y) * math.copysign(1.0, float(slope))
    return expression


def _close(a: sp.Expr, b: sp.Expr, scales: dict[sp.Symbol, float]) -> bool:
    """``a`` and ``b`` are the same expression (numbers within :data:`TOLERANCE`) or
    features of one variable that agree over its exercised range (module docstring)."""
    if _same_form(a, b):
        return True
    variables = a.free_symbols
    if len(variables) != 1 or variables != b.free_symbols or next(iter(variables)) not in scales:
        return False
    z = next(iter(variables))
    grid = np.linspace(-RANGE_RMS, RANGE_RMS, GRID_POINTS) * scales[z]
    values = [np.broadcast_to(np.asarray(sp.lambdify(z, f, "numpy")(grid), dtype=float),
                              grid.shape) for f in (a, b)]
    if not all(np.all(np.isfinite(v)) for v in values):
        return False
    reference = float(np.sqrt(np.mean(values[1] ** 2)))
    return reference > 0 and float(np.sqrt(np.mean((values[0] - values[1]) ** 2))) <= \
        TOLERANCE * reference


def _same_form(a: sp.Expr, b: sp.Expr) -> bool:
    """``a`` and ``b`` are the same expression, numbers within :data:`TOLERANCE`."""
    if a.is_Number and b.is_Number:
        return math.isclose(float(a), float(b), rel_tol=TOLERANCE, abs_tol=1e-12)
    if a.func != b.func or len(a.args) != len(b.args):
        return False
    if not a.args:
        return a == b
    return all(_same_form(x, y) for x, y in zip(a.args, b.args))


def compare_structure(model: sp.Eq, truth: sp.Eq, *,
                      scales: dict[sp.Symbol, float] | None = None) -> dict:
    """Whether ``model`` has the structure and constants of ``truth`` (module docstring):
    ``structure``, ``constants`` (bools), ``missing`` and ``extra`` features (text), and
    ``worst_constant_error`` (largest relative error of a matched coefficient).

    Raises:
        ValueError: as :func:`features`.
    """
    wanted = features(truth, scales=scales)
    try:
        found = features(model, scales=scales)
    except ValueError:  # no input term to normalise by: nothing can match
        return {"structure": False, "constants": False, "missing": [str(U)],
                "extra": [], "worst_constant_error": math.inf}
    matched, extra = {}, []
    for feature, coefficient in found.items():
        partner = next((w for w in wanted if w not in matched
                        and _close(feature, w, scales or {})), None)
        if partner is None:
            extra.append(str(feature))
        else:
            matched[partner] = coefficient
    missing = [str(w) for w in wanted if w not in matched]
    errors = [abs(matched[w] / wanted[w] - 1.0) for w in matched]
    worst = max(errors, default=math.inf)
    structure = not missing and not extra
    return {"structure": structure, "constants": structure and worst <= TOLERANCE,
            "missing": missing, "extra": extra, "worst_constant_error": worst}
