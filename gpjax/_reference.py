"""Reference solve: a model integrated by a high-order adaptive diffrax method.

The run's own integrator is fixed-step RK4 (fast, batched over a population). Whether a
reported model means the same under *any* accurate solver is checked here, independently:
the model's equation is lambdified from sympy to one JAX right-hand side and integrated by
diffrax's 8th-order Dormand–Prince method (``Dopri8``) under PID step-size control with
tight tolerances. The record is integrated one sample interval at a time (a ``lax.scan``
of adaptive solves, each choosing its own first step), so every kink or jump of the input
falls on an interval's end, and the inputs are functions of continuous time:

* ``linear``: straight lines between samples;
* ``hold``: each interval sees its first sample's value (the left limit at its end);
* ``bandlimited``: the cubic spline of :func:`gpjax._data.bandlimited_spline`, the same
  function the RK4 stage values are taken from. Its third derivative jumps at each of its
  knots, :data:`~gpjax._data.BANDLIMITED_FACTOR` per interval, and at these tolerances the
  step control paid for every jump with rejected steps: the steps end on the knots instead
  (diffrax ``ClipStepSizeController``), ~3× faster.

Each input is given to the solve as a table of polynomial pieces per sample interval
(:func:`input_path`): one piece of degree 0 or 1 for ``hold`` and ``linear``, the spline's
:data:`~gpjax._data.BANDLIMITED_FACTOR` cubics for ``bandlimited``. An interval's solve
takes its own rows, and a stage finds its piece by dividing its time into the interval by
the piece length. That is the same function as diffrax's ``LinearInterpolation`` and
``CubicInterpolation`` over the whole record (to rounding), without their binary search
over every knot of the record at every stage: Silverbox's first 16,384 samples solve in
3.1 s instead of 5.0 s band-limited, 1.0 s instead of 1.3 s linear.

The state is scaled by the response's and its derivative's spread, so one absolute
tolerance serves both. A solve that fails (a model that blows up, or more steps than an
interval allows) is returned as data (``ok`` false, NaN response), never raised. The
solve of a structure is a :class:`gpjax._aot.Program`: a later process loads it.
"""

from __future__ import annotations

import dataclasses
from functools import lru_cache
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np
import sympy as sp

from ._aot import Program, fingerprint
from ._canonical import numbers_lifted
from ._coefficients import Coefficients
from ._data import BANDLIMITED_FACTOR, bandlimited_spline
from ._integrate import enable_float64
from ._record import padded_length


@dataclasses.dataclass(frozen=True, kw_only=True)
class ReferenceSolver:
    """Settings of the reference solve (diffrax ``Dopri8`` + ``PIDController``). The
    defaults keep its error ~1e-7 of the response's spread: below what RK4 is asked to
    reach on noise-free records (restarting every sample interval costs the solve
    accuracy that 1e-10 left visible there).

    Attributes:
        rtol: relative tolerance.
        atol: absolute tolerance on the state scaled to unit spread.
        max_steps_per_sample: steps allowed in one sample interval (the solve fails
            beyond it).

    Raises:
        ValueError: a non-positive setting.
    """

    rtol: float = 1e-12
    atol: float = 1e-12
    max_steps_per_sample: int = 256

    def __post_init__(self):
        if not (self.rtol > 0 and self.atol > 0 and self.max_steps_per_sample >= 1):
            raise ValueError(f"reference solver settings must be positive, got {self}")

    def to_json(self) -> dict:
        return {"method": "diffrax.Dopri8", "controller": "PID", "rtol": self.rtol,
                "atol": self.atol}


def input_path(time: np.ndarray, inputs: list[np.ndarray], method: str) -> jnp.ndarray:
    """Inputs sampled at uniform ``time`` (s) as the reference solve reads them: an array
    (N − 1, P, degree + 1, K) of K inputs' polynomial pieces, P per sample interval,
    coefficient i of the power i of the time (s) since the piece's start
    (module docstring).

    Raises:
        ValueError: an unknown method.
    """
    n, dt = time.size, float((time[-1] - time[0]) / (time.size - 1))
    values = np.stack(inputs, axis=1) if inputs else np.zeros((n, 0))
    if method == "hold":
        table = values[:-1, None, None, :]
    elif method == "linear":
        table = np.stack([values[:-1], np.diff(values, axis=0) / dt], axis=1)[:, None]
    elif method == "bandlimited":
        # scipy's coefficients, highest power first in units of the sample index, become
        # the lowest power first in seconds
        k, m = values.shape[1], (n - 1) * BANDLIMITED_FACTOR
        c = (np.stack([bandlimited_spline(values[:, i]).c for i in range(k)], axis=-1)
             if k else np.zeros((4, m, 0)))
        table = (c[::-1] / dt ** np.arange(4)[:, None, None]).transpose(1, 0, 2).reshape(
            n - 1, BANDLIMITED_FACTOR, 4, k)
    else:
        raise ValueError(f"unknown input interpolation {method!r}")
    return jnp.asarray(table, dtype=float)


