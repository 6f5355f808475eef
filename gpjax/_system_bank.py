"""Non-polynomial terms of a system's equations (several coordinates): the system bank.

Equation i of a system has 2D variables z (:func:`system_variables`): x_i, x_i − x_j
(j ≠ i), x_i', x_i' − x_j'. Beside their powers (eqs. 5–6 per variable), the function set
brings these *kinds*, one state column per kind and variable:

========  ============================  ==================
kind      feature of z                  tree functions
========  ============================  ==================
``sign``  tanh(θ·z), θ = 1/ε            sign, tanh
``abs``   z·|z|                         abs
``sin``   sin(z)                        sin
``cos``   cos(z)                        cos
========  ============================  ==================

So dry friction between two masses is tanh(θ·(x1' − x2')), quadratic drag x1'·|x1'|, and a
pendulum's restoring torque sin(x1) of its angle in rad.

**Where this differs from one coordinate's bank** (:mod:`gpjax._features`): no inner
constant is fitted. ``sin`` and ``cos`` act on the variable in its own units (an angle in
rad), so sin(a·z) with a ≠ ±1 is no valid term; a tree's tanh(a·z) is read as the smoothed
sign of a·z. The smoothed sign's width is one coordinate's starting width, ε =
:data:`gpjax._features.SIGN_WIDTH` × RMS(z) on the smoothed record (the reported model holds
the tanh it was fitted with, so any accurate solver integrates the same ODE). The scales θ
are data — a program argument (:attr:`gpjax._record.RecordArrays.sign_scales`) — so a new
record compiles nothing. As for one coordinate (:mod:`gpjax._sign_width`), the reported
system must not depend on that width: its reference response with every sign
:data:`gpjax._sign_width.NARROWING` times narrower, constants unchanged, must differ from
its own by less than the convergence tolerance of its RMS residual; otherwise the search
refits it with the narrower signs by one coordinate's rule
(:func:`gpjax._sign_width.next_narrowing`; :meth:`gpjax._system_search.SystemEvolution.finish`).
"""

from __future__ import annotations

from typing import Callable

import jax.numpy as jnp
import numpy as np
import sympy as sp

from ._features import SIGN_WIDTH

#: The kinds in column order (module docstring).
KINDS = ("sign", "abs", "sin", "cos")
#: Tree functions that make each kind.
MAKERS = {"sign": ("sign", "tanh"), "abs": ("abs",), "sin": ("sin",), "cos": ("cos",)}
#: Every function a system's trees may use.
SYSTEM_FUNCTIONS = ("add", "sub", "mul", "sign", "tanh", "abs", "sin", "cos")


def kinds_for(functions) -> tuple[str, ...]:
    """The kinds the tree ``functions`` make, in :data:`KINDS` order."""
    return tuple(k for k in KINDS if set(MAKERS[k]) & set(functions))


def system_variables(names: tuple[str, ...]) -> list[list[sp.Expr]]:
    """Per equation i of a system with coordinates ``names``: x_i, x_i − x_j (j ≠ i, in
    order), x_i', x_i' − x_j' (the order of every per-variable column)."""
    positions = [sp.Symbol(name) for name in names]
    velocities = [sp.Symbol(f"{name}_dot") for name in names]
    others = [[j for j in range(len(names)) if j != i] for i in range(len(names))]
    return [[z[i] - z[j] if j != i else z[i] for z in (positions, velocities)
             for j in [i, *others[i]]] for i in range(len(names))]


def bank_feature(kind: str, z: sp.Expr, scale: float = 1.0) -> sp.Expr:
    """The feature of ``kind`` of variable ``z`` (sympy); ``scale``: the sign's θ."""
    if kind == "sign":
        return sp.tanh(sp.Float(scale) * z)
    if kind == "abs":
        return z * sp.Abs(z)
    return (sp.sin if kind == "sin" else sp.cos)(z)


def bank_values(kind: str, z, scale):
    """(value, slope) of ``kind`` at ``z`` (JAX arrays; ``scale`` broadcasts to ``z``)."""
    if kind == "sign":
        value = jnp.tanh(scale * z)
        return value, scale * (1.0 - value * value)
    if kind == "abs":
        return z * jnp.abs(z), 2.0 * jnp.abs(z)
    if kind == "sin":
        return jnp.sin(z), jnp.cos(z)
    return jnp.cos(z), -jnp.sin(z)


def match_bank(feature: sp.Expr, variables: list[sp.Expr]) -> tuple[str, int, float] | None:
    """(kind, position in ``variables``, θ) of a feature of one equation's bank, or
    ``None`` (θ 1.0 but for the sign)."""
    for position, z in enumerate(variables):
        if feature.free_symbols != z.free_symbols:
            continue
        for kind in ("abs", "sin", "cos"):
            if sp.expand(feature - bank_feature(kind, z)) == 0:
                return kind, position, 1.0
        signs = feature.atoms(sp.tanh)  # tanh(θ·z), or −tanh(θ·(−z)) as sympy writes it
        if len(signs) == 1:
            argument = sp.expand(next(iter(signs)).args[0])
            scale = abs(argument.coeff(next(iter(sp.ordered(z.free_symbols)))))
            if scale.is_number and scale > 0 and sp.expand(
                    feature - bank_feature("sign", z, float(scale))) == 0:
                return "sign", position, float(scale)
    return None


def sign_scales(names: tuple[str, ...], rms: Callable[[sp.Expr], float]) -> np.ndarray:
    """(D·2D,) θ = 1/(SIGN_WIDTH·RMS(z)) of every equation's variables in order
    (:func:`system_variables`), ``rms`` giving RMS(z) on the smoothed record (1 where it
    is 0)."""
    return np.array([1.0 / (SIGN_WIDTH * (rms(z) or 1.0))
                     for variables in system_variables(names) for z in variables])


def bank_of(names: tuple[str, ...], features: list) -> tuple[tuple[str, ...], np.ndarray]:
    """(kinds, sign scales) an evaluator needs for the state ``features`` of every
    equation (the sign's θ from its feature; 1 where no sign is used).

    Raises:
        ValueError: a feature that is neither a power nor of the bank.
    """
    variables = system_variables(names)
    scales, kinds = np.ones(len(names) * 2 * len(names)), set()
    for i, equation in enumerate(features):
        for feature in equation:
            base, exponent = feature.as_base_exp()
            if exponent.is_Integer and exponent > 0 and base in variables[i]:
                continue
            found = match_bank(feature, variables[i])
            if found is None:
                raise ValueError(
                    f"feature {feature} of equation {i + 1} is neither a power nor a bank "
                    f"term (tanh(θ·z), z·|z|, sin(z), cos(z)) of {names[i]}, {names[i]}_dot "
                    "or their differences to the other coordinates")
            kinds.add(found[0])
            scales[i * len(variables[i]) + found[1]] = found[2]
    return tuple(k for k in KINDS if k in kinds), scales
