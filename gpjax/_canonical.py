"""Canonical Newton–Euler form and the structure rules of §3 (eqs. 3–6), decided with sympy.

A candidate expression E (read as E = 0) is expanded and each additive term classified:

* a term holding x'' must be (non-zero constant)·x'' — constant inertia (eq. 3);
* every other term depends on x only, on x' only (eqs. 5–6), or on time/inputs only;
* anything else (x''·x, x·x', x·u, …) is a cross term and makes the candidate invalid.

Valid candidates become ``m·x'' + Σ c_i·φ_i(x or x') = Σ g_j·ψ_j(t, inputs)``, normalised
so the first input's linear forcing coefficient is 1 (mass 1 when no such term exists).
"""

from __future__ import annotations

import dataclasses
from functools import lru_cache

import sympy as sp

from ._trees import Tree, is_function

#: Coefficients smaller than this (relative to the largest) count as zero after expansion.
ZERO_TOLERANCE = 1e-12


@dataclasses.dataclass(frozen=True)
class Symbols:
    """The sympy symbols of one data set, named after its columns."""

    response: str = "x"
    time: str = "t"
    inputs: tuple[str, ...] = ()

    @property
    def x(self) -> sp.Symbol:
        return sp.Symbol(self.response)

    @property
    def x_dot(self) -> sp.Symbol:
        return sp.Symbol(f"{self.response}_dot")

    @property
    def x_ddot(self) -> sp.Symbol:
        return sp.Symbol(f"{self.response}_ddot")

    @property
    def t(self) -> sp.Symbol:
        return sp.Symbol(self.time)

    @property
    def u(self) -> tuple[sp.Symbol, ...]:
        return tuple(sp.Symbol(name) for name in self.inputs)

    def names(self) -> set[str]:
        return {self.response, f"{self.response}_dot", f"{self.response}_ddot", self.time,
                *self.inputs}


@dataclasses.dataclass(frozen=True)
class CanonicalForm:
    """``mass·x'' + Σ c·state_feature = Σ g·forcing_feature`` with sympy features.

    ``state`` and ``forcing`` are tuples of (feature, coefficient), sorted by feature text.
    Features carry no numeric factor (``x**2``, not ``3*x**2``); the constant force is 1.
    """

    mass: float
    state: tuple[tuple[sp.Expr, float], ...]
    forcing: tuple[tuple[sp.Expr, float], ...]

    @property
    def structure(self) -> tuple[tuple[sp.Expr, ...], tuple[sp.Expr, ...]]:
        """The features alone: what GP decides when coefficients come from least squares."""
        return tuple(f for f, _ in self.state), tuple(f for f, _ in self.forcing)

    def equation(self, symbols: Symbols) -> sp.Eq:
        lhs = sp.Float(self.mass) * symbols.x_ddot + sum(
            (sp.Float(c) * f for f, c in self.state), sp.Integer(0))
        rhs = sum((sp.Float(g) * f for f, g in self.forcing), sp.Integer(0))
        return sp.Eq(lhs, rhs)


@dataclasses.dataclass(frozen=True)
class StructureCheck:
    """Outcome of :func:`check_structure`: ``valid``, a ``reason`` when not, the form when so."""

    valid: bool
    reason: str = ""
    canonical: CanonicalForm | None = None

    def __bool__(self) -> bool:
        return self.valid


def tree_to_sympy(tree: Tree, symbols: Symbols, constants: dict[str, float]) -> sp.Expr:
    """The expression a tree denotes; named constants take their numeric values."""
    head = tree[0]
    if is_function(tree):
        a = tree_to_sympy(tree[1], symbols, constants)
        b = tree_to_sympy(tree[2], symbols, constants)
        if head == "add":
            return a + b
        if head == "sub":
            return a - b
        if head == "mul":
            return a * b
        return sp.Integer(1) if sp.expand(b) == 0 else a / b  # protected division
    if head == "x":
        return symbols.x
    if head == "x_dot":
        return symbols.x_dot
    if head == "x_ddot":
        return symbols.x_ddot
    if head == "t":
        return symbols.t
    if head == "u":
        return symbols.u[tree[1]]
    if head == "c":
        return sp.Float(constants[tree[1]])
    if head == "k":
        return sp.Float(tree[2])
    return sp.Integer(tree[1]) if isinstance(tree[1], int) else sp.Float(tree[1])


