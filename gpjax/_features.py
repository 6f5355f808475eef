"""Non-polynomial state features with inner constants: the feature bank.

A state term is any function of x alone or of x' alone (eqs. 5–6). Besides the powers of
eq. 10, gpjax simulates the *families* below of one variable z (x or x'). A family is
compiled once per evaluator, and its inner constants θ are data (an array per model), so
Levenberg–Marquardt refines them with the outer coefficients and a new θ never compiles:

=========  ====================  ==  =========================================
family     feature               θ   made by the tree functions
=========  ====================  ==  =========================================
``abs``    z^k·|z|, k = 0 … D−1  –   abs (x'·|x'|: quadratic drag)
``tanh``   tanh(θ0·z)            1   tanh; sign(z), smoothed (below)
``sin``    sin(θ0·z + θ1)        2   sin
``cos``    cos(θ0·z + θ1)        2   cos
``exp``    exp(θ0·z)             1   exp (a factor e^b of exp(a·z + b) is a coefficient)
``sinh``   sinh(θ0·z)            1   sinh; exp (an exp pair with one scale, below)
``cosh``   cosh(θ0·z)            1   cosh; exp (likewise)
``stribeck``  exp(−(θ0·z)²)·      2   exp *and* tanh or sign; of x' only (below)
           tanh(θ1·z)
=========  ====================  ==  =========================================

**Stribeck friction.** The Stribeck law (Fc + (Fs − Fc)·exp(−(x'/vs)²))·sign(x') is a
Coulomb term (``tanh``) plus this family, 1/θ0 = vs the Stribeck velocity; a product of
two tree functions, so it is in the bank only where the function set has both. Its sign
is smoothed like the Coulomb term's: local search adds it with θ1 held at the smoothed
sign's scale (:mod:`gpjax._select_moves`), so it has one fitted inner constant, vs.

**exp pairs, sinh and cosh.** The symmetric exponential laws of stiffening springs are
exp pairs: k·sinh(z/a) = k/2·(exp(z/a) − exp(−z/a)). A model holds one member of each
family except ``exp``, which has two slots (:data:`SLOTS`; the k-th member of a model takes
the k-th slot, :meth:`gpjax._evaluator.PopulationEvaluator.state_columns`), each with its
own scale. A pair with one scale is sinh or cosh: the same law with one fitted constant
fewer, which the final selection's tie move proposes (:mod:`gpjax._select_moves`). The
``exp`` function brings them into the bank (and into local search's extensions, written
with sinh and cosh tree nodes, as compact as tanh's); ``sinh`` and ``cosh`` may also be
given as tree functions.

**sign, smoothed.** A GP candidate's sign(z) (dry friction) enters the search as
tanh(z/ε) with ε = :data:`SIGN_WIDTH` × RMS(z) on the data: a discontinuous right-hand side
would cost the fixed-step RK4 its order at every zero crossing, and the smoothed law is a
member of the ``tanh`` family, so ε is refined like any inner constant. The model reports
the tanh it was fitted with, so the reported ODE is what any accurate solver integrates;
its width is narrowed until the constants no longer depend on it (:mod:`gpjax._sign_width`).
A ``sign`` written in a model file is simulated as the exact sign.
"""

from __future__ import annotations

import dataclasses
import math
from functools import lru_cache

import jax.numpy as jnp
import sympy as sp

from ._canonical import Symbols

#: Tree functions that make state-feature families, by family: a family is in the bank
#: when the function set holds one function of each group.
FAMILY_FUNCTIONS = {"abs": (("abs",),), "tanh": (("tanh", "sign"),), "sin": (("sin",),),
                    "cos": (("cos",),), "exp": (("exp",),), "sinh": (("exp", "sinh"),),
                    "cosh": (("exp", "cosh"),), "stribeck": (("exp",), ("tanh", "sign"))}
