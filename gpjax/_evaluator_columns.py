"""Parts of :class:`gpjax._evaluator.PopulationEvaluator`: its columns — which state
column (and which inner-constant slots) a feature takes, the forcing basis evaluated at the
RK4 stage rows and grown in bucketed capacities (so a new forcing feature compiles only
when the capacity doubles), and the flat constant layouts of a model."""

from __future__ import annotations

import dataclasses

import numpy as np
import sympy as sp

from ._coefficients import FlatLayout, Population
from ._features import SLOTS, match
from ._system_bank import match_bank, system_variables

#: Forcing columns of a new evaluator's basis, then doubled as features arrive. Every
#: doubling compiles each program again (~40 s on 2 cores with the wide function set's
#: layouts), and a wide-set search registers 25–40 forcing features (u, |u|, sin u,
#: tanh(a·u), …) on an 8,000-sample record; starting at 16 it compiled everything twice
#: more. Where the basis at this capacity would exceed one call's stage array
#: (:data:`gpjax._evaluator.STAGE_ELEMENTS_PER_CALL`: a record of ~200,000 samples) it
#: starts at :data:`MIN_FORCING_CAPACITY`, as memory bounds everything else there.
FIRST_FORCING_CAPACITY, MIN_FORCING_CAPACITY = 64, 16


def first_forcing_capacity(n_stage: int) -> int:
    """Forcing columns of a new basis of ``n_stage`` RK4 stage rows (see
    :data:`FIRST_FORCING_CAPACITY`)."""
    from ._evaluator import STAGE_ELEMENTS_PER_CALL

    fits = n_stage * FIRST_FORCING_CAPACITY <= STAGE_ELEMENTS_PER_CALL
    return FIRST_FORCING_CAPACITY if fits else MIN_FORCING_CAPACITY


