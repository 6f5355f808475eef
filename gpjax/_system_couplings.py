"""Newton's third law between the coordinates of a system: one coupling force, two equations.

With the option on, every power of a relative coordinate in equation i — (x_i − x_j)^k or
(x_i' − x_j')^k, a force of the coupling between coordinates i and j — also acts on
coordinate j with the opposite sign: −c·(x_i − x_j)^k = (−1)^(k+1)·c·(x_j − x_i)^k, so
equation j carries the *mirror* feature (x_j − x_i)^k with its coefficient tied to c
(a :class:`Tie`). The force is searched once (in the lower-numbered equation) and its
constants — mesh stiffness and damping of eqs. 21–22 — are fitted once.

The equations then share units: equations joined by couplings (a *component*) can only be
scaled together, so each component has one normalisation — the forcing coefficients the
structure fixes (the search fixes the first input of the component's first equation that
has one), or, where none is fixed, the mass of its first equation. The other masses and
input coefficients are free: an equation without an input is no longer identified up to
a factor only.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import sympy as sp

from ._weak_form import scaled_lstsq

#: A fixed-forcing entry of :meth:`gpjax._refine.Refiner.refine`: neither the mass nor a
#: forcing coefficient of this equation is held (its component is normalised elsewhere).
NOTHING_FIXED = -2


@dataclasses.dataclass(frozen=True)
class Tie:
    """The coefficient of ``mirror`` (equation, feature) is ``sign`` × that of ``source``."""

    source: tuple[int, sp.Expr]
    mirror: tuple[int, sp.Expr]
    sign: float


def _relative(names: tuple[str, ...]) -> dict[sp.Expr, tuple[int, int, int]]:
    """x_i − x_j and x_i' − x_j' (i ≠ j) -> (i, j, 0 for positions / 1 for velocities)."""
    out = {}
    for which, suffix in enumerate(("", "_dot")):
        z = [sp.Symbol(f"{n}{suffix}") for n in names]
        out |= {z[i] - z[j]: (i, j, which) for i in range(len(z)) for j in range(len(z))
                if i != j}
    return out


def couple(structure, names: tuple[str, ...]):
    """``structure`` (per equation: state features, forcing) with the mirror of every
    coupling feature added to the other equation, and the ties, one per coupling term
    (a feature already present on both sides is one term)."""
    relative = _relative(tuple(names))
    states = [list(state) for state, _ in structure]
    ties, seen = [], set()
    for i in range(len(structure)):
        for feature in list(states[i]):
            base, power = feature.as_base_exp()
            if base not in relative or not (power.is_Integer and power > 0):
                continue
            _, j, which = relative[base]
            pair = (min(i, j), max(i, j), which, int(power))
            if pair in seen:
                continue
            seen.add(pair)
            mirror = (-base) ** power
            if mirror not in states[j]:
                states[j].append(mirror)
            ties.append(Tie((i, feature), (j, mirror), float((-1) ** (int(power) + 1))))
    full = tuple((tuple(state), forcing) for state, (_, forcing) in zip(states, structure))
    return full, tuple(ties)


def components(count: int, ties) -> list[list[int]]:
    """The equations joined by ties, each group in increasing order."""
    group = list(range(count))

    def root(e):
        while group[e] != e:
            e = group[e]
        return e

    for tie in ties:
        a, b = root(tie.source[0]), root(tie.mirror[0])
        group[max(a, b)] = min(a, b)
    out: dict[int, list[int]] = {}
    for e in range(count):
        out.setdefault(root(e), []).append(e)
    return list(out.values())


def normalisation(structure, ties, inputs) -> list:
    """Per equation, the forcing feature held at 1 for the GP's structures: with ties,
    the first of ``inputs`` in the first equation of each component that has one;
    without, every equation's first input. ``None``: none held."""
    first = [next((u for u in inputs if u in forcing), None) for _, forcing in structure]
    if not ties:
        return first
    out = [None] * len(structure)
    for group in components(len(structure), ties):
        e = next((e for e in group if first[e] is not None), None)
        if e is not None:
            out[e] = first[e]
    return out


def held_structure(key, names: tuple[str, ...], inputs, third_law: bool):
    """``key`` (per equation: state features, forcing features) as a
    :data:`gpjax._system_fit.Structure`: the forcing feature :func:`normalisation` holds at
    1 marked, the others free (``None``); ``third_law``: components joined by couplings."""
    ties = couple(key, names)[1] if third_law else ()
    held = normalisation(key, ties, inputs)
    return tuple((tuple(state), {f: 1.0 if f == h else None for f in forcing})
                 for (state, forcing), h in zip(key, held))