#: Variables a family is built for where not both (a velocity law).
ROLES = {"stribeck": ("x_dot",)}
#: Width of the smoothed sign, as a fraction of the RMS of its argument in the data.
SIGN_WIDTH = 0.01
#: Largest |exponent argument| evaluated (beyond it exp overflows float64 at 709.8).
EXP_LIMIT = 700.0
#: Starts of a family's scale θ0 tried beside the tree's, as θ0·RMS(z) (tanh: 100 is the
#: smoothed sign's width; sin/cos keep the tree's phase b; stribeck: vs from a third to a
#: hundredth of RMS(x'), its sign's θ1 kept).
INNER_GRID = {"tanh": (1.0, 3.0, 10.0, 100.0), "sin": (0.5, 1.0, 2.0), "cos": (0.5, 1.0, 2.0),
              "exp": (-2.0, -1.0, -0.5, 0.5, 1.0, 2.0), "sinh": (0.5, 1.0, 2.0, 4.0),
              "cosh": (0.5, 1.0, 2.0, 4.0), "stribeck": (3.0, 10.0, 30.0, 100.0)}
_INNER = {"abs": 0, "tanh": 1, "sin": 2, "cos": 2, "exp": 1, "sinh": 1, "cosh": 1,
          "stribeck": 2}
#: The one-scale families, by their sympy and JAX functions.
_SCALED = {"tanh": (sp.tanh, jnp.tanh), "exp": (sp.exp, jnp.exp), "sinh": (sp.sinh, jnp.sinh),
           "cosh": (sp.cosh, jnp.cosh)}
#: Members of one family a model may hold (columns per family and variable; module
#: docstring, "Slots").
SLOTS = {"exp": 2}


@dataclasses.dataclass(frozen=True)
class Family:
    """One compiled feature of one variable: ``function`` of ``role`` (``"x"`` or
    ``"x_dot"``); ``power`` k of the ``abs`` family's z^k·|z|; ``slot``: which of the
    family's columns (:data:`SLOTS`)."""

    function: str
    role: str
    power: int = 0
    slot: int = 0

    @property
    def n_inner(self) -> int:
        return _INNER[self.function]

    @property
    def unit(self) -> tuple[float, ...]:
        """Inner constants of the family's member written in the basis: scales 1, phase 0."""
        return (1.0, 0.0) if self.function in ("sin", "cos") else (1.0,) * self.n_inner

    def variable(self, symbols: Symbols) -> sp.Symbol:
        return symbols.x if self.role == "x" else symbols.x_dot

    def feature(self, symbols: Symbols, theta=()) -> sp.Expr:
        """The feature with inner constants ``theta`` (floats) as a sympy expression."""
        z = self.variable(symbols)
        a = [sp.Float(v) for v in theta]
        if self.function == "abs":
            return z ** self.power * sp.Abs(z)
        if self.function in _SCALED:
            return _SCALED[self.function][0](a[0] * z)
        if self.function == "stribeck":
            return sp.exp(-(a[0] * z) ** 2) * sp.tanh(a[1] * z)
        return (sp.sin if self.function == "sin" else sp.cos)(a[0] * z + a[1])

    def __call__(self, z, theta):
        """Values for states ``z`` (P,) and inner constants ``theta`` (P, n_inner) (JAX)."""
        if self.function == "abs":
            return z ** self.power * jnp.abs(z)
        if self.function == "tanh":
            return jnp.tanh(theta[..., 0] * z)
        if self.function == "stribeck":
            return jnp.exp(-(theta[..., 0] * z) ** 2) * jnp.tanh(theta[..., 1] * z)
        if self.function in _SCALED:  # exp, sinh, cosh: clipped below float64's overflow
            return _SCALED[self.function][1](jnp.clip(theta[..., 0] * z, -EXP_LIMIT, EXP_LIMIT))
        phase = theta[..., 0] * z + theta[..., 1]
        return jnp.sin(phase) if self.function == "sin" else jnp.cos(phase)


def inner_constants(feature: sp.Expr) -> int:
    """Inner constants a state feature's family fits: sin/cos(a·z + b) 2, tanh, exp, sinh
    and cosh of a·z 1 (a product of them: the sum, stribeck's 2), powers and z^k·|z|
    none."""
    return sum(_INNER.get(f.func.__name__, 0) for f in sp.Mul.make_args(feature))


