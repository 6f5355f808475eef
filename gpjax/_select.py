"""Choosing the reported model: the best structure, simplified, and the Pareto table.

Least-squares coefficients make every additive term free to help a little, so the best
structure GP finds often carries terms that buy almost nothing (a constant force of 1e-3,
a t·T term), and on short records several structures fit to the noise floor (x + x⁴ + c
mimics x + x² about an operating point). After the run a local search starts from the
best structure and moves, by one-term removals and swaps, to the simplest structure whose
objective stays within ``selection_tolerance`` of the best seen. This is a difference from
the paper, which reports the best tree as found.
"""

from __future__ import annotations

import math

import sympy as sp

from ._canonical import CanonicalForm
from ._evaluator import OK
from ._fitness import Fitness, Record, structure_key


def _records_for(fitness: Fitness, mass: float,
                 options: list[tuple[dict[sp.Expr, float], dict[sp.Expr, float]]], *,
                 refine_below: float) -> list[Record]:
    """Score several structures together; refine those scoring below ``refine_below``.

    The values are the start coefficients tree mode uses (least squares ignores them).
    """
    keys, new = [], {}
    for state, forcing in options:
        form = CanonicalForm(mass=mass, state=tuple(state.items()),
                             forcing=tuple(forcing.items()))
        key = structure_key(form, with_coefficients=False)
        if fitness.config.coefficients == "tree":
            key = "pruned " + key
        keys.append(key)
        if key not in fitness.records:
            new[key] = form
    if new:
        fitness.score_forms(new)
    records = [fitness.records[k] for k in keys]
    fitness.refine([r for r in records if r.objective <= refine_below])
    return records


def simplify(fitness: Fitness, best: Record, tolerance: float) -> tuple[Record, list[Record]]:
    """Local search from ``best`` for the simplest model within ``tolerance`` of the best.

    Neighbours of a structure: every one-term removal and every one-term swap (a state
    term replaced by another basis feature, a forcing term by another forcing feature;
    see :meth:`Fitness.basis_features`), each refitted (least squares, then refinement
    of those whose start is within 5x of the limit). In tree mode a neighbour starts from
    the current model's constants (a swapped-in term from the coefficient of the term it
    replaces) and is always refined: with no least-squares refit, a dropped term's share
    of the fit shifts the phase until Levenberg–Marquardt moves the other constants.
    A move is taken to the neighbour with the fewest terms whose objective is within the
    limit, or, at equal size, to a lower objective. The limit is (1 + tolerance) times the
    lowest objective seen. Returns the final record and the path taken.
    """
    normaliser = fitness.symbols.u[0] if fitness.symbols.u else None
    tree_mode = fitness.config.coefficients == "tree"
    basis = fitness.basis_features()
    lowest = best.objective
    current, path = best, [best]
    while True:
        options = []
        for part in ("state", "forcing"):
            terms = dict(getattr(current.coefficients, part))
            others = [t for t in basis[part] if t not in terms]
            for name, value in terms.items():
                if part == "forcing" and name == normaliser:
                    continue
                rest = {t: v for t, v in terms.items() if t != name}
                options.append((part, rest))
                options += [(part, {**rest, other: value}) for other in others]
        now = current.coefficients
        structures = [(terms, dict(now.forcing)) if part == "state"
                      else (dict(now.state), terms) for part, terms in options]
        records = _records_for(fitness, now.mass, structures, refine_below=(
            math.inf if tree_mode else 5 * lowest * (1 + tolerance)))
        usable = [r for r in records if r.valid and r.status == OK]
        lowest = min([lowest, *(r.objective for r in usable)])
        limit = lowest * (1 + tolerance)
        moves = [r for r in usable if r.objective <= limit and (
            r.n_terms < current.n_terms
            or (r.n_terms == current.n_terms and r.objective < current.objective))]
        if current.objective > limit:  # a better model appeared: anything within reach
            moves = [r for r in usable if r.objective <= limit]
        if not moves:
            return current, path
        current = min(moves, key=lambda r: (r.n_terms, r.objective))
        path.append(current)


def pareto_front(records: list[Record]) -> list[Record]:
    """For each complexity (number of terms), the best record if it beats every simpler one."""
    front: list[Record] = []
    for record in sorted((r for r in records if r.valid and r.status == OK),
                         key=lambda r: (r.n_terms, r.objective)):
        if not front or (record.n_terms > front[-1].n_terms
                         and record.objective < front[-1].objective):
            front.append(record)
        elif record.n_terms == front[-1].n_terms and record.objective < front[-1].objective:
            front[-1] = record
    return front
