"""The grammar of a system's equations: every equation's terminals, how a tree reads as
its terms, and the structure rules (:mod:`gpjax._system_search`'s module docstring).

Tree i's terminals are its own coordinate x_i, x_i', x_i'', the relative coordinates
d_ij = x_i − x_j and d_ij' (j ≠ i; with the third law of j > i only), the inputs, t and
random constants; its functions add, sub, mul and those of the system bank
(:mod:`gpjax._system_bank`). A term is valid as (non-zero constant)·x_i'', a power of one
state variable up to ``max_degree``, a bank term of one, or a function of time and inputs
(an input itself or a constant unless ``GPConfig.input_forcing`` is ``"any"``).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import sympy as sp

from ._data import Measurement
from ._operators import Grammar
from ._system_bank import (MAKERS, SYSTEM_FUNCTIONS, bank_feature, kinds_for, match_bank,
                           system_variables)


class Equations:
    """Terminals, tree reading and structure rules of every equation of one measurement;
    ``functions`` beyond add, sub, mul make the bank's kinds (:mod:`gpjax._system_bank`),
    the smoothed sign of variable z at θ = ``scales``' entry of z."""

    def __init__(self, measurement: Measurement, max_degree: int, third_law: bool = False,
                 functions=("add", "sub", "mul"), scales=None, input_forcing: str = "linear"):
        names = measurement.response_names
        self.names, self.max_degree, self.third_law = names, max_degree, third_law
        self.input_forcing = input_forcing
        self.functions = ("add", "sub", "mul") + tuple(
            f for f in functions if f in SYSTEM_FUNCTIONS and f not in ("add", "sub", "mul"))
        self.kinds = kinds_for(self.functions)
        self.inputs = tuple(sp.Symbol(u) for u in measurement.input_names)
        self.t = sp.Symbol(measurement.time_name)
        self.tables, self.meaning = [], []
        for i, name in enumerate(names):
            x, v, a = sp.symbols(f"{name} {name}_dot {name}_ddot")
            table = {f"{name}": x, f"{name}_dot": v, f"{name}_ddot": a}
            meaning = {x: x, v: v}
            for j, other in enumerate(names):  # third law: a coupling lives in equation min(i, j)
                if j > i or (j < i and not third_law):
                    d, dv = sp.symbols(f"d_{name}_{other} d_{name}_{other}_dot")
                    table[str(d)], table[str(dv)] = d, dv
                    meaning[d] = x - sp.Symbol(other)
                    meaning[dv] = v - sp.Symbol(f"{other}_dot")
            self.tables.append(table)
            self.meaning.append(meaning)
        variables = system_variables(names)
        scales = np.ones(2 * len(names) ** 2) if scales is None else scales
        #: Per equation, the sign's θ of each of its variables.
        self.scale_of = [{z: float(scales[i * len(zs) + p]) for p, z in enumerate(zs)}
                         for i, zs in enumerate(variables)]
        self.variables = variables

    def grammar(self, i: int, config) -> Grammar:
        variables = tuple(("s", name) for name in self.tables[i]) + tuple(
            ("u", k) for k in range(len(self.inputs)))
        return Grammar(functions=self.functions, variables=variables,
                       named_constants=(), interval_constants={},
                       real_interval=config.real_interval, int_interval=config.int_interval,
                       max_depth=config.max_depth, max_size=config.max_size)

    def structure(self, i: int, tree) -> tuple | None:
        """(state features, forcing features) of equation ``i``, or ``None`` if invalid."""
        return _structure(self, i, tree)

    def feature(self, i: int, kind: str, z: sp.Expr) -> sp.Expr:
        """Equation ``i``'s bank feature of ``kind`` of its variable ``z``."""
        return bank_feature(kind, z, self.scale_of[i][z])

    def tree(self, i: int, state, forcing):
        """A tree whose structure is (``state``, ``forcing``) (for local search)."""
        inverse = {m: s for s, m in self.meaning[i].items()}
        name = self.names[i]
        terms = [("s", f"{name}_ddot")]
        for feature in state:
            base, power = feature.as_base_exp()
            if base in inverse:
                leaf = ("s", str(inverse[base]))
                term = leaf
                for _ in range(int(power) - 1):
                    term = ("mul", term, leaf)
            else:
                kind, position, _ = match_bank(feature, self.variables[i])
                leaf = ("s", str(inverse[self.variables[i][position]]))
                maker = next(f for f in MAKERS[kind] if f in self.functions)
                term = ("mul", leaf, (maker, leaf)) if kind == "abs" else (maker, leaf)
            terms.append(term)
        for feature in forcing:  # a product of inputs, or 1
            leaves = [("u", self.inputs.index(u)) for u, power in feature.as_powers_dict().items()
                      if u in self.inputs for _ in range(int(power))] or [("n", 1.0)]
            term = leaves[0]
            for leaf in leaves[1:]:
                term = ("mul", term, leaf)
            terms.append(term)
        tree = terms[0]
        for term in terms[1:]:
            tree = ("add", tree, term)
        return tree

    def basis(self, i: int) -> tuple[list[sp.Expr], list[sp.Expr]]:
        """Equation ``i``'s possible state and forcing features (local search)."""
        state = [m ** k for m in self.meaning[i].values()
                 for k in range(1, self.max_degree + 1)]
        state += [self.feature(i, kind, m) for kind in self.kinds
                  for m in self.meaning[i].values()]
        return state, list(self.inputs) + [sp.Integer(1)]