def families_for(functions, roles, max_degree: int) -> tuple[Family, ...]:
    """The families the tree ``functions`` can make for the variables ``roles`` (of
    ``"x"``, ``"x_dot"``), in a fixed order."""
    found = []
    for name, groups in FAMILY_FUNCTIONS.items():
        if not all(set(makers) & set(functions) for makers in groups):
            continue
        for role in ROLES.get(name, ("x", "x_dot")):
            if role not in roles:
                continue
            powers = range(max_degree) if name == "abs" else (0,)
            found += [Family(name, role, k, slot) for k in powers
                      for slot in range(SLOTS.get(name, 1))]
    return tuple(found)


def match(feature: sp.Expr, symbols: Symbols) -> tuple[Family, tuple[float, ...]] | None:
    """The family (its first slot) of a concrete state feature and its inner constants,
    or ``None`` when the feature is no family member (a power, another product of
    functions, sin(x²), …).
    ``sign(z)`` is not matched here: it becomes a tanh with the data's width first
    (:func:`smoothed_sign`)."""
    return _match(feature, symbols)


@lru_cache(maxsize=100_000)
def _match(feature: sp.Expr, symbols: Symbols):
    for role, z in (("x", symbols.x), ("x_dot", symbols.x_dot)):
        if feature.free_symbols != {z}:
            continue
        powers = feature.as_powers_dict()
        if powers.get(sp.Abs(z)) == 1 and set(powers) <= {z, sp.Abs(z)}:
            k = powers.get(z, 0)
            return (Family("abs", role, int(k)), ()) if sp.Integer(k) == k and k >= 0 else None
        if isinstance(feature, sp.Mul):
            return _stribeck(feature, z) if role in ROLES["stribeck"] else None
        if not isinstance(feature, (sp.tanh, sp.exp, sp.sinh, sp.cosh, sp.sin, sp.cos)):
            return None
        linear = _affine(feature.args[0], z)
        if linear is None:
            return None
        slope, offset = linear
        if isinstance(feature, (sp.sin, sp.cos)):
            name = "sin" if isinstance(feature, sp.sin) else "cos"
            return Family(name, role), (slope, offset)
        if offset != 0.0:
            return None
        return Family(feature.func.__name__, role), (slope,)
    return None


def _stribeck(feature: sp.Mul, z: sp.Symbol):
    """(Family, (θ0, θ1)) of exp(−θ0²·z²)·tanh(θ1·z), else ``None``."""
    factors = sp.Mul.make_args(feature)
    gauss = [f for f in factors if isinstance(f, sp.exp)]
    smooth = [f for f in factors if isinstance(f, sp.tanh)]
    if len(factors) != 2 or len(gauss) != 1 or len(smooth) != 1:
        return None
    exponent = sp.expand(gauss[0].args[0])
    curvature = exponent.coeff(z, 2)
    slope = _affine(smooth[0].args[0], z)
    if (not curvature.is_number or curvature >= 0 or sp.expand(curvature * z ** 2) != exponent
            or slope is None or slope[1] != 0.0):
        return None
    return Family("stribeck", "x_dot"), (math.sqrt(-float(curvature)), slope[0])


def _affine(argument: sp.Expr, z: sp.Symbol) -> tuple[float, float] | None:
    """(a, b) of an argument a·z + b with numbers a ≠ 0 and b, else ``None``."""
    expanded = sp.expand(argument)
    slope = expanded.coeff(z, 1)
    offset = expanded.coeff(z, 0)
    if not (slope.is_number and offset.is_number) or slope == 0:
        return None
    if sp.expand(slope * z + offset - expanded) != 0:
        return None
    return float(slope), float(offset)


def smoothed_sign(feature: sp.Expr, symbols: Symbols, widths: dict[str, float]) -> sp.Expr:
    """``feature`` with every sign(x) and sign(x') replaced by tanh(z/ε), ε = ``widths``
    of that variable (see the module docstring)."""
    replacements = {sp.sign(z): sp.tanh(z / sp.Float(widths[role]))
                    for role, z in (("x", symbols.x), ("x_dot", symbols.x_dot))}
    return feature.xreplace(replacements) if feature.has(sp.sign) else feature