class Columns:
    """Mixin of :class:`gpjax._evaluator.PopulationEvaluator` (uses its ``symbols``,
    ``families``, ``state_features``, ``n_inner``, ``n_coordinates``, ``stage_times`` and
    the column maps its constructor builds)."""

    def state_columns(self, features) -> list[tuple[int | None, slice, tuple[float, ...]]]:
        """Per state feature of one model: its column in the basis (``None``: not
        supported), the slots of its inner constants in :attr:`Population.inner` and their
        values in the feature. The k-th member of a family takes the family's k-th slot
        (:data:`gpjax._features.SLOTS`); members beyond them share the last slot's column,
        which :func:`gpjax._coefficients.to_population` refuses."""
        out, taken = [], set()
        for feature in features:
            column = self._state_index.get(feature)
            found = None if column is not None or not self.families else match(
                feature, self.symbols)
            if found is None:
                out.append((column, slice(0, 0), ()))
                continue
            slots = [dataclasses.replace(found[0], slot=k)
                     for k in range(SLOTS.get(found[0].function, 1))]
            slots = [f for f in slots if f in self._family_column]
            if not slots:
                out.append((None, slice(0, 0), ()))
                continue
            family = next((f for f in slots if self._family_column[f] not in taken), slots[-1])
            taken.add(self._family_column[family])
            out.append((self._family_column[family],
                        self._inner_slots[self.families.index(family)], found[1]))
        return out

    def state_index(self, feature: sp.Expr) -> int | None:
        """Column of a state feature in the basis (a power, an extra feature, or a member
        of one of the families, its first slot), or ``None`` if it is not supported."""
        return self.state_columns([feature])[0][0]

    def equation_index(self, feature: sp.Expr, equation: int) -> int | None:
        """Column of a state feature in ``equation``'s basis (:attr:`equation_features`),
        or ``None``; for D = 1 :meth:`state_index`."""
        if self.n_coordinates == 1:
            return self.state_index(feature)
        column = self._equation_index[equation].get(feature)
        found = None if column is not None or not self.kinds else match_bank(
            feature, system_variables(self.measurement.response_names)[equation])
        if found is None or found[0] not in self.kinds:
            return column
        count = self.n_coordinates
        return 2 * count * (self.max_degree + self.kinds.index(found[0])) + found[1]

    def inner_of(self, feature: sp.Expr) -> tuple[slice, tuple[float, ...]]:
        """The slots of a state feature's inner constants in :attr:`Population.inner` (its
        family's first slot) and their values in ``feature`` (none for powers and extra
        features)."""
        return self.state_columns([feature])[0][1:]

    def inner_columns(self) -> list[tuple[int, slice]]:
        """(state column, slots in :attr:`Population.inner`) of every family."""
        return [(self._family_column[f], slots)
                for f, slots in zip(self.families, self._inner_slots)]

    def feature_at(self, column: int, theta) -> sp.Expr:
        """The state feature of ``column`` with inner constants ``theta`` (a family's)."""
        first = len(self.state_features) - len(self.families)
        if column < first:
            return self.state_features[column]
        return self.families[column - first].feature(self.symbols, tuple(map(float, theta)))

    def forcing_finite(self, feature: sp.Expr) -> bool:
        """Whether a forcing feature is finite at every stage time: a column that is not
        would make the forcing of *every* model in a call NaN (0·inf), so such a feature
        must not enter the basis."""
        if feature not in self._finite:
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # the check
                self._finite[feature] = bool(np.all(np.isfinite(self.forcing_values(
                    feature, self.stage_times, self._stage_inputs))))
        return self._finite[feature]

    def forcing_index(self, feature: sp.Expr) -> int:
        """Column of a forcing feature, evaluating it on the stage grid the first time.

        Raises:
            ValueError: the feature is not finite at every stage time
                (:meth:`forcing_finite`).
        """
        if feature not in self._forcing_index:
            values = self.forcing_values(feature, self.stage_times, self._stage_inputs)
            if not np.all(np.isfinite(values)):
                raise ValueError(f"forcing feature {feature} is not finite on the data")
            column = self._forcing_index[feature] = len(self._forcing_features)
            self._forcing_features.append(feature)
            capacity = grown_capacity(column + 1, self._first_forcing_capacity)
            if capacity > self.forcing_capacity:  # a wider basis: the old columns copied once
                basis = np.zeros((self.stage_times.size, capacity))
                basis[:, :column] = self._forcing_basis[:, :column]
                self._forcing_basis = basis
            # A column no model in flight uses (its coefficients are 0) is written in place:
            # a record of 10⁶ stage rows is not copied for every feature added.
            self._forcing_basis[:, column] = values
        return self._forcing_index[feature]

    @property
    def forcing_capacity(self) -> int:
        return self._forcing_basis.shape[1]

    @property
    def forcing_features(self) -> tuple[sp.Expr, ...]:
        """The forcing features in column order."""
        return tuple(self._forcing_features)

    @property
    def forcing_basis(self) -> np.ndarray:
        """(n_stage, forcing capacity) forcing features at every RK4 stage row (read-only)."""
        view = self._forcing_basis.view()
        view.flags.writeable = False
        return view

    @property
    def layout(self) -> FlatLayout:
        """The flat constant vector of one model on this evaluator's columns."""
        return FlatLayout(len(self.state_features), self.forcing_capacity, self.n_inner,
                          self.n_coordinates)

    @property
    def plain_layout(self) -> FlatLayout:
        """:attr:`layout` without the families' columns and inner constants (models that
        use no family; see :meth:`plain_rows`)."""
        return FlatLayout(len(self.state_features) - len(self.families),
                          self.forcing_capacity, 0, self.n_coordinates)

    def plain_rows(self, population: Population) -> np.ndarray:
        """(P,) whether each model uses no family: such models are simulated and refined
        without the bank's columns (the same compiled code traced for narrower arrays), so
        polynomial candidates never pay for the families' transcendental functions."""
        used = population.state[..., self.plain_layout.n_state:] != 0
        return ~np.any(used.reshape(len(population), -1), axis=1)

    def layout_groups(self, population: Population) -> list[tuple[np.ndarray, bool]]:
        """``population``'s rows by layout, as (rows, plain): the models that use no family
        (:meth:`plain_rows`), then the others ordered by the families they use, so that
        models using the same families share a batch and each batch evaluates few of them
        (:meth:`~gpjax._evaluator_dynamics.Dynamics._family_sum`); empty groups left out."""
        plain = self.plain_rows(population)
        rows = np.flatnonzero(~plain)
        if rows.size:
            used = population.state[rows][..., self.plain_layout.n_state:] != 0
            rows = rows[np.lexsort(used.reshape(rows.size, -1).T[::-1])]
        return [(r, p) for r, p in ((np.flatnonzero(plain), True), (rows, False)) if r.size]

    def narrowed(self, population: Population) -> Population:
        """``population`` on :attr:`plain_layout` (its family columns dropped)."""
        return dataclasses.replace(population,
                                   state=population.state[..., :self.plain_layout.n_state],
                                   inner=population.inner[:, :0])

    def check_forcing_bank(self, population: Population) -> None:
        """Check that ``population``'s forcing columns hold this evaluator's forcing features
        (an evaluator that registered other features, or the same in another order, would
        multiply each coefficient by another feature).

        Raises:
            ValueError: they were laid out on another forcing bank.
        """
        made = population.forcing_features
        if made is not None and tuple(self._forcing_features[:len(made)]) != tuple(made):
            raise ValueError(
                f"the population's forcing columns hold {list(made)} but this evaluator's "
                f"hold {list(self._forcing_features)}: lay it out with this evaluator "
                f"(to_population) or register its forcing features in the same order")

    def _layout_of(self, width: int) -> FlatLayout:
        return self.layout if width == self.layout.width else self.plain_layout

    def forcing_basis_as(self, interpolation: str | None = None, *,
                         inputs: dict[str, np.ndarray] | None = None) -> np.ndarray:
        """:attr:`forcing_basis` with the inputs reconstructed between samples by
        ``interpolation`` (``"linear"`` or ``"bandlimited"``) instead of the evaluator's own,
        or of other ``inputs`` samples (name -> (N,), e.g. with noise drawn on them): same
        rows and columns, so a program compiled for one takes the other.

        Raises:
            ValueError: an ``interpolation`` with a ``"hold"`` evaluator, or ``"hold"``
                (their forcing rows are laid out otherwise).
        """
        from ._record import padded_rows

        if interpolation is not None and (self.split_stages or interpolation == "hold"):
            raise ValueError("a held input has its own forcing rows; compare linear and "
                             "bandlimited reconstructions only")
        rows = self._forcing_basis.shape[0]
        inputs = {name: padded_rows(self._at_stages(values, interpolation), rows)
                  for name, values in (inputs or self.measurement.inputs).items()}
        basis = np.zeros_like(self._forcing_basis)
        for column, feature in enumerate(self._forcing_features):
            basis[:, column] = self.forcing_values(feature, self.stage_times, inputs)
        return basis

    def forcing_values(self, feature: sp.Expr, times: np.ndarray,
                       inputs: dict[str, np.ndarray]) -> np.ndarray:
        """A forcing feature ψ(t, u) evaluated (numpy) at ``times`` with ``inputs``."""
        args = (self.symbols.t, *self.symbols.u)
        fn = sp.lambdify(args, feature, modules="numpy")
        values = fn(times, *(inputs[name] for name in self.symbols.inputs))
        return np.broadcast_to(np.asarray(values, dtype=np.float64), times.shape).copy()


def grown_capacity(count: int, first: int) -> int:
    """Forcing columns for ``count`` features: ``first``, doubled as often as needed."""
    capacity = max(1, first)
    while capacity < count:
        capacity *= 2
    return capacity
