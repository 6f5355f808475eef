"""Canonical Newton–Euler form and the structure rules of §3 (eqs. 3–6), decided with sympy.

A candidate expression E (read as E = 0) is expanded and each additive term classified:

* a term holding x'' must be (non-zero constant)·x'' — constant inertia (eq. 3);
* every other term depends on x only, on x' only (eqs. 5–6), or on time/inputs only;
* anything else (x''·x, x·x', x·u, …) is a cross term and makes the candidate invalid;
* with ``linear_inputs`` (the GP's check under ``input_forcing = "linear"``) a term that
  holds an input is that input alone (g·u).

Beyond the paper's polynomial function set, a state term may be any function of x alone or
x' alone (sin x, x'·|x'|, sign x', …); with ``bank=True`` (the GP's check) such a term must
also be a member of the feature bank the evaluator compiles (:mod:`gpjax._features`) or
sign(x) / sign(x'), and a sign with ``bank`` is smoothed later, where the data are known.

Valid candidates become ``m·x'' + Σ c_i·φ_i(x or x') = Σ g_j·ψ_j(t, inputs)``, normalised
so the first input's linear forcing coefficient is 1 (mass 1 when no such term exists).
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from functools import lru_cache

import numpy as np
import sympy as sp

from ._trees import UNARY_NODES, Tree, is_function

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

    #: No reading of unary nodes in the ring (:func:`expanded_tree`): sympy's functions.
    read_unary = None

    @property
    def generators(self) -> tuple[sp.Symbol, ...]:
        """The polynomial generators of a tree's expansion (:func:`expanded_tree`)."""
        return (self.x, self.x_dot, self.x_ddot, self.t, *self.u)

    @property
    def leaves(self) -> tuple[tuple[tuple, int], ...]:
        """(terminal node, index into :attr:`generators`) of every variable terminal."""
        return ((("x",), 0), (("x_dot",), 1), (("x_ddot",), 2), (("t",), 3),
                *((("u", k), 4 + k) for k in range(len(self.inputs))))


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
    """The expression a tree denotes, expanded; named constants take their numeric values."""
    return _as_expr(expanded_tree(tree, symbols, tuple(sorted(constants.items()))))


def check_tree(tree: Tree, symbols: Symbols, constants: dict[str, float], *,
               max_degree: int | None = None, bank: bool = False,
               linear_inputs: bool = False) -> StructureCheck:
    """:func:`check_structure` of the expression a tree denotes (read as ``tree = 0``).

    Subtrees without division are multiplied out as sparse polynomials over the reals
    (sympy's ``ring``) and checked term by term without building the whole expression —
    far cheaper than expanding expressions; a division falls back to ``sympy.expand``.
    Every subtree's result is cached (crossover and mutation reuse most of their parents'
    subtrees), so a new tree costs the work along its changed path.
    """
    value = expanded_tree(tree, symbols, tuple(sorted(constants.items())))
    if isinstance(value, sp.Expr):  # already expanded: not expanded again (idempotent)
        return _check_expanded(value, symbols, max_degree, bank, linear_inputs)
    terms = tuple((float(c), _monomial(symbols, exponents)) for exponents, c in value.terms())
    return _check_terms(terms, symbols, max_degree, bank, linear_inputs)


@lru_cache(maxsize=64)
def _ring(symbols):
    """(ring, {terminal node: its generator}) of ``symbols`` (:func:`expanded_tree`)."""
    ring, *generators = sp.ring(symbols.generators, sp.RR)
    return ring, {node: generators[index] for node, index in symbols.leaves}


@lru_cache(maxsize=100_000)
def _monomial(symbols: Symbols, exponents: tuple[int, ...]) -> sp.Expr:
    return sp.Mul(*(g ** e for g, e in zip(symbols.generators, exponents) if e))


