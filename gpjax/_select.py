"""Choosing the reported model: the best structure, pruned, and the Pareto table.

Least-squares coefficients make every additive term free to help a little, so the best
structure GP finds often carries terms that buy almost nothing (a constant force of 1e-3,
a t·T term). After the run the best structure is pruned by backward elimination: each
removable term is dropped in turn, the smaller structure is refitted (least squares, then
output-error refinement), and the removal that costs least is kept while the objective
stays within ``selection_tolerance`` of the unpruned best. This is a difference from the
paper, which reports the best tree as found.
"""

from __future__ import annotations

from ._canonical import CanonicalForm
from ._fitness import Fitness, Record, structure_key


def _form(fitness: Fitness, state: list[str], forcing: list[str]) -> CanonicalForm:
    feature = fitness._feature
    return CanonicalForm(mass=1.0, state=tuple((feature(f), 1.0) for f in state),
                         forcing=tuple((feature(f), 1.0) for f in forcing))


def _records_for(fitness: Fitness, options: list[tuple[list[str], list[str]]]) -> list[Record]:
    """Score and refine several structures together (one batch each)."""
    keys, new = [], {}
    for state, forcing in options:
        form = _form(fitness, state, forcing)
        key = structure_key(form, with_coefficients=False)
        if fitness.config.coefficients == "tree":
            key = "pruned " + key
        keys.append(key)
        if key not in fitness.records:
            new[key] = form
    if new:
        fitness.score_forms(new)
    records = [fitness.records[k] for k in keys]
    fitness.refine(records)
    return records


def prune(fitness: Fitness, best: Record, tolerance: float) -> tuple[Record, list[Record]]:
    """Backward elimination from ``best``; returns the pruned record and the chain tried."""
    normaliser = str(fitness.symbols.u[0]) if fitness.symbols.u else None
    limit = best.objective * (1.0 + tolerance)
    current, chain = best, [best]
    while True:
        options = []
        for name in current.state:
            options.append(([f for f in current.state if f != name], list(current.forcing)))
        for name in current.forcing:
            if name != normaliser:
                options.append((list(current.state), [f for f in current.forcing if f != name]))
        candidates = [c for c in _records_for(fitness, options)
                      if c.valid and c.status == 0 and c.objective <= limit]
        if not candidates:
            return current, chain
        current = min(candidates, key=lambda r: r.objective)
        chain.append(current)


def pareto_front(records: list[Record]) -> list[Record]:
    """For each complexity (number of terms), the best record if it beats every simpler one."""
    front: list[Record] = []
    for record in sorted((r for r in records if r.valid and r.status == 0),
                         key=lambda r: (r.n_terms, r.objective)):
        if not front or (record.n_terms > front[-1].n_terms
                         and record.objective < front[-1].objective):
            front.append(record)
        elif record.n_terms == front[-1].n_terms and record.objective < front[-1].objective:
            front[-1] = record
    return front
