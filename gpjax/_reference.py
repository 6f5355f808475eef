"""Reference solve: a model integrated by a high-order adaptive diffrax method.

The run's own integrator is fixed-step RK4 (fast, batched over a population). Whether a
reported model means the same under *any* accurate solver is checked here, independently:
the model's equation is lambdified from sympy to one JAX right-hand side and integrated by
diffrax's 8th-order Dormand–Prince method (``Dopri8``) under PID step-size control with
tight tolerances, the inputs given as functions of continuous time:

* ``linear``: straight lines between samples (the solver steps exactly to every sample,
  where the input has a kink);
* ``hold``: each sample's value until the next (the solver steps to just before and just
  after every sample, where the input jumps);
* ``bandlimited``: the cubic spline of :func:`gpjax._data.bandlimited_spline`, the same
  function the RK4 stage values are taken from.

The state is scaled by the response's and its derivative's spread, so one absolute
tolerance serves both. A solve that fails (a model that blows up, or more steps than
allowed) is returned as data (``ok`` false, NaN response), never raised.
"""

from __future__ import annotations

import dataclasses
from functools import lru_cache

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import sympy as sp

from ._coefficients import Coefficients
from ._data import BANDLIMITED_FACTOR, Measurement, bandlimited_spline
from ._integrate import enable_float64


@dataclasses.dataclass(frozen=True, kw_only=True)
class ReferenceSolver:
    """Settings of the reference solve (diffrax ``Dopri8`` + ``PIDController``).

    Attributes:
        rtol: relative tolerance.
        atol: absolute tolerance on the state scaled to unit spread.
        max_steps_per_sample: step budget per sample interval (the solve fails beyond it).

    Raises:
        ValueError: a non-positive setting.
    """

    rtol: float = 1e-10
    atol: float = 1e-10
    max_steps_per_sample: int = 64

    def __post_init__(self):
        if not (self.rtol > 0 and self.atol > 0 and self.max_steps_per_sample >= 1):
            raise ValueError(f"reference solver settings must be positive, got {self}")

    def to_json(self) -> dict:
        return {"method": "diffrax.Dopri8", "controller": "PID", "rtol": self.rtol,
                "atol": self.atol}


class _Hold(eqx.Module):
    """Piecewise-constant inputs: each sample's value until the next sample time."""

    ts: jax.Array
    ys: jax.Array

    def evaluate(self, t):
        index = jnp.searchsorted(self.ts, t, side="right") - 1
        return self.ys[jnp.clip(index, 0, self.ys.shape[0] - 1)]


def input_path(time: np.ndarray, inputs: list[np.ndarray], method: str):
    """Inputs sampled at uniform ``time`` (s) as a diffrax-ready path
    ``path.evaluate(t) -> (K,)``, with the times the solver must step to (``step_ts``) and
    across (``jump_ts``), per the module docstring: ``(path, step_ts, jump_ts)``.

    Raises:
        ValueError: an unknown method.
    """
    n, dt = time.size, float((time[-1] - time[0]) / (time.size - 1))
    times = jnp.asarray(time)
    values = np.stack(inputs, axis=1) if inputs else np.zeros((n, 0))
    if method == "linear":
        return diffrax.LinearInterpolation(ts=times, ys=jnp.asarray(values)), times, None
    if method == "hold":
        return _Hold(ts=times, ys=jnp.asarray(values)), None, times
    if method == "bandlimited":
        splines = [bandlimited_spline(values[:, k]) for k in range(values.shape[1])]
        fine = np.arange((n - 1) * BANDLIMITED_FACTOR + 1) / BANDLIMITED_FACTOR
        # scipy's coefficients (highest power first, in units of the sample index) rescaled
        # to seconds are diffrax's (d, c, b, a); one column per input
        coeffs = tuple(jnp.asarray(np.stack([s.c[i] for s in splines], axis=-1).reshape(
            fine.size - 1, len(splines)) / dt ** (3 - i)) for i in range(4))
        path = diffrax.CubicInterpolation(ts=jnp.asarray(time[0] + fine * dt), coeffs=coeffs)
        return path, None, None
    raise ValueError(f"unknown input interpolation {method!r}")


def _structure(equations: tuple[Coefficients, ...]) -> tuple[
        tuple[sp.Expr, ...], tuple[sp.Symbol, ...], np.ndarray]:
    """Each equation's second derivative as one sympy expression in the states, t, the
    inputs and one symbol per constant; the symbols and their values."""
    expressions, values, count = [], [], 0
    for coefficients in equations:
        features = [(f, -value) for f, value in coefficients.state.items()]
        features += list(coefficients.forcing.items())
        constants = sp.symbols(f"_c{count}:{count + len(features) + 1}")
        force = sum((c * f for c, (f, _) in zip(constants[1:], features)), sp.Integer(0))
        expressions.append(constants[0] * force)
        values += [1.0 / coefficients.mass] + [v for _, v in features]
        count += len(features) + 1
    return tuple(expressions), sp.symbols(f"_c0:{count}"), np.array(values)