@lru_cache(maxsize=500_000)
def expanded_tree(tree: Tree, symbols, constants: tuple = ()):
    """A tree (or subtree) multiplied out: a polynomial of sympy's ``ring`` over the reals in
    ``symbols.generators`` where no unary function or division lies below it, else an
    expanded expression. ``symbols``: hashable, with ``generators`` (sympy symbols) and
    ``leaves`` ((terminal node, generator index) pairs: :class:`Symbols`, or a system
    equation's terminals) and ``read_unary``: ``None`` (sympy's functions) or
    ``read_unary(head, argument, ring)``, a unary node of a polynomial argument as a
    polynomial, or ``None`` where the tree has no valid reading (then so has the whole
    tree); ``constants``: (name, value) pairs of named constants."""
    ring, leaves = _ring(symbols)
    head = tree[0]
    if head in UNARY_NODES:
        argument = expanded_tree(tree[1], symbols, constants)
        if symbols.read_unary is not None:
            return None if argument is None else symbols.read_unary(head, argument, ring)
        return _unary(head, _as_expr(argument))
    if is_function(tree):
        a = expanded_tree(tree[1], symbols, constants)
        b = expanded_tree(tree[2], symbols, constants)
        if a is None or b is None:
            return None
        if head == "div":  # protected division
            if b == 0:
                return ring.one
            return sp.expand(_as_expr(a) / _as_expr(b))
        if isinstance(a, sp.Expr) or isinstance(b, sp.Expr):
            a, b = _as_expr(a), _as_expr(b)
            if head == "mul":
                return sp.expand(a * b)
        return a + b if head == "add" else a - b if head == "sub" else a * b
    if tree in leaves:
        return leaves[tree]
    if head == "c":
        value = dict(constants)[tree[1]]
    elif head == "k":
        value = tree[2]
    else:
        value = tree[1]
    return ring.ground_new(sp.RR(value))  # ring(value) would build a new mpmath context


#: Unary nodes whose value of a constant is checked in float64 first (:func:`_unary`).
FLOAT64_FUNCTIONS = {"sin": np.sin, "cos": np.cos, "tanh": np.tanh, "exp": np.exp,
                     "sinh": np.sinh, "cosh": np.cosh}


def _unary(name: str, a: sp.Expr) -> sp.Expr:
    """A unary function node applied to an expanded argument, expanded (``exp(a + b)``
    becomes ``e^b·exp(a)``); sqrt and log act on |a| and log 0 is 0 (protected)."""
    if name == "log":
        return sp.Integer(0) if a == 0 else sp.expand(sp.log(sp.Abs(a)))
    function = {"sin": sp.sin, "cos": sp.cos, "tanh": sp.tanh, "exp": sp.exp, "sinh": sp.sinh,
                "cosh": sp.cosh, "abs": sp.Abs,
                "sign": sp.sign, "sqrt": lambda z: sp.sqrt(sp.Abs(z))}[name]
    if a.is_Number and name in FLOAT64_FUNCTIONS:
        # a constant whose argument or value is beyond float64 (sin(exp(exp(N1))),
        # exp(exp(N1)) from GP): sympy evaluates it to as many digits as its exponent has
        # (π or ln 2 to millions of digits: hours), and float64 has no such number anyway
        try:
            argument = float(a)
        except OverflowError:
            return sp.zoo
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            if not math.isfinite(FLOAT64_FUNCTIONS[name](np.float64(argument))):
                return sp.zoo
    try:
        out = sp.expand(function(a))
    except OverflowError:  # a constant beyond mpmath's range: exp(exp(exp(977))) from GP
        return sp.zoo
    # the variables are real signals: sympy's re(z), from |exp(z)| = exp(re z), is z
    return sp.expand(out.replace(sp.re, lambda z: z)) if out.has(sp.re) else out


def _as_expr(value) -> sp.Expr:
    return value if isinstance(value, sp.Expr) else value.as_expr()


