"""Neighbours of a model for the final selection (:func:`gpjax._select.simplify`).

A neighbour is the model with one of these changes, refitted afterwards:

* **removal** of one term (never the input whose coefficient is normalised to 1);
* **swap**: one term replaced by another basis feature (:meth:`Fitness.basis_features`);
* **snap** of an inner constant to its simple value, *held* from then on (never refined,
  not counted as fitted): in sin/cos(a·z + b) the phase b to 0 (an odd law), the scale a
  to 1 (the variable is itself the angle, in radians), or both; in tanh(a·z) the scale to
  the smoothed sign's, 1/(ε·RMS z), ε the fitness's ``sign_width`` (dry friction's sign
  law has no scale of its own; :mod:`gpjax._features`), and so the sign's scale θ1 in the stribeck family's
  exp(−(θ0·z)²)·tanh(θ1·z), which a move that adds a stribeck member (a swap, powers →
  function) holds from the start. exp's scale carries the units of z and has no
  simple value;
* **function → powers**: a bank feature replaced by two powers z^j, z^k of its variable
  (a Taylor pair: x and x³ in place of sin(a·x + b) or of x·|x|);
* **powers → function**: one or two powers of z replaced by one bank feature of z (z^k·|z|;
  sin/cos(z) with a = 1 and b = 0 held; tanh, exp, sinh, cosh from their default scale,
  which the least-squares start's grid and refinement then set);
* **function → constant force and z**: a bank feature of z replaced by a constant force
  and the first power of z (kept where the model has it): the model at the feature's
  first-order expansion, f(a·z) ≈ f(0) + f'(0)·a·z. A feature whose argument stays small
  over the record (exp(0.006·x') beside x', an offset in disguise) is then one or two
  constants too many;
* **Taylor pair dropped**: where a bank feature of z is in the model, two powers of z
  removed at once (the reverse of function → powers: k·tanh(x/a) beside x and x³ sheds the
  pair in one move, which two single removals, each through a worse model, may not);
* **exp pair tied**: exp(a₁·z) and exp(a₂·z) with scales of opposite sign replaced by
  sinh(ā·z), or by cosh(ā·z), ā = (|a₁| + |a₂|)/2 — the symmetric law with two constants
  fewer (:mod:`gpjax._features`);
* **Stribeck law completed**: a stribeck member exp(−(θ0·z)²)·sign(z) with no sign of z in
  the model gets the smoothed sign tanh(z/(ε·RMS z)), its scale held. The stribeck member
  is the *excess* of static over Coulomb friction, (Fs − Fc)·e^{−(z/v_s)²}·sign z; the
  law it belongs to carries the Coulomb level Fc·sign z beside it. The only move that
  keeps every term and adds one: without it a walk that reaches the excess alone (a front
  member whose Coulomb level the search never paired with it) cannot reach the law, since
  every other move removes or replaces terms. The model's fitted inner constants are the
  neighbour's start (``kept``), not a grid start: the grid is chosen by the weak form at
  the smoothed measured velocity, which blurs what a Stribeck bump resolves (on
  ``stribeck_resolved`` suite seed 0 it moved the excess's fitted v_s = 1.24 to the
  grid's RMS x'/100 = 0.013, a basin Levenberg–Marquardt does not leave). Like every neighbour as complex as the current
  model or more, it is taken only if it predicts the held-out data significantly better
  (:mod:`gpjax._select`).

A single power replacing a function is a swap already.
"""

from __future__ import annotations

import dataclasses
import itertools

import sympy as sp

from ._canonical import CanonicalForm
from ._features import match
from ._fitness import structure_key

#: Simple values of sin/cos(a·z + b): slot 0 is a, slot 1 is b (see the module docstring).
SNAPS = ({1: 0.0}, {0: 1.0}, {0: 1.0, 1: 0.0})


@dataclasses.dataclass(frozen=True)
class Move:
    """A neighbour's terms (feature -> start value), held inner-constant slots, and
    ``kept`` slots: refined from the values in ``state``, not from a grid start
    (:meth:`gpjax._fitness.Fitness.score_forms`)."""

    state: dict
    forcing: dict
    held: tuple[int, ...]
    kept: tuple[int, ...] = ()

    def form(self, mass: float) -> CanonicalForm:
        return CanonicalForm(mass=mass, state=tuple(self.state.items()),
                             forcing=tuple(self.forcing.items()))


