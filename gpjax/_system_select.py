"""A system's selection at the search's step count: from the best system found, one
change at a time by the held-out predictive test (:func:`simplest`; the rule is in
:mod:`gpjax._system_search`'s docstring). The changes: a term removed (:func:`removals`), a
bank term swapped for its polynomial stand-in (:func:`power_swaps`) and back
(:func:`bank_swaps`), and one end of a coupling given the law of its other end
(:func:`mirror_swaps`)."""

from __future__ import annotations

import numpy as np
import sympy as sp

from ._diagnose_acceptance import predictive_test
from ._system_bank import match_bank
from ._system_scorer import SystemScorer


def removals(key, i: int):
    """``key`` without one term of equation ``i``, each term in turn."""
    state, forcing = key[i]
    for k in range(len(state)):
        yield key[:i] + ((state[:k] + state[k + 1:], forcing),) + key[i + 1:]
    for k in range(len(forcing)):
        yield key[:i] + ((state, forcing[:k] + forcing[k + 1:]),) + key[i + 1:]


#: A bank kind's Taylor terms near z = 0, lowest first (sin z = z − z³/6 + …, tanh θz =
#: θz − (θz)³/3 + …, cos z = 1 − z²/2 + z⁴/24 − …).
STAND_IN_DEGREES = {"sign": (1, 3), "sin": (1, 3), "cos": (2, 4)}


def power_swaps(key, i: int, scorer: SystemScorer):
    """``key`` with one bank term of equation ``i`` replaced by its polynomial stand-in:
    the lowest of its variable's Taylor powers (:data:`STAND_IN_DEGREES`) that the equation
    lacks (beside z, sin z adds what z³ adds). Where a variable stays small (a coupling's
    relative displacement) sin z and z are nearly collinear, and the selection keeps the
    transcendental term only where the data demonstrate it, as they must any term."""
    equations = scorer.equations
    state, forcing = key[i]
    for z in equations.meaning[i].values():
        for kind, degrees in STAND_IN_DEGREES.items():
            feature = equations.feature(i, kind, z) if kind in equations.kinds else None
            power = next((z ** d for d in degrees if z ** d not in state), None)
            if feature in state and power is not None:
                swapped = tuple(sorted((*(f for f in state if f != feature), power), key=str))
                yield key[:i] + ((swapped, forcing),) + key[i + 1:]


def bank_swaps(key, i: int, scorer: SystemScorer):
    """``key`` with the powers of one variable z of equation ``i`` (two or more) replaced
    by one bank term of z, of each kind of the function set; with three or more, also all
    but z itself. The reverse of :func:`power_swaps` (one coordinate's walk swaps powers for
    a function too), offered only where it removes a term, so that the held-out test's tie
    goes to it for the reason it goes to any removal: c·z + c₃·z³ is the search's usual
    stand-in for a damper's z·|z|, and without a bank term in any equation neither this
    move nor :func:`mirror_swaps` would reach it."""
    equations = scorer.equations
    state, forcing = key[i]
    for z in equations.meaning[i].values():
        powers = [f for f in state if f.as_base_exp()[0] == z]
        if len(powers) < 2:
            continue
        keeps = ((), (z,)) if len(powers) > 2 and z in powers else ((),)
        for kind in equations.kinds:
            feature = equations.feature(i, kind, z)
            for keep in keeps:
                part = (*(f for f in state if f not in powers), *keep, feature)
                yield key[:i] + ((tuple(sorted(part, key=str)), forcing),) + key[i + 1:]


def _coupling_terms(features, z: sp.Expr, variables) -> dict:
    """{feature: its form} of the ``features`` of an equation with ``variables`` that are
    a term of its variable ``z`` alone: ("power", k) for z**k, (kind,) for a bank term of z."""
    out = {}
    for feature in features:
        base, exponent = feature.as_base_exp()
        if base == z and exponent.is_Integer:
            out[feature] = ("power", int(exponent))
        elif feature.free_symbols == z.free_symbols:
            found = match_bank(feature, variables)
            if found is not None and variables[found[1]] == z:
                out[feature] = (found[0],)
    return out


def mirror_swaps(key, j: int, scorer: SystemScorer):
    """``key`` with equation ``j``'s terms in a relative coordinate z = x_j − x_k (or
    x_j' − x_k') replaced by the mirror of equation k's terms in −z, where equation k has a
    bank term in it that equation j lacks and the change adds no term. Reason: a force
    between two masses acts on both by one law (Newton's third law), so a polynomial in z
    in one equation beside a bank term in the other is a stand-in; the held-out test
    decides, as for any change (none with the third law: a coupling lives in one equation
    there)."""
    equations = scorer.equations
    if equations.third_law:
        return
    state, forcing = key[j]
    mine = equations.variables[j]
    for k in range(len(key)):
        if k == j:
            continue
        theirs = equations.variables[k]
        for z in mine:
            mirror = next((w for w in theirs if sp.expand(w + z) == 0), None)
            if mirror is None:
                continue
            own = _coupling_terms(state, z, mine)
            other = _coupling_terms(key[k][0], mirror, theirs)
            mirrored = [z ** form[1] if form[0] == "power" else equations.feature(j, form[0], z)
                        for form in other.values()]
            if not own or len(mirrored) > len(own) or set(mirrored) == set(own) or not any(
                    form[0] != "power" for form in other.values()):
                continue
            part = tuple(sorted((*(f for f in state if f not in own), *mirrored), key=str))
            yield key[:j] + ((part, forcing),) + key[j + 1:]


def simplest(best, scorer: SystemScorer, alpha: float, resolution: float):
    """From ``best``, one-term removals, power, bank and mirror swaps by the held-out test
    (:mod:`gpjax._system_search`), tried in the order of their held-out mean square. A
    change replaces the current system when it predicts the held-out windows significantly
    better (level ``alpha``: the term demonstrably hurts), or when neither predicts
    significantly better and it does not simulate significantly worse once refined
    (:meth:`SystemScorer.simulates_better`). The held-out windows' equation error, on
    smoothed noisy states, is biased differently for a function and its Taylor stand-in
    (errors in variables: E sin(x + n) ≠ sin x), enough to call a held-out chain's true k·x1
    significantly worse than 22·sin x1 + 3.4·x1³ (2 % noise); so it cannot veto a power swap
    nor take a bank swap on its own: the simulated guard decides both, the held-out test
    only screening bank swaps (a refinement each would be dear). A system once left is not
    offered again (a swap and its reverse cannot cycle). Ends when no change qualifies."""
    current, visited = best, {best}
    while True:
        to_power, to_bank, changes = set(), set(), []
        for i in range(len(current)):
            powers = list(power_swaps(current, i, scorer))
            banks = list(bank_swaps(current, i, scorer))
            to_power.update(powers)
            to_bank.update(banks)
            changes += [*removals(current, i), *powers, *banks, *mirror_swaps(current, i, scorer)]
        candidates = list(dict.fromkeys(c for c in changes if c not in visited
                                        and all(part[0] or part[1] for part in c)))
        base = scorer.held_out(current)
        residuals = [scorer.held_out(c) for c in candidates]
        order = np.argsort([np.mean(r ** 2) for r in residuals], kind="stable")
        for index in order:
            change = candidates[index]
            swap = change in to_power or change in to_bank
            if (not swap and predictive_test(base, residuals[index])["p_value"] < alpha) or (
                    (change in to_power
                     or predictive_test(residuals[index], base)["p_value"] >= alpha)
                    and not scorer.simulates_better(current, change, alpha, resolution)):
                current = change
                visited.add(current)
                break
        else:
            return current