@lru_cache(maxsize=64)
def _field(expressions: tuple[sp.Expr, ...], names: tuple, constants: tuple):
    """The scaled vector field ``field(t, y, (values, path, scale))`` of one structure,
    y of shape (2, D); cached, so models of one structure share a compiled solve."""
    rhs = sp.lambdify((*names, constants), list(expressions), modules="jax")
    count = len(expressions)
    n_inputs = len(names) - 2 * count - 1

    def field(time, y, args):
        values, path, scale = args
        position, velocity = y[0] * scale[0], y[1] * scale[1]
        inputs = path.evaluate(time)
        acceleration = jnp.stack(rhs(*position, *velocity, time,
                                     *(inputs[k] for k in range(n_inputs)), values))
        return jnp.stack([velocity, acceleration]) / scale
    return field


def reference_response(model, time: np.ndarray, inputs: dict[str, np.ndarray],
                       initial_conditions: tuple[float, float], *,
                       scale: tuple[float, float] = (1.0, 1.0),
                       solver: ReferenceSolver = ReferenceSolver()) -> tuple[np.ndarray, bool]:
    """A model's response at uniformly spaced sample times by the reference solve.

    Args:
        model: a :class:`~gpjax._model.Model`.
        time: sample times (N,) in seconds, uniform.
        inputs: the model's inputs by name, (N,) each.
        initial_conditions: (x, x') at the first sample.
        scale: typical sizes of x and x' (the absolute tolerance applies to x/scale).
        solver: tolerances.

    Returns:
        (response (N,), ok); a failed solve gives NaN and ``ok`` false.
    """
    symbols = model.symbols
    x, ok = reference_system_response(
        (model.coefficients,), (symbols.response,), symbols.time, symbols.inputs, time, inputs,
        [initial_conditions], interpolation=model.input_interpolation, scale=[scale],
        solver=solver)
    return x[:, 0], ok


def reference_system_response(equations, coordinates: tuple[str, ...], time_name: str,
                              input_names: tuple[str, ...], time: np.ndarray,
                              inputs: dict[str, np.ndarray], initial_states, *,
                              interpolation: str = "linear", scale=None,
                              solver: ReferenceSolver = ReferenceSolver()
                              ) -> tuple[np.ndarray, bool]:
    """The response of a system of equations (one :class:`Coefficients` per coordinate,
    features in the ``coordinates``' names, ``NAME_dot``, ``time_name`` and the inputs) at
    uniformly spaced sample ``time`` by the reference solve.

    Args:
        initial_states: (D, 2) each coordinate's (x, x') at the first sample.
        interpolation: the inputs between samples (the module docstring).
        scale: (D, 2) typical sizes of each x and x' (default ones).

    Returns:
        (responses (N, D), ok); a failed solve gives NaN and ``ok`` false.
    """
    enable_float64()
    expressions, constants, values = _structure(tuple(equations))
    names = tuple(sp.Symbol(n) for n in coordinates) + tuple(
        sp.Symbol(f"{n}_dot") for n in coordinates) + (sp.Symbol(time_name),) + tuple(
        sp.Symbol(n) for n in input_names)
    field = _field(expressions, names, constants)
    path, step_ts, jump_ts = input_path(time, [inputs[name] for name in input_names],
                                        interpolation)
    scale = np.ones((len(coordinates), 2)) if scale is None else np.asarray(scale, float)
    scale = jnp.asarray(np.where(scale > 0, scale, 1.0).T)
    controller = diffrax.PIDController(rtol=solver.rtol, atol=solver.atol)
    if step_ts is not None or jump_ts is not None:
        controller = diffrax.ClipStepSizeController(controller, step_ts=step_ts,
                                                    jump_ts=jump_ts)
    dt = float((time[-1] - time[0]) / (time.size - 1))
    solution = diffrax.diffeqsolve(
        diffrax.ODETerm(field), diffrax.Dopri8(), t0=float(time[0]), t1=float(time[-1]),
        dt0=dt / 4, y0=jnp.asarray(np.asarray(initial_states, float).T) / scale,
        args=(jnp.asarray(values), path, scale), saveat=diffrax.SaveAt(ts=jnp.asarray(time)),
        stepsize_controller=controller, max_steps=solver.max_steps_per_sample * time.size,
        throw=False)
    x = np.asarray(solution.ys[:, 0]) * np.asarray(scale[0])
    ok = bool(solution.result == diffrax.RESULTS.successful) and bool(np.all(np.isfinite(x)))
    return (x if ok else np.full(x.shape, np.nan)), ok


def measurement_scale(measurement: Measurement) -> tuple[float, float]:
    """Typical sizes of x and x' in a measurement: the spreads of the response and of its
    sample-to-sample rate."""
    return (float(np.std(measurement.response)),
            float(np.std(np.diff(measurement.response)) / measurement.dt))