def _structure(equations: tuple[Coefficients, ...]) -> tuple[
        tuple[sp.Expr, ...], tuple[sp.Symbol, ...], np.ndarray]:
    """Each equation's second derivative as one sympy expression in the states, t, the
    inputs and one symbol per constant; the symbols and their values. A feature's own
    numbers (a sin's frequency and phase, a smoothed sign's scale; not an exponent) are
    constants too, so models that differ only in them share one compiled solve (a sign
    narrowed for the width check compiled its own, ~2 s each)."""
    expressions, values = [], []

    def constant(value: float) -> sp.Symbol:
        values.append(float(value))
        return sp.Symbol(f"_c{len(values) - 1}")

    for coefficients in equations:
        inverse_mass = constant(1.0 / coefficients.mass)
        features = [(f, -value) for f, value in coefficients.state.items()]
        features += list(coefficients.forcing.items())
        force = sp.Integer(0)
        for feature, value in features:
            c = constant(value)
            force = force + c * numbers_lifted(feature, constant)
        expressions.append(inverse_mass * force)
    return tuple(expressions), tuple(sp.Symbol(f"_c{k}") for k in range(len(values))), \
        np.array(values)


@lru_cache(maxsize=64)
def _solve_program(expressions: tuple[sp.Expr, ...], names: tuple, constants: tuple,
                   method: str, solver: ReferenceSolver) -> Program:
    """The compiled reference solve of one structure, shared by its models and by every
    record of a length bucket: ``program(values, path, ts, n, y0, scale) -> (x / scale at
    ts (N', D), succeeded)`` with ``path`` from :func:`input_path` and ``ts`` the sample
    times (s), both padded to the bucket's N' samples (:func:`gpjax._record.padded_length`),
    ``n`` the record's samples (the intervals past them are skipped), ``y0`` and ``scale``
    (2, D): each coordinate's (x, x') at the first sample and their typical sizes."""
    rhs = sp.lambdify((*names, constants), list(expressions), modules="jax")
    n_inputs = len(names) - 2 * len(expressions) - 1

    def field(time, y, args):
        values, (start, length, table), scale = args
        # the piece of this interval's (P, degree + 1, K) table that ``time`` falls in
        piece = jnp.clip(jnp.floor((time - start) / length).astype(int), 0, table.shape[0] - 1)
        since = time - (start + piece * length)
        u = table[piece, -1]
        for power in range(table.shape[1] - 2, -1, -1):
            u = u * since + table[piece, power]
        position, velocity = y[0] * scale[0], y[1] * scale[1]
        acceleration = jnp.stack(rhs(*position, *velocity, time,
                                     *(u[k] for k in range(n_inputs)), values))
        return jnp.stack([velocity, acceleration]) / scale

    def solve(values, path, ts, n, y0, scale):
        import diffrax  # traced only when compiled (gpjax._integrate.rk4_solver)

        term = diffrax.ODETerm(field)
        controller = diffrax.PIDController(rtol=solver.rtol, atol=solver.atol)
        count = path.shape[1]  # pieces per interval
        knots = jnp.arange(count + 1) / count  # of one interval

        def advance(y, k):
            # The band-limited input is a cubic between knots 1/BANDLIMITED_FACTOR of an
            # interval apart, its third derivative jumping at each: steps end on them
            # (module docstring).
            length = (ts[k + 1] - ts[k]) / count
            steps = controller if count == 1 else diffrax.ClipStepSizeController(
                controller, step_ts=ts[k] + (ts[k + 1] - ts[k]) * knots)
            solution = diffrax.diffeqsolve(
                term, diffrax.Dopri8(), t0=ts[k], t1=ts[k + 1], dt0=None, y0=y,
                args=(values, (ts[k], length, path[k]), scale),
                saveat=diffrax.SaveAt(t1=True), stepsize_controller=steps,
                max_steps=solver.max_steps_per_sample, throw=False)
            ok = (solution.result == diffrax.RESULTS.successful) & jnp.all(
                jnp.isfinite(solution.ys[-1]))
            return solution.ys[-1], ok

        def interval(carry, k):  # after a failure the rest is skipped (NaN), as is padding
            y, ok = carry
            y, succeeded = jax.lax.cond(ok & (k < n - 1), advance,
                                        lambda y, k: (y * jnp.where(ok, 1.0, jnp.nan), ok),
                                        y, k)
            return (y, ok & succeeded), y[0]

        start = y0 / scale
        (_, ok), xs = jax.lax.scan(interval, (start, jnp.array(True)), jnp.arange(ts.size - 1))
        return jnp.concatenate([start[:1], xs]), ok

    return Program(solve, name="reference", key=fingerprint(
        [sp.srepr(e) for e in expressions], names, constants, method, solver))