def neighbours(fitness, record) -> list[Move]:
    """Every neighbour of ``record`` (module docstring), once."""
    ev, symbols = fitness.evaluator, fitness.symbols
    now = record.coefficients
    held = set(record.held)

    def slots(feature) -> set[int]:
        where, _ = ev.inner_of(feature)
        return set(range(where.start, where.stop))

    def move(state, forcing, dropped=(), added=()) -> Move:
        kept = held - set().union(*map(slots, dropped)) if dropped else set(held)
        kept |= {i for f in state if f not in now.state for i in _sign_slot(fitness, f)}
        return Move(dict(state), dict(forcing), tuple(sorted(kept | set(added))))

    basis = fitness.basis_features()
    normaliser = symbols.u[0] if symbols.u else None
    state, forcing = dict(now.state), dict(now.forcing)
    moves = []
    for name, value in state.items():  # removals and swaps of state terms
        rest = {t: v for t, v in state.items() if t != name}
        moves.append(move(rest, forcing, [name]))
        moves += [move({**rest, other: value}, forcing, [name])
                  for other in basis["state"] if other not in state]
    for name, value in forcing.items():
        if name == normaliser:
            continue
        rest = {t: v for t, v in forcing.items() if t != name}
        moves.append(move(state, rest))
        moves += [move(state, {**rest, other: value})
                  for other in basis["forcing"] if other not in forcing]
    for name, value in state.items():
        found = match(name, symbols)
        if found is None:
            continue
        family, theta = found
        first = ev.inner_of(name)[0].start
        rest = {t: v for t, v in state.items() if t != name}
        if family.function in ("sin", "cos"):
            for snap in SNAPS:
                if any(first + k in held for k in snap):
                    continue
                snapped = tuple(snap.get(k, v) for k, v in enumerate(theta))
                moves.append(move({**rest, family.feature(symbols, snapped): value}, forcing,
                                  added=[first + k for k in snap]))
        sign_slot = _last_slot(fitness, name, family)
        if family.function in ("tanh", "stribeck") and sign_slot not in held:
            sign = fitness.sign_scale(family.role)
            moves.append(move({**rest, family.feature(symbols, (*theta[:-1], sign)): value},
                              forcing, added=[sign_slot]))
        z = family.variable(symbols)
        if sp.Integer(1) not in forcing:  # function -> constant force and z
            moves.append(move({**rest, z: rest.get(z, value)},
                              {**forcing, sp.Integer(1): -value}, [name]))
        for j, k in itertools.combinations(range(1, fitness.config.max_degree + 1), 2):
            moves.append(move({**rest, z ** j: rest.get(z ** j, value),
                               z ** k: rest.get(z ** k, value)}, forcing, [name]))
    moves += _powers_to_function(fitness, state, forcing, move)
    moves += _drop_taylor_pairs(fitness, state, forcing, move)
    moves += _tie_exp_pairs(fitness, state, forcing, move)
    moves += _complete_stribeck(fitness, state, forcing, move, slots)
    unique, names = {}, {}

    def name(feature) -> str:  # a few features recur in every move: print each once
        if feature not in names:
            names[feature] = str(feature)
        return names[feature]

    for m in moves:
        unique.setdefault((tuple(map(name, m.state)), tuple(map(name, m.forcing)), m.held), m)
    return list(unique.values())


def _powers_to_function(fitness, state: dict, forcing: dict, move) -> list[Move]:
    """One or two powers of x (or of x') replaced by a bank feature of that variable
    (module docstring)."""
    ev, symbols = fitness.evaluator, fitness.symbols
    moves = []
    used = {ev.state_index(f) for f in state}
    for family in ev.families:
        if family.slot:
            continue  # a second slot's default (exp(−z/s)) is reached by a swap
        powers = _powers_of(family.variable(symbols), state)
        feature = fitness.default_feature(family)
        slots = ev.inner_of(feature)[0]
        added = list(range(slots.start, slots.stop)) if family.function in ("sin", "cos") else []
        if ev.state_index(feature) in used:
            continue
        for count in (1, 2):
            for replaced in itertools.combinations(powers, count):
                rest = {t: v for t, v in state.items() if t not in replaced}
                moves.append(move({**rest, feature: state[replaced[0]]}, forcing,
                                  added=added))
    return moves


