"""One model's constants, keyed by sympy feature, and their array forms.

:class:`Coefficients` is the one representation of an equation's constants that records,
models, the diagnosis and the Silverbox tools share: the inertia m, the left-hand-side
terms (features of x alone, of x' alone, or declared time-varying g(t)·h(x)), the forcing
terms (features of time and inputs) and the initial state. Features are sympy
expressions, so no feature text is parsed once a model exists; text appears only where
a model is written to or read from JSON.

Two array forms serve the compiled code:

* :class:`Population`, (P,) and (P, F) arrays over an evaluator's feature columns
  (:func:`to_population`, :func:`from_population`);
* :class:`FlatLayout`, one vector per model ``[m | c | g | θ | x0, x0']`` — what
  Levenberg–Marquardt moves (:mod:`gpjax._refine`) and what the variational Jacobian
  differentiates (:meth:`gpjax._evaluator.PopulationEvaluator.constant_jacobian`).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Iterable, Protocol, Sequence

import numpy as np
import sympy as sp

from ._canonical import CanonicalForm, feature_name
from ._features import inner_constants


@dataclasses.dataclass(frozen=True)
class Coefficients:
    """``mass·x'' + Σ c·φ = Σ g·ψ`` and the initial state (x0, x0') of one equation.

    Attributes:
        mass: inertia coefficient m.
        state: left-hand-side feature -> coefficient c (insertion order is kept).
        forcing: right-hand-side feature (time and inputs; ``1`` is a constant force) ->
            coefficient g.
        y0: (x, x') at the first sample; NaN where not known.
    """

    mass: float
    state: dict[sp.Expr, float]
    forcing: dict[sp.Expr, float]
    y0: tuple[float, float] = (math.nan, math.nan)

    @classmethod
    def from_canonical(cls, form: CanonicalForm,
                       y0: tuple[float, float] = (math.nan, math.nan)) -> "Coefficients":
        return cls(mass=form.mass, state=dict(form.state), forcing=dict(form.forcing), y0=y0)

    def canonical(self) -> CanonicalForm:
        return CanonicalForm(mass=self.mass, state=tuple(self.state.items()),
                             forcing=tuple(self.forcing.items()))

    @property
    def n_terms(self) -> int:
        """Complexity: inertia term + state terms + forcing terms."""
        return 1 + len(self.state) + len(self.forcing)

    @property
    def n_constants(self) -> int:
        """Fitted constants: m, one coefficient per term and each state feature's inner
        constants (:func:`gpjax._features.inner_constants`)."""
        return self.n_terms + sum(inner_constants(f) for f in self.state)

    def replace(self, **changes) -> "Coefficients":
        return dataclasses.replace(self, **changes)

    def to_json(self) -> dict:
        """Plain JSON: feature text -> value (a checkpoint or model file part)."""
        return {"mass": self.mass, "state": {feature_name(f): v for f, v in self.state.items()},
                "forcing": {feature_name(f): v for f, v in self.forcing.items()},
                "y0": list(self.y0)}

    @classmethod
    def from_json(cls, data: dict, names: set[str]) -> "Coefficients":
        """Inverse of :meth:`to_json`; features are parsed by the whitelist parser.

        Raises:
            ModelFileError: a feature outside the whitelist or with unknown names.
        """
        from ._expressions import parse_expression

        def parsed(terms: dict) -> dict:
            return {parse_expression(text, names): float(v) for text, v in terms.items()}

        return cls(mass=float(data["mass"]), state=parsed(data["state"]),
                   forcing=parsed(data["forcing"]), y0=tuple(map(float, data["y0"])))


@dataclasses.dataclass(frozen=True)
class Population:
    """A batch of models as arrays (P models) over an evaluator's feature columns; a
    system of D > 1 equations has a coordinate axis after P in mass, state, forcing and y0.

    Attributes:
        mass: (P,) inertia coefficient m.
        state: (P, F_state) coefficients of the state basis.
        forcing: (P, F_forcing) coefficients of the forcing basis.
        y0: (P, 2) initial response and its derivative at the first sample.
        inner: (P, F_inner) inner constants θ of the feature bank's families
            (:mod:`gpjax._features`); ``None`` for an evaluator without families.
        forcing_features: the forcing features its forcing columns hold, in column order,
            as the evaluator that laid it out held them; an evaluator given the
            population checks them against its own bank. ``None``: not recorded.
    """

    mass: np.ndarray
    state: np.ndarray
    forcing: np.ndarray
    y0: np.ndarray
    inner: np.ndarray | None = None
    forcing_features: tuple | None = None

    def __post_init__(self):
        if self.inner is None:
            object.__setattr__(self, "inner", np.zeros((self.mass.shape[0], 0)))

    def __len__(self) -> int:
        return self.mass.shape[0]

    def rows(self, rows) -> "Population":
        """The models at ``rows`` (a slice or index array)."""
        return dataclasses.replace(self, **{name: getattr(self, name)[rows]
                                            for name in _POPULATION_ARRAYS})

    @staticmethod
    def concatenate(populations: Iterable["Population"]) -> "Population":
        """One population of the rows of ``populations`` in order.

        Raises:
            ValueError: two were laid out on different forcing banks (neither's forcing
                features begin the other's).
        """
        populations = list(populations)
        banks = [p.forcing_features for p in populations if p.forcing_features is not None]
        bank = max(banks, key=len) if banks else None
        if any(b != bank[:len(b)] for b in banks):
            raise ValueError("populations laid out on different forcing banks cannot be joined")
        return Population(**{name: np.concatenate([getattr(p, name) for p in populations])
                             for name in _POPULATION_ARRAYS}, forcing_features=bank)


_POPULATION_ARRAYS = ("mass", "state", "forcing", "y0", "inner")


class Columns(Protocol):
    """Where each feature's coefficient lives in a :class:`Population` (an evaluator)."""

    def state_columns(self, features) -> list[tuple[int | None, slice, tuple[float, ...]]]: ...

    def feature_at(self, column: int, theta) -> sp.Expr: ...

    def forcing_index(self, feature: sp.Expr) -> int: ...

    def empty(self, count: int) -> Population: ...


def to_population(models: Sequence[Coefficients], columns: Columns) -> Population:
    """The arrays of ``models`` on ``columns``' features (forcing columns are added as
    needed). A NaN mass becomes 1 and a NaN initial state 0 (placeholders).

    Raises:
        ValueError: a state feature outside ``columns``' basis, or two features of one
            model in one column (two members of one feature-bank family).
    """
    for model in models:
        for feature in model.forcing:
            columns.forcing_index(feature)
    population = columns.empty(len(models))
    for i, model in enumerate(models):
        placed = columns.state_columns(list(model.state))
        taken = [column for column, _, _ in placed]
        if len(set(taken)) < len(taken):
            raise ValueError(f"two state features of one model share a column (more members "
                             f"of one feature-bank family than its slots?): {list(model.state)}")
        population.mass[i] = model.mass if math.isfinite(model.mass) else 1.0
        for (feature, value), (column, slots, theta) in zip(model.state.items(), placed):
            if column is None:
                raise ValueError(f"state feature {feature} is outside the evaluator's basis")
            population.state[i, column] = value
            population.inner[i, slots] = theta
        for feature, value in model.forcing.items():
            population.forcing[i, columns.forcing_index(feature)] = value
        population.y0[i] = np.nan_to_num(model.y0)
    return population


def from_population(population: Population, columns: Columns,
                    like: Sequence[Coefficients]) -> list[Coefficients]:
    """Coefficients of the features of ``like[i]`` read from row i of ``population``; a
    feature with inner constants comes back with row i's (refined) values inside."""
    def state(i: int, model: Coefficients) -> dict[sp.Expr, float]:
        out = {}
        for column, slots, _ in columns.state_columns(list(model.state)):
            out[columns.feature_at(column, population.inner[i, slots])] = float(
                population.state[i, column])
        return out

    return [Coefficients(
        mass=float(population.mass[i]), state=state(i, model),
        forcing={f: float(population.forcing[i, columns.forcing_index(f)])
                 for f in model.forcing},
        y0=(float(population.y0[i, 0]), float(population.y0[i, 1])))
        for i, model in enumerate(like)]


def to_system_population(systems: Sequence[Sequence[Coefficients]], columns) -> Population:
    """The arrays of ``systems`` — each one :class:`Coefficients` per equation, in the
    coordinates' order, y0 that coordinate's (x0, x0') — on a system evaluator's columns
    (``columns.equation_index(feature, equation)``). A NaN mass becomes 1 and a NaN
    initial state 0.

    Raises:
        ValueError: a state feature outside that equation's basis.
    """
    for system in systems:
        for equation in system:
            for feature in equation.forcing:
                columns.forcing_index(feature)
    population = columns.empty(len(systems))
    for i, system in enumerate(systems):
        for e, equation in enumerate(system):
            population.mass[i, e] = equation.mass if math.isfinite(equation.mass) else 1.0
            for feature, value in equation.state.items():
                column = columns.equation_index(feature, e)
                if column is None:
                    raise ValueError(f"state feature {feature} is outside equation {e + 1}'s "
                                     "basis")
                population.state[i, e, column] = value
            for feature, value in equation.forcing.items():
                population.forcing[i, e, columns.forcing_index(feature)] = value
            population.y0[i, e] = np.nan_to_num(equation.y0)
    return population


def from_system_population(population: Population, columns,
                           like: Sequence[Sequence[Coefficients]]) -> list[list[Coefficients]]:
    """Inverse of :func:`to_system_population` for the features of ``like``."""
    return [[Coefficients(
        mass=float(population.mass[i, e]),
        state={f: float(population.state[i, e, columns.equation_index(f, e)])
               for f in equation.state},
        forcing={f: float(population.forcing[i, e, columns.forcing_index(f)])
                 for f in equation.forcing},
        y0=(float(population.y0[i, e, 0]), float(population.y0[i, e, 1])))
        for e, equation in enumerate(system)] for i, system in enumerate(like)]


@dataclasses.dataclass(frozen=True)
class FlatLayout:
    """One model's constants as one vector
    ``[m | c (n_state) | g (n_forcing) | θ (n_inner) | x0, x0']``; for a system of
    ``n_coordinates`` D > 1 equations ``[m_1 … m_D | c per equation | g per equation | θ |
    (x0, x0') per coordinate]``.

    Works on numpy and JAX arrays alike; the last axis is the flat one.
    """

    n_state: int
    n_forcing: int
    n_inner: int = 0
    n_coordinates: int = 1

    @property
    def width(self) -> int:
        d = self.n_coordinates
        return d * (1 + self.n_state + self.n_forcing + 2) + self.n_inner

    def mass_column(self, equation: int = 0) -> int:
        return equation

    def state_column(self, column: int, equation: int = 0) -> int:
        return self.n_coordinates + equation * self.n_state + column

    def forcing_column(self, column: int, equation: int = 0) -> int:
        d = self.n_coordinates
        return d * (1 + self.n_state) + equation * self.n_forcing + column

    def inner_column(self, slot: int) -> int:
        return self.n_coordinates * (1 + self.n_state + self.n_forcing) + slot

    def part(self, column: int) -> tuple[str, int, int]:
        """What flat ``column`` holds: (``"mass"``, equation, 0), (``"state"``, equation,
        column), (``"forcing"``, equation, column), (``"inner"``, 0, slot) or (``"y0"``,
        coordinate, 0 for x0 or 1 for x0')."""
        d = self.n_coordinates
        bounds = [("mass", d, 1), ("state", d, self.n_state), ("forcing", d, self.n_forcing),
                  ("inner", 1, self.n_inner), ("y0", d, 2)]
        for name, count, size in bounds:
            if column < count * size:
                return name, column // size, column % size
            column -= count * size
        raise IndexError(f"column {column} is past the layout's width {self.width}")

    def pack(self, population: Population) -> np.ndarray:
        """(P, width) from a population (forcing columns zero-padded to ``n_forcing``)."""
        count = len(population)
        forcing = np.zeros(population.forcing.shape[:-1] + (self.n_forcing,))
        forcing[..., : population.forcing.shape[-1]] = population.forcing
        return np.concatenate([population.mass.reshape(count, -1),
                               population.state.reshape(count, -1), forcing.reshape(count, -1),
                               population.inner, population.y0.reshape(count, -1)], axis=1)

    def split(self, flat):
        """(mass, state, forcing, inner, y0) views along the last axis of ``flat``; for
        D > 1 with a coordinate axis before the last: mass (..., D), state (..., D,
        n_state), forcing (..., D, n_forcing), y0 (..., D, 2)."""
        d = self.n_coordinates
        s = d * (1 + self.n_state)
        g = s + d * self.n_forcing
        i = g + self.n_inner
        if d == 1:
            return flat[..., 0], flat[..., 1:s], flat[..., s:g], flat[..., g:i], flat[..., i:]
        lead = flat.shape[:-1]
        return (flat[..., :d], flat[..., d:s].reshape(lead + (d, self.n_state)),
                flat[..., s:g].reshape(lead + (d, self.n_forcing)), flat[..., g:i],
                flat[..., i:].reshape(lead + (d, 2)))

    def population(self, flat: np.ndarray, n_forcing: int | None = None) -> Population:
        """A population from (P, width) rows, keeping the first ``n_forcing`` forcing
        columns (default all)."""
        mass, state, forcing, inner, y0 = self.split(np.asarray(flat))
        return Population(mass=mass, state=state, forcing=forcing[..., :n_forcing], y0=y0,
                          inner=inner)


#: Padding rows a smaller compiled call must save to be worth one more call: a call costs
#: about a + b·rows, and a/b, its fixed cost in rows, is what the population evaluator
#: measured on 8,000 samples, 2 cores, with and without a family
#: (``benchmarks/bench_call_cost.py``, ``benchmarks/call_cost.json``; at 8, 64 models ran
#: as four calls of 16 in 0.40 s instead of one of 128 in 0.27 s). The refiner's own is
#: smaller (1–2 rows), but with its sizes 2 and 8 only a call of 3–6 models would go
#: otherwise.
CALL_OVERHEAD_ROWS = 36


def chunk_sizes(count: int, sizes: Sequence[int]) -> list[int]:
    """The compiled batch sizes (from ``sizes``) of the calls that cover ``count`` rows:
    full calls of the largest, then the remainder by the calls that cost least, a call
    costing its rows plus :data:`CALL_OVERHEAD_ROWS` (150 rows of sizes (16, 128, 512):
    128 + 16 + 16; 300 rows: 128 + 128 + 16 + 16 + 16)."""
    sizes = tuple(sorted(set(sizes)))
    full, remainder = divmod(count, sizes[-1])
    return [sizes[-1]] * full + list(_cheapest(remainder, sizes)[1])


@functools.lru_cache(maxsize=4096)
def _cheapest(count: int, sizes: tuple[int, ...]) -> tuple[int, tuple[int, ...]]:
    """(cost, calls) of the cheapest calls covering ``count`` < ``sizes[-1]`` rows."""
    if count <= 0:
        return 0, ()
    options = []
    for size in sizes:
        cost, rest = _cheapest(count - size, sizes) if size < count else (0, ())
        options.append((size + CALL_OVERHEAD_ROWS + cost, (size, *rest)))
    return min(options)


def padded_chunks(arrays: Sequence[np.ndarray], sizes: int | Sequence[int]):
    """Yield (size, chunk) for consecutive row blocks of ``arrays`` (same first axis), each
    padded to one of the compiled batch ``sizes`` (:func:`chunk_sizes`) by repeating the
    block's first row, so every compiled call sees one of a few shapes and every padding
    row is a valid model."""
    count = arrays[0].shape[0]
    begin = 0
    for batch in chunk_sizes(count, (sizes,) if isinstance(sizes, int) else sizes):
        stop = min(begin + batch, count)
        pad = batch - (stop - begin)
        yield stop - begin, [np.concatenate([a[begin:stop], np.repeat(a[begin:begin + 1], pad,
                                                                       axis=0)])
                             for a in arrays]
        begin = stop