def reference_response(model, time: np.ndarray, inputs: dict[str, np.ndarray],
                       initial_states, *, scale=None,
                       solver: ReferenceSolver = ReferenceSolver()) -> tuple[np.ndarray, bool]:
    """A model's responses at uniformly spaced sample times by the reference solve:
    :func:`prepared_reference_response`'s solve, run at once (arguments and result as
    there)."""
    return prepared_reference_response(model, time, inputs, initial_states, scale=scale,
                                       solver=solver)()


def prepared_reference_response(model, time: np.ndarray, inputs: dict[str, np.ndarray],
                                initial_states, *, scale=None,
                                solver: ReferenceSolver = ReferenceSolver()
                                ) -> Callable[[], tuple[np.ndarray, bool]]:
    """A model's reference solve at uniformly spaced sample times, compiled (or loaded)
    now and run when the returned function is called, which may be in another thread
    (:meth:`gpjax._aot.Program.prepared`).

    Args:
        model: a :class:`~gpjax._model.Model` of D coordinates.
        time: sample times (N,) in seconds, uniform.
        inputs: the model's inputs by name, (N,) each.
        initial_states: (D, 2) every coordinate's (x, x') at the first sample.
        scale: (D, 2) typical sizes of every x and x' (the absolute tolerance applies to
            x/scale; default ones).
        solver: tolerances.

    Returns:
        The solve: a function returning (responses (N, D), ok); a failed solve gives NaN
        and ``ok`` false.
    """
    enable_float64()
    coordinates = model.coordinates
    expressions, constants, values = _structure(model.system)
    names = tuple(sp.Symbol(n) for n in coordinates) + tuple(
        sp.Symbol(f"{n}_dot") for n in coordinates) + (sp.Symbol(model.time),) + tuple(
        sp.Symbol(n) for n in model.inputs)
    program = _solve_program(expressions, names, constants, model.input_interpolation, solver)
    path = input_path(time, [inputs[name] for name in model.inputs], model.input_interpolation)
    # Padded to the length bucket, so a record of another length in it loads this program:
    # the times go on uniformly, the pieces repeat the last interval's (never solved).
    n, padded = time.size, padded_length(time.size)
    dt = (time[-1] - time[0]) / max(n - 1, 1)
    ts = np.concatenate([time, time[-1] + dt * np.arange(1, padded - n + 1)])
    path = jnp.concatenate([path, jnp.repeat(path[-1:], padded - n, axis=0)])
    scale = np.ones((len(coordinates), 2)) if scale is None else np.asarray(scale, float)
    scale = jnp.asarray(np.where(scale > 0, scale, 1.0).T)
    y0 = np.reshape(np.asarray(initial_states, float), (len(coordinates), 2))
    run = program.prepared(jnp.asarray(values), path, jnp.asarray(ts, dtype=float),
                           jnp.asarray(n), jnp.asarray(y0.T), scale)

    def solved() -> tuple[np.ndarray, bool]:
        scaled, succeeded = run()
        x = np.asarray(scaled)[:n] * np.asarray(scale[0])
        ok = bool(succeeded) and bool(np.all(np.isfinite(x)))
        return (x if ok else np.full(x.shape, np.nan)), ok

    return solved