@lru_cache(maxsize=100_000)
def _degree(feature: sp.Expr, symbol: sp.Symbol) -> int:
    if feature.is_polynomial(symbol):
        return int(sp.degree(feature, symbol))
    return 0


def check_structure(expression: sp.Expr | sp.Eq, symbols: Symbols, *,
                    max_degree: int | None = None, bank: bool = False,
                    linear_inputs: bool = False) -> StructureCheck:
    """Decide the §3 structure rules for ``expression`` (read as ``expression = 0``).

    Args:
        expression: a sympy expression or ``Eq(lhs, rhs)`` in the symbols of ``symbols``.
        symbols: the names of response, time and inputs.
        max_degree: if given, a power of x or x' above it also makes the candidate invalid.
        bank: a non-polynomial state term must be a feature-bank member or sign(x), sign(x')
            (see the module docstring).
        linear_inputs: a forcing term that holds an input must be the input itself, g·u
            (``GPConfig.input_forcing = "linear"``).

    Returns:
        A :class:`StructureCheck`: ``valid`` and, if valid, the normalised canonical form,
        otherwise the ``reason`` (which rule the expression breaks, and which term).
    """
    if isinstance(expression, sp.Equality):
        expression = expression.lhs - expression.rhs
    if not isinstance(expression, sp.Expr):
        raise TypeError(f"expected a sympy expression or Eq, got {type(expression).__name__}")
    return _check(expression, symbols, max_degree, bank, linear_inputs)


@lru_cache(maxsize=200_000)
def _check(expression: sp.Expr, symbols: Symbols, max_degree: int | None,
           bank: bool, linear_inputs: bool = False) -> StructureCheck:
    known = {symbols.x, symbols.x_dot, symbols.x_ddot, symbols.t, *symbols.u}
    unknown = expression.free_symbols - known
    if unknown:
        return StructureCheck(False, f"unknown symbol {sorted(map(str, unknown))[0]}")
    return _check_expanded(sp.expand(expression), symbols, max_degree, bank, linear_inputs)


@lru_cache(maxsize=200_000)
def _check_expanded(expanded: sp.Expr, symbols: Symbols, max_degree: int | None,
                    bank: bool, linear_inputs: bool = False) -> StructureCheck:
    """:func:`_check` of an expression that is already expanded, in known symbols."""
    if expanded.has(sp.zoo, sp.oo, -sp.oo, sp.nan):
        return StructureCheck(False, "the expression is not finite")
    terms = []
    for term in sp.Add.make_args(expanded):
        coefficient, feature = term.as_coeff_Mul()
        if not feature.free_symbols:
            coefficient, feature = term, sp.Integer(1)
        terms.append((float(coefficient), feature))
    return _check_terms(tuple(terms), symbols, max_degree, bank, linear_inputs)