def fixed_columns(structure, ties, forcing_index) -> list[int]:
    """Per equation, :meth:`gpjax._refine.Refiner.refine`'s entry: the column of its held
    forcing coefficient (a value given in ``structure``), −1 where its mass is held (no
    tie: every such equation; with ties: the first of a component that holds nothing),
    else :data:`NOTHING_FIXED`."""
    out = [next((forcing_index(f) for f, v in forcing.items() if v is not None), -1)
           for _, forcing in structure]
    if ties:
        for group in components(len(structure), ties):
            if any(out[e] >= 0 for e in group):
                out = [NOTHING_FIXED if e in group and c < 0 else c for e, c in enumerate(out)]
            else:
                out = [NOTHING_FIXED if e in group[1:] else c for e, c in enumerate(out)]
    return out


def tie_columns(ties, evaluator) -> list[tuple[int, int, int, int, float]]:
    """The ties as (equation, column, equation, column, sign) in ``evaluator``'s columns
    (:meth:`gpjax._evaluator.PopulationEvaluator.equation_index`)."""
    return [(tie.source[0], evaluator.equation_index(tie.source[1], tie.source[0]),
             tie.mirror[0], evaluator.equation_index(tie.mirror[1], tie.mirror[0]), tie.sign)
            for tie in ties]


def coupled_least_squares(weak, structure, ties) -> list:
    """Weak-form equation-error least squares of all equations at once with every tie
    imposed (:class:`gpjax._weak_form.WeakForm`'s columns, one block of rows per
    equation); normalised as :func:`fixed_columns` says; a component whose normalising
    equation comes out with a negative mass has all its signs flipped. Returns one
    :class:`gpjax._coefficients.Coefficients` per equation."""
    from ._coefficients import Coefficients

    count = len(structure)
    mirrors = {t.mirror: (t.source, t.sign) for t in ties}
    held = fixed_columns(structure, ties, lambda f: 0)
    value, _ = _solve(weak, structure, mirrors, held)
    signs = np.ones(count)
    for group in components(count, ties):
        e = next((e for e in group if held[e] >= 0), None)
        if e is not None and value.get(("mass", e), 1.0) < 0:
            signs[group] = -1.0
    out = []
    for e, (state, forcing) in enumerate(structure):
        s = signs[e]
        coefficient = {f: s * sign * value[("state",) + source] for f in state
                       for source, sign in [mirrors.get((e, f), ((e, f), 1.0))]}
        out.append(Coefficients(
            mass=s * value.get(("mass", e), 1.0), state=coefficient,
            forcing={f: s * (v if v is not None else value[("forcing", e, f)])
                     for f, v in forcing.items()},
            y0=weak.initial_state(e)))
    return out


def coupled_residual(weak, key, names) -> float:
    """Relative weak-form equation error of the GP structure ``key`` (per equation: state
    features, forcing features) with the third law (mirrors added, constants tied, every
    forcing coefficient free, each component's first mass 1): the local search's measure
    of a change to one equation, which moves the others' fit through the shared terms."""
    structure, ties = couple(tuple((s, {f: None for f in g}) for s, g in key), names)
    held = fixed_columns(structure, ties, lambda f: 0)
    return _solve(weak, structure, {t.mirror: (t.source, t.sign) for t in ties}, held)[1]


def _solve(weak, structure, mirrors, held):
    """(parameter -> value, relative residual) of the stacked weak-form equations."""
    parameters: dict[tuple, int] = {}
    blocks, targets = [], []
    for e, (state, forcing) in enumerate(structure):
        rows = weak.rows
        entries: list[tuple[tuple, float, np.ndarray]] = []
        acceleration = weak.acceleration(e)
        target = np.zeros(rows)
        if held[e] == -1:
            target = -acceleration
        else:
            entries.append((("mass", e), 1.0, acceleration))
        for feature in state:
            source, sign = mirrors.get((e, feature), ((e, feature), 1.0))
            entries.append((("state",) + source, sign, weak.column(feature)))
        for feature, value in forcing.items():
            if value is None:
                entries.append((("forcing", e, feature), -1.0, weak.column(feature)))
            else:
                target = target + value * weak.column(feature)
        for key, _, _ in entries:
            parameters.setdefault(key, len(parameters))
        blocks.append(entries)
        targets.append(target)
    matrix = np.zeros((sum(t.size for t in targets), len(parameters)))
    start = 0
    for entries, target in zip(blocks, targets):
        for key, sign, column in entries:
            matrix[start:start + target.size, parameters[key]] += sign * column
        start += target.size
    target = np.concatenate(targets)
    if not parameters:
        return {}, 1.0
    solution = scaled_lstsq(matrix, target)
    residual = np.linalg.norm(target - matrix @ solution) / max(np.linalg.norm(target), 1e-300)
    return {key: float(solution[k]) for key, k in parameters.items()}, float(residual)
