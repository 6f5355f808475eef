"""The effect library: physical effects a Newton–Euler model may lack.

Every effect has a name, a physical meaning, its term(s) in Newton–Euler form (state terms
of x alone or x' alone, declared time-varying terms g(t)·h(x), or forcing terms of time
and inputs — the structure rules of eqs. 3–6 and their ``parametric`` extension in
:mod:`gpjax._model`), its nonlinear parameters with bounds, and its residual signature.
Linear coefficients are not parameters: they come from least squares and refinement.
Nonlinear parameters (a frequency, a dead-zone width, a friction smoothing velocity) are
searched on a grid built from the data, then polished (see :mod:`gpjax._diagnose`).

Users add their own with :func:`register_effect`.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Callable

import numpy as np
import sympy as sp

from ._canonical import Symbols


@dataclasses.dataclass(frozen=True)
class Parameter:
    """A nonlinear effect parameter: name, unit (words) and bounds (lower, upper)."""

    name: str
    unit: str
    lower: float
    upper: float


@dataclasses.dataclass(frozen=True)
class Context:
    """What effects need from the data to build their terms and grids.

    Attributes:
        symbols: names of response, time and inputs.
        x: measured response (N,).
        x_dot: smoothed derivative of the response (N,), response units per second.
        time: sample times (N,), seconds.
        inputs: input name -> values (N,).
        frequencies: candidate frequencies in Hz (given by the user, then the input's
            strongest spectral lines).
        forcing: text of the forcing features the current model already has.
    """

    symbols: Symbols
    x: np.ndarray
    x_dot: np.ndarray
    time: np.ndarray
    inputs: dict[str, np.ndarray]
    frequencies: tuple[float, ...]
    forcing: tuple[str, ...]


@dataclasses.dataclass(frozen=True)
class Terms:
    """The features one effect with fixed nonlinear parameters adds (sympy expressions)."""

    state: tuple[sp.Expr, ...] = ()
    parametric: tuple[sp.Expr, ...] = ()
    forcing: tuple[sp.Expr, ...] = ()


@dataclasses.dataclass(frozen=True)
class Effect:
    """One physical effect.

    Attributes:
        name: identifier used in reports (``cubic_stiffness``).
        meaning: what it is physically, in words.
        term: its term in Newton–Euler form, in words/symbols (``k·x³``).
        signature: what it leaves in the residual when missing.
        parameters: nonlinear parameters with bounds (empty if none).
        grid: context -> list of parameter dicts to try (``[{}]`` for none).
        build: (context, parameters) -> :class:`Terms`, or ``None`` if not applicable.
        sign: +1 if the physical effect has a positive coefficient on the left-hand side
            (m·x'' + … = forcing; a loss: damping, friction), −1 if negative, 0 if either;
            a fit of the other sign is flagged in the report as not the effect named.
    """

    name: str
    meaning: str
    term: str
    signature: str
    parameters: tuple[Parameter, ...]
    grid: Callable[[Context], list[dict]]
    build: Callable[[Context, dict], Terms | None]
    sign: int = 0

    def bounds(self, context: Context) -> dict[str, tuple[float, float]]:
        """Bounds of the numeric parameters, scaled to the data where the unit says so."""
        return {p.name: _scaled_bounds(p, context) for p in self.parameters}


#: Least share of the samples inside a backlash dead zone, and outside it: a narrower zone
#: is a kink, and one the motion never enters (or never leaves) is a constant force plus a
#: stiffness change (or nothing), which simpler effects describe.
MIN_DEAD_ZONE_SHARE = 0.1

_REGISTRY: dict[str, Effect] = {}


def register_effect(effect: Effect, *, replace: bool = False) -> None:
    """Add ``effect`` to the library.

    Raises:
        ValueError: an effect of that name exists and ``replace`` is false.
    """
    if effect.name in _REGISTRY and not replace:
        raise ValueError(f"effect {effect.name!r} is already registered; pass replace=True")
    _REGISTRY[effect.name] = effect


def effects() -> dict[str, Effect]:
    """The registered effects by name, in registration order."""
    return dict(_REGISTRY)


def _scaled_bounds(parameter: Parameter, context: Context) -> tuple[float, float]:
    scale = {"x_dot std": float(np.std(context.x_dot)) or 1.0,
             "x std": float(np.std(context.x)) or 1.0}.get(parameter.unit, 1.0)
    if parameter.unit == "x":  # a position well inside the measured range
        return tuple(map(float, np.quantile(context.x, [0.1, 0.9])))
    if parameter.unit == "Hz":
        nyquist = 0.5 / float(np.mean(np.diff(context.time)))
        return parameter.lower, min(parameter.upper, nyquist)
    return parameter.lower * scale, parameter.upper * scale


def dead_zone(x: sp.Expr, centre: float, half_width: float) -> sp.Expr:
    """x − c outside [c − b, c + b], zero inside, with whitelisted functions only (Abs)."""
    c, b = sp.Float(centre), sp.Float(half_width)
    return (x - c) + (sp.Abs(x - c - b) - sp.Abs(x - c + b)) / 2


def _none(context: Context) -> list[dict]:
    del context
    return [{}]


def _state(feature: Callable[[Symbols], sp.Expr]) -> Callable[[Context, dict], Terms]:
    return lambda context, parameters: Terms(state=(feature(context.symbols),))


def _friction_grid(context: Context) -> list[dict]:
    scale = float(np.std(context.x_dot)) or 1.0
    return [{"smoothing": f * scale} for f in (0.003, 0.01, 0.03, 0.1, 0.3)]


def _friction(context: Context, parameters: dict) -> Terms:
    v = context.symbols.x_dot
    return Terms(state=(sp.tanh(v / sp.Float(parameters["smoothing"])),))


def _mesh_grid(context: Context) -> list[dict]:
    return [{"frequency": f} for f in context.frequencies]


def _mesh(context: Context, parameters: dict) -> Terms:
    s = context.symbols
    omega = sp.Float(2 * math.pi * parameters["frequency"])
    return Terms(parametric=(sp.cos(omega * s.t) * s.x, sp.sin(omega * s.t) * s.x))


def _backlash_grid(context: Context) -> list[dict]:
    x = context.x
    spread = float(np.std(x)) or 1.0
    centres = list(map(float, np.quantile(x, np.linspace(0.1, 0.9, 9))))
    if np.min(x) < 0 < np.max(x):
        centres.append(0.0)
    return [{"centre": c, "half_width": float(w) * spread}
            for c in centres for w in np.geomspace(0.05, 1.5, 7)]


def _backlash(context: Context, parameters: dict) -> Terms | None:
    """The dead-zone term, or ``None`` if the measured motion does not exercise the dead
    zone (less than :data:`MIN_DEAD_ZONE_SHARE` of the samples inside it, or outside it)."""
    c, b = parameters["centre"], parameters["half_width"]
    inside = float(np.mean(np.abs(context.x - c) < b))
    if not MIN_DEAD_ZONE_SHARE <= inside <= 1.0 - MIN_DEAD_ZONE_SHARE:
        return None
    return Terms(state=(dead_zone(context.symbols.x, c, b),))


def _input_grid(context: Context) -> list[dict]:
    return [{"input": name} for name in context.symbols.inputs if name not in context.forcing]


def _input(context: Context, parameters: dict) -> Terms | None:
    if parameters.get("input") not in context.symbols.inputs:
        return None
    return Terms(forcing=(sp.Symbol(parameters["input"]),))


for _effect in (
    Effect("viscous_damping", "energy loss proportional to velocity (oil film, material "
           "damping)", "c·x'", "residual force in phase with x'; decay of free oscillation",
           (), _none, _state(lambda s: s.x_dot), sign=1),
    Effect("coulomb_friction", "dry friction of constant magnitude opposing motion, smoothed "
           "by tanh(x'/ε)", "F·tanh(x'/ε)", "square-wave residual force switching with the "
           "sign of x'; odd harmonics", (Parameter("smoothing", "x_dot std", 1e-4, 1.0),),
           _friction_grid, _friction, sign=1),
    Effect("quadratic_stiffness", "asymmetric (hardening on one side) stiffness, e.g. tooth "
           "contact", "k·x²", "residual at twice the response frequency and a mean shift",
           (), _none, _state(lambda s: s.x ** 2)),
    Effect("cubic_stiffness", "symmetric hardening or softening stiffness (Duffing)", "k·x³",
           "residual at three times the response frequency; amplitude-dependent resonance",
           (), _none, _state(lambda s: s.x ** 3)),
    Effect("mesh_stiffness_variation", "stiffness varying periodically in time, e.g. the "
           "number of teeth in contact changing at the mesh frequency",
           "k·cos(2πf·t + ψ)·x", "sidebands f ± (response frequencies) in the residual "
           "spectrum", (Parameter("frequency", "Hz", 1e-3, 1e9),), _mesh_grid, _mesh),
    Effect("static_offset", "a constant force (preload, gravity, sensor or input offset)",
           "F0 (constant)", "residual with non-zero mean; DC in the spectrum", (), _none,
           lambda context, parameters: Terms(forcing=(sp.Integer(1),))),
    Effect("backlash", "clearance: no restoring force inside a dead zone of half width b "
           "around c", "k·dz(x; c, b)", "residual force only at large |x − c|; stiffness "
           "that changes with amplitude", (Parameter("centre", "x", 0.0, 0.0),
                                            Parameter("half_width", "x std", 0.03, 3.0)),
           _backlash_grid, _backlash),
    Effect("input_gain", "an input acting on the system that the model leaves out (its "
           "scale is fitted)", "g·u", "residual force correlated with an input", (),
           _input_grid, _input),
):
    register_effect(_effect)
