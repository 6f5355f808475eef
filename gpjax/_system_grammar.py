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

import dataclasses
from functools import lru_cache

import numpy as np
import sympy as sp

from ._canonical import FLOAT64_FUNCTIONS, expanded_tree
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
        #: Per equation, its terminals as polynomial generators (:func:`expanded_tree`).
        self.terminals = [_Terminals.of(table, meaning, self.kinds, self.t, self.inputs, name)
                          for table, meaning, name in zip(self.tables, self.meaning, names)]
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


#: Per unary node, the bank kind it makes (:data:`MAKERS` read the other way).
_KIND_OF = {function: kind for kind, makers in MAKERS.items() for function in makers}
#: Per unary node, its float64 value at a constant.
_FLOAT64 = FLOAT64_FUNCTIONS | {"sign": np.sign, "abs": np.abs}


@dataclasses.dataclass(frozen=True, eq=False)  # hashed by identity: a cache key per call
class _Terminals:
    """One equation's reading of a tree as a polynomial (:func:`gpjax._canonical.expanded_tree`)
    in x_i'', the state variables s (x_i, d_ij, x_i', d_ij'), one placeholder per bank kind
    and s, t and the inputs; ``leaves``: each terminal node's generator; ``bank``: per
    placeholder (its generator, kind, its variable's generator)."""

    generators: tuple[sp.Symbol, ...]
    leaves: tuple[tuple[tuple, int], ...]
    bank: tuple[tuple[int, str, int], ...]

    @classmethod
    def of(cls, table: dict, meaning: dict, kinds, t: sp.Symbol, inputs: tuple, name: str):
        states = list(meaning)
        placeholders = [(sp.Symbol(f"_{kind}_{s}"), kind, s) for kind in kinds for s in states]
        generators = (table[f"{name}_ddot"], *states, *(p for p, _, _ in placeholders), t,
                      *inputs)
        index = {g: k for k, g in enumerate(generators)}
        leaves = (*((("s", n), index[g]) for n, g in table.items()), (("t",), index[t]),
                  *((("u", k), index[u]) for k, u in enumerate(inputs)))
        return cls(generators, leaves,
                   tuple((index[p], kind, index[s]) for p, kind, s in placeholders))

    def read_unary(self, head: str, argument, ring):
        """A unary node of the polynomial ``argument``: of a constant, its value; of c·s (s
        a state variable), the bank's term — sign(c)·sign s for sign and tanh (the smoothed
        sign), |c|·|s| for abs, ±sin s, cos s for c = ±1 — and sign(c·sign s) = sign(c)·sign s;
        otherwise ``None`` (invalid)."""
        kind, function = _KIND_OF[head], _FLOAT64[head]
        if argument.is_ground:
            with np.errstate(all="ignore"):
                value = float(function(float(argument.LC)))
            return ring.ground_new(sp.RR(value)) if np.isfinite(value) else None
        if len(argument) != 1:
            return None
        ((exponents, c),) = argument.terms()
        c = float(c)
        if sum(exponents) != 1 or (kind in ("sin", "cos") and abs(c) != 1):
            return None
        position = exponents.index(1)
        if head == "sign" and any(p == position and k == "sign" for p, k, _ in self.bank):
            position = next(s for p, _, s in self.bank if p == position)  # sign(c·sign s)
        placeholder = next((p for p, k, s in self.bank if k == kind and s == position), None)
        if placeholder is None:
            return None
        factor = {"sign": np.sign(c), "abs": abs(c), "sin": c, "cos": 1.0}[kind]
        return ring.gens[placeholder] * ring.ground_new(sp.RR(float(factor)))


@lru_cache(maxsize=200_000)
def _structure(equations: Equations, i: int, tree) -> tuple | None:
    terminals, meaning = equations.terminals[i], equations.meaning[i]
    value = expanded_tree(tree, terminals)
    if value is None:
        return None
    generators, states = terminals.generators, set(meaning)
    ddot = generators[0]
    bank = {generators[p]: (kind, generators[s]) for p, kind, s in terminals.bank}
    terms = value.terms()
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