@lru_cache(maxsize=200_000)
def _check_terms(terms: tuple[tuple[float, sp.Expr], ...], symbols: Symbols,
                 max_degree: int | None, bank: bool = False,
                 linear_inputs: bool = False) -> StructureCheck:
    """The §3 rules on an expanded expression given as (coefficient, feature) terms."""
    x, v, a, t, u = symbols.x, symbols.x_dot, symbols.x_ddot, symbols.t, symbols.u
    mass = 0.0
    state: dict[sp.Expr, float] = {}
    forcing: dict[sp.Expr, float] = {}
    exogenous = {t, *u}
    for coefficient, feature in terms:
        symbols_in = _free_symbols(feature)
        if a in symbols_in:
            if feature != a:
                return StructureCheck(False, f"{a} appears other than as a constant times {a}: "
                                             f"term {_term(coefficient, feature)} (eq. 3: "
                                             "constant inertia)")
            mass += coefficient
            continue
        if x in symbols_in and v in symbols_in:
            return StructureCheck(False, f"cross term {_term(coefficient, feature)}: a term may "
                                         f"depend on {x} or on {v}, not both (eqs. 5–6)")
        if symbols_in & {x, v}:
            if symbols_in & exogenous:
                return StructureCheck(False, f"cross term {_term(coefficient, feature)}: the "
                                             "response and time/inputs mixed in one term (eq. 3)")
            z = x if x in symbols_in else v
            if max_degree is not None:
                degree = _degree(feature, z)
                if degree > max_degree:
                    return StructureCheck(False, f"term {_term(coefficient, feature)} has degree "
                                                 f"{degree} > max_degree {max_degree}")
            if bank and not _in_bank(feature, z, symbols, max_degree):
                return StructureCheck(False, f"term {_term(coefficient, feature)} is no member "
                                             "of the feature bank (powers, z^k·|z|, tanh(a·z), "
                                             "sin/cos(a·z + b), exp(a·z), sign(z))")
            state[feature] = state.get(feature, 0.0) + coefficient
        else:
            if linear_inputs and symbols_in & set(u) and feature not in u:
                return StructureCheck(False, f"forcing term {feature} is a nonlinear function "
                                             "of an input; inputs enter as g·u "
                                             "(input_forcing=\"any\" allows it)")
            forcing[feature] = forcing.get(feature, 0.0) - coefficient
    scale = max([abs(mass), *map(abs, state.values()), *map(abs, forcing.values())], default=0.0)
    if scale == 0.0 or abs(mass) <= ZERO_TOLERANCE * scale:
        return StructureCheck(False, f"no {a} term: eq. 3 needs an acceleration (inertia) term")
    state = {f: c for f, c in state.items() if abs(c) > ZERO_TOLERANCE * scale}
    forcing = {f: g for f, g in forcing.items() if abs(g) > ZERO_TOLERANCE * scale}
    norm = forcing.get(u[0], 0.0) if u else 0.0
    norm = norm if norm != 0.0 else mass
    form = CanonicalForm(
        mass=mass / norm,
        state=tuple(sorted(((f, c / norm) for f, c in state.items()), key=lambda p: feature_name(p[0]))),
        forcing=tuple(sorted(((f, g / norm) for f, g in forcing.items()),
                             key=lambda p: feature_name(p[0]))))
    return StructureCheck(True, "", form)


def _in_bank(feature: sp.Expr, z: sp.Symbol, symbols: Symbols, max_degree: int | None) -> bool:
    """A power of z, sign(z), or a family member the evaluator compiles (an ``abs``
    family's z^k·|z| only up to k = max_degree − 1)."""
    from ._features import match

    if feature.is_polynomial(z) or feature == sp.sign(z):
        return True
    found = match(feature, symbols)
    return found is not None and (max_degree is None or found[0].power < max_degree)


# Features recur across thousands of candidates: their symbols, degrees and names are cached.
@lru_cache(maxsize=100_000)
def _free_symbols(feature: sp.Expr) -> frozenset:
    return frozenset(feature.free_symbols)


@lru_cache(maxsize=100_000)
def feature_name(feature: sp.Expr) -> str:
    """``str(feature)``, cached: keys, sort orders and checkpoints print every record's
    features, and sympy's printer is slow."""
    return str(feature)


def _term(coefficient: float, feature: sp.Expr) -> sp.Expr:
    """A term for a message: integral coefficients print as integers."""
    number = sp.Integer(int(coefficient)) if float(coefficient).is_integer() else sp.Float(
        coefficient)
    return number * feature


def numbers_lifted(expression: sp.Expr, constant) -> sp.Expr:
    """``expression`` with every number not in an exponent replaced by ``constant(value)``
    (a symbol the caller makes): the expression's shape, whose numbers a compiled program
    takes as data."""
    if expression.is_Number:
        return constant(float(expression))
    if isinstance(expression, sp.Pow):
        return sp.Pow(numbers_lifted(expression.base, constant), expression.exp, evaluate=False)
    if not expression.args:
        return expression
    return expression.func(*(numbers_lifted(a, constant) for a in expression.args),
                           evaluate=False)