def _sign_slot(fitness, feature) -> tuple[int, ...]:
    """The slot of a stribeck member's sign scale θ1, held where local search adds one
    (:mod:`gpjax._features`); none for other features."""
    found = match(feature, fitness.symbols)
    if found is None or found[0].function != "stribeck":
        return ()
    return (_last_slot(fitness, feature, found[0]),)


def _last_slot(fitness, feature, family) -> int:
    """The slot of ``feature``'s last inner constant: the sign's scale of tanh and stribeck."""
    return fitness.evaluator.inner_of(feature)[0].start + family.n_inner - 1


def move_key(move: Move, mass: float, tree_mode: bool) -> str:
    """The record key of a neighbour: its structure key, the held slots, and in tree mode
    the ``pruned`` prefix (:func:`gpjax._fitness.structure_key`)."""
    key = structure_key(move.form(mass), with_coefficients=False)
    if move.held:
        key += " | held " + ",".join(map(str, move.held))
    return "pruned " + key if tree_mode else key



def _powers_of(z, state: dict) -> list:
    return [f for f in state if f == z or (f.is_Pow and f.base == z)]


def _drop_taylor_pairs(fitness, state: dict, forcing: dict, move) -> list[Move]:
    """Two powers of z removed at once where a bank feature of z is in ``state`` (module
    docstring)."""
    moves = []
    for z in {found[0].variable(fitness.symbols) for found in map(
            lambda f: match(f, fitness.symbols), state) if found is not None}:
        for pair in itertools.combinations(_powers_of(z, state), 2):
            moves.append(move({t: v for t, v in state.items() if t not in pair}, forcing, pair))
    return moves


def _complete_stribeck(fitness, state: dict, forcing: dict, move, slots) -> list[Move]:
    """A stribeck member's Coulomb level, the smoothed sign of its variable with the scale
    held, added where the model has no sign of that variable; the model's fitted inner
    constants are its start (module docstring)."""
    symbols, ev = fitness.symbols, fitness.evaluator
    found = {f: match(f, symbols) for f in state}
    signed = {fam.role for fam, _ in filter(None, found.values()) if fam.function == "tanh"}
    moves = []
    for f, hit in found.items():
        if hit is None or hit[0].function != "stribeck" or hit[0].role in signed:
            continue
        sign = next((fam for fam in ev.families
                     if fam.function == "tanh" and fam.role == hit[0].role), None)
        if sign is None:
            continue
        feature = fitness.default_feature(sign)
        added = move({**state, feature: state[f]}, forcing,
                     added=[_last_slot(fitness, feature, sign)])
        moves.append(dataclasses.replace(added, kept=tuple(sorted(
            set().union(*(slots(t) for t in state)) - set(added.held)))))
        signed.add(hit[0].role)
    return moves


def _tie_exp_pairs(fitness, state: dict, forcing: dict, move) -> list[Move]:
    """exp(a₁·z), exp(a₂·z) with a₁·a₂ < 0 replaced by sinh(ā·z) or cosh(ā·z) (module
    docstring)."""
    symbols, moves = fitness.symbols, []
    exps = [(f, match(f, symbols)) for f in state if isinstance(f, sp.exp)]
    for (f1, (family, (a1,))), (f2, (_, (a2,))) in itertools.combinations(
            [(f, found) for f, found in exps if found is not None], 2):
        if family.role != match(f2, symbols)[0].role or a1 * a2 >= 0:
            continue
        rest = {t: v for t, v in state.items() if t not in (f1, f2)}
        scale = 0.5 * (abs(a1) + abs(a2))
        z = family.variable(symbols)
        for function in (sp.sinh, sp.cosh):
            moves.append(move({**rest, function(sp.Float(scale) * z): state[f1]}, forcing,
                              [f1, f2]))
    return moves