#: A tree's unary functions as sympy functions.
_UNARY = {"sign": sp.sign, "tanh": sp.tanh, "abs": sp.Abs, "sin": sp.sin, "cos": sp.cos}


def _bank_placeholders(expression: sp.Expr, states) -> tuple | None:
    """``expression`` with every function of one state variable s (sign(c·s),
    tanh(c·s): the smoothed sign of s times sign(c); |c·s|; sin(±s), cos(±s)) replaced by
    a placeholder symbol, and {placeholder: (kind, s)}; ``None`` where a function has
    another argument."""
    replacements, table = {}, {}
    for atom in expression.atoms(*_UNARY.values()):
        argument = atom.args[0]
        if len(argument.free_symbols) != 1 or not argument.free_symbols <= states:
            return None
        (s,) = argument.free_symbols
        factor = sp.expand(argument / s)
        if not factor.is_number or factor == 0:
            return None
        if isinstance(atom, (sp.sign, sp.tanh)):
            kind, value = "sign", sp.sign(factor)
        elif isinstance(atom, sp.Abs):
            kind, value = "abs", abs(factor)
        elif factor in (1, -1):
            kind = "sin" if isinstance(atom, sp.sin) else "cos"
            value = factor if kind == "sin" else 1
        else:
            return None
        placeholder = sp.Symbol(f"_{kind}_{s}")
        replacements[atom] = value * placeholder
        table[placeholder] = (kind, s)
    return expression.xreplace(replacements), table


@lru_cache(maxsize=200_000)
def _structure(equations: Equations, i: int, tree) -> tuple | None:
    table, meaning = equations.tables[i], equations.meaning[i]
    expression = sp.expand(_expression(tree, table, equations.inputs, equations.t))
    ddot = table[f"{equations.names[i]}_ddot"]
    states = list(meaning)
    replaced = _bank_placeholders(expression, set(states))
    if replaced is None:
        return None
    expression, bank = sp.expand(replaced[0]), replaced[1]
    generators = [ddot, *states, *bank, equations.t, *equations.inputs]
    try:
        terms = sp.Poly(expression, *generators).terms()
    except sp.PolynomialError:
        return None
    mass, state, forcing = 0.0, [], []
    for exponents, coefficient in terms:
        used = [g for g, e in zip(generators, exponents) if e]
        if abs(float(coefficient)) < 1e-12:
            continue
        powers = dict(zip(generators, exponents))
        placeholders = [g for g in used if g in bank]
        if ddot in used:
            if used != [ddot] or exponents[0] != 1:
                return None
            mass += float(coefficient)
        elif placeholders:
            kind, s = bank[placeholders[0]]
            alone = used == placeholders and kind != "abs"
            drag = kind == "abs" and sorted(used, key=str) == sorted([placeholders[0], s], key=str)
            if len(placeholders) > 1 or any(powers[g] != 1 for g in used) or not (alone or drag):
                return None
            state.append(equations.feature(i, kind, meaning[s]))
        elif set(used) & set(states):
            power = sum(exponents)
            if len(used) > 1 or power > equations.max_degree:
                return None
            state.append(meaning[used[0]] ** power)
        else:
            if equations.input_forcing == "linear" and used and sum(exponents) > 1:
                return None  # a power or product of inputs (GPConfig.input_forcing)
            forcing.append(sp.Mul(*(g ** e for g, e in zip(generators, exponents) if e)))
    if mass == 0.0 or len(set(state)) < len(state):
        return None
    return tuple(sorted(state, key=str)), tuple(sorted(forcing, key=str))


def _expression(tree, table, inputs, t):
    head = tree[0]
    if head in ("add", "sub", "mul"):
        a, b = (_expression(c, table, inputs, t) for c in tree[1:])
        return a + b if head == "add" else a - b if head == "sub" else a * b
    if head in _UNARY:
        return _UNARY[head](_expression(tree[1], table, inputs, t))
    if head == "s":
        return table[tree[1]]
    if head == "u":
        return inputs[tree[1]]
    if head == "t":
        return t
    return sp.Float(tree[-1])