def _degree(feature: sp.Expr, symbol: sp.Symbol) -> int:
    if feature.is_polynomial(symbol):
        return int(sp.degree(feature, symbol))
    return 0


def check_structure(expression: sp.Expr | sp.Eq, symbols: Symbols, *,
                    max_degree: int | None = None) -> StructureCheck:
    """Decide the §3 structure rules for ``expression`` (read as ``expression = 0``).

    Args:
        expression: a sympy expression or ``Eq(lhs, rhs)`` in the symbols of ``symbols``.
        symbols: the names of response, time and inputs.
        max_degree: if given, a power of x or x' above it also makes the candidate invalid.

    Returns:
        A :class:`StructureCheck`: ``valid`` and, if valid, the normalised canonical form,
        otherwise the ``reason`` (which rule the expression breaks, and which term).
    """
    if isinstance(expression, sp.Equality):
        expression = expression.lhs - expression.rhs
    if not isinstance(expression, sp.Expr):
        raise TypeError(f"expected a sympy expression or Eq, got {type(expression).__name__}")
    return _check(expression, symbols, max_degree)


@lru_cache(maxsize=200_000)
def _check(expression: sp.Expr, symbols: Symbols, max_degree: int | None) -> StructureCheck:
    x, v, a, t, u = symbols.x, symbols.x_dot, symbols.x_ddot, symbols.t, symbols.u
    known = {x, v, a, t, *u}
    unknown = expression.free_symbols - known
    if unknown:
        return StructureCheck(False, f"unknown symbol {sorted(map(str, unknown))[0]}")
    expanded = sp.expand(expression)
    if not expanded.is_finite and expanded.has(sp.zoo, sp.oo, -sp.oo, sp.nan):
        return StructureCheck(False, "the expression is not finite")
    mass = 0.0
    state: dict[sp.Expr, float] = {}
    forcing: dict[sp.Expr, float] = {}
    exogenous = {t, *u}
    for term in sp.Add.make_args(expanded):
        coefficient, feature = term.as_coeff_Mul()
        if not feature.free_symbols:
            coefficient, feature = term, sp.Integer(1)
        symbols_in = feature.free_symbols
        if a in symbols_in:
            if feature != a:
                return StructureCheck(False, f"{a} appears other than as a constant times {a}: "
                                             f"term {term} (eq. 3: constant inertia)")
            mass += float(coefficient)
            continue
        if x in symbols_in and v in symbols_in:
            return StructureCheck(False, f"cross term {term}: a term may depend on {x} or on {v}, "
                                         "not both (eqs. 5–6)")
        if symbols_in & {x, v}:
            if symbols_in & exogenous:
                return StructureCheck(False, f"cross term {term}: the response and time/inputs "
                                             "mixed in one term (eq. 3)")
            if max_degree is not None:
                degree = _degree(feature, x if x in symbols_in else v)
                if degree > max_degree:
                    return StructureCheck(False, f"term {term} has degree {degree} > max_degree "
                                                 f"{max_degree}")
            state[feature] = state.get(feature, 0.0) + float(coefficient)
        else:
            forcing[feature] = forcing.get(feature, 0.0) - float(coefficient)
    scale = max([abs(mass), *map(abs, state.values()), *map(abs, forcing.values())], default=0.0)
    if scale == 0.0 or abs(mass) <= ZERO_TOLERANCE * scale:
        return StructureCheck(False, f"no {a} term: eq. 3 needs an acceleration (inertia) term")
    state = {f: c for f, c in state.items() if abs(c) > ZERO_TOLERANCE * scale}
    forcing = {f: g for f, g in forcing.items() if abs(g) > ZERO_TOLERANCE * scale}
    norm = forcing.get(u[0], 0.0) if u else 0.0
    norm = norm if norm != 0.0 else mass
    form = CanonicalForm(
        mass=mass / norm,
        state=tuple(sorted(((f, c / norm) for f, c in state.items()), key=lambda p: str(p[0]))),
        forcing=tuple(sorted(((f, g / norm) for f, g in forcing.items()), key=lambda p: str(p[0]))))
    return StructureCheck(True, "", form)
