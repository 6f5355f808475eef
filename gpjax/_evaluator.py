"""Batched simulation and scoring of a whole population in one compiled RK4 call.

The population enters as *data*: every model is ``mass·x'' + C·φ(x, x') = G·ψ(t, u)`` with

* φ a fixed basis of state features (x, x², …, x^D, x', …, x'^D, plus optional extra
  features compiled in), so the coefficient matrix C (P, F_state) is an array;
* ψ the forcing features, evaluated once on the host (numpy) at every RK4 stage time and
  passed in as an array (n_stage, F_forcing), so new forcing features cost no compile
  (rows: :meth:`PopulationEvaluator.stage_rows`).

One fixed-step RK4 solve integrates the whole population; the same compiled function scores
every model (eqs. 7–9).

**Several coordinates** (a measurement with D responses, a system of D Newton–Euler
equations): the state is (x_1 … x_D, x_1' … x_D') for every model, so the population ×
coordinates state goes through the same scan. Equation i's state basis holds the powers of
its own x_i and x_i' and of the relative coordinates x_i − x_j and x_i' − x_j' (j ≠ i; the
couplings of eqs. 21–22), so coefficients are (P, D, F); the masses (P, D); the forcing
(P, D, F_forcing) over the shared forcing basis; the initial states (P, D, 2). With D = 1
the coordinate axis is absent from every array a caller sees, and the computation is the
one-coordinate one operation for operation. The objective sums eqs. 7–9 over the
coordinates, coordinate d's part weighted by s_1/s_d (s: the response's standard
deviation), so each is normalised by its own scale and f stays in the first response's
units. A model that blows up is marked ``DIVERGED`` and scored with a large
finite objective; it never aborts the population.

Two integrators run the same RK4 tableau on the same stage grid: ``"scan"`` (default), a
hand-written step in ``lax.scan`` over (x, x') arrays of shape (P,) with Horner-form
polynomials, and ``"diffrax"`` (:class:`RK4`, one ``diffeqsolve`` of the (P, 2) state).
They agree to rounding; the scan step has none of diffrax's per-step bookkeeping and is
~1.4× faster on CPU (``benchmarks/bench_population.py`` measures both; :mod:`gpjax._integrate`). When JAX sees more
than one device (GPUs, or host devices from
``XLA_FLAGS=--xla_force_host_platform_device_count=K`` set before JAX starts) each batch is
split over them with ``shard_map``; models never interact, so no communication is needed.
"""

from __future__ import annotations

import dataclasses
import enum
import time

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import sympy as sp

from jax.sharding import AxisType, PartitionSpec

from ._aot import Program, fingerprint
from ._canonical import Symbols
from ._coefficients import FlatLayout, Population, padded_chunks
from ._data import Measurement, between_samples
from ._evaluator_systems import SystemTerms, system_state_features
from ._features import SLOTS, Family, match
from ._integrate import RK4, enable_float64, rk4_scan
from ._objective import _amplitude, _dft_matrix, _objective_parts, default_n_bins


class Status(enum.IntEnum):
    """Per-candidate outcome of a simulation (failures are data, never raised)."""

    OK = 0
    INVALID_STRUCTURE = 1
    NONPOSITIVE_MASS = 2
    DIVERGED = 3


OK, INVALID_STRUCTURE, NONPOSITIVE_MASS, DIVERGED = Status
#: Objective given to a candidate that is invalid or diverged ("high value by definition").
PENALTY = 1e12
#: A simulated response farther than this many measured ranges from the data has diverged.
DIVERGENCE_RANGES = 100.0
INTEGRATORS = ("scan", "diffrax")
HOLD_WITH_DIFFRAX = ('the "diffrax" integrator cannot simulate "hold" inputs (it looks the '
                     'forcing up by time alone); use integrator="scan"')
#: Most (RK4 stage × model) numbers one compiled call holds per array (200 MB in float64).
STAGE_ELEMENTS_PER_CALL = 25_000_000


def polynomial_state_features(symbols: Symbols, max_degree: int) -> list[sp.Expr]:
    """x, x², …, x^D, x', …, x'^D: the fixed part of the state basis."""
    return ([symbols.x ** k for k in range(1, max_degree + 1)]
            + [symbols.x_dot ** k for k in range(1, max_degree + 1)])


def split_state_features(features, symbols: Symbols, *, families: bool = True
                         ) -> tuple[int, tuple[sp.Expr, ...], tuple[Family, ...]]:
    """(max_degree, extra features, families) of an evaluator whose basis holds
    ``features``: the highest power of x or x' among the plain powers, the families of the
    feature-bank members (:func:`gpjax._features.match`; the k-th member of a family takes
    its k-th slot, :data:`gpjax._features.SLOTS`; a member beyond them, and every member
    with ``families=False``, is an extra feature, its inner constants fixed), and every
    other feature (products with functions of time, sign(x'), …) compiled in as an extra
    feature."""
    degree, extra, found_families = 1, [], []
    powers = {symbols.x, symbols.x_dot}
    for feature in features:
        base, exponent = feature.as_base_exp()
        found = match(feature, symbols) if families else None
        free = [] if found is None else [
            dataclasses.replace(found[0], slot=k) for k in range(SLOTS.get(found[0].function, 1))
            if dataclasses.replace(found[0], slot=k) not in found_families]
        if base in powers and exponent.is_Integer and exponent > 0:
            degree = max(degree, int(exponent))
        elif free:
            found_families.append(free[0])
        else:  # a member beyond the family's slots is fixed
            extra.append(feature)
    return degree, tuple(extra), tuple(found_families)


@dataclasses.dataclass(frozen=True)
class Scores:
    """Per-candidate results of :meth:`PopulationEvaluator.score` (shape (P,); y0 (P, 2),
    for a system (P, D, 2); rms of a system: the RMS over coordinates of the weighted
    per-coordinate RMS errors)."""

    objective: np.ndarray
    f_time: np.ndarray
    f_freq: np.ndarray
    rms: np.ndarray
    status: np.ndarray
    y0: np.ndarray


class PopulationEvaluator(SystemTerms):
    """Simulates and scores populations against one measurement; compiles once.

    Args:
        measurement: the data the models are scored against; with D responses the models
            are systems of D equations (module docstring).
        symbols: names of response, time and inputs (for the feature expressions).
        max_degree: highest power of x and x' in the state basis.
        substeps: RK4 steps per sample interval.
        n_bins: spectral amplitudes m in f_freq (eq. 9); ``None`` for the 99 % energy rule.
        w_time, w_freq: weights of eq. 7.
        extra_state_features: further state features (sympy expressions in x, x' and t,
            e.g. ``sign(x_dot)`` or ``cos(1790*t)*x``) compiled in.
        families: feature families with inner constants (:mod:`gpjax._features`), one
            state column each, after the extra features; a model's θ are data
            (:attr:`Population.inner`), so new values never compile.
        batch: number of models per compiled call; populations are padded to a multiple.
            Capped so one call's (stage × model) arrays hold at most
            :data:`STAGE_ELEMENTS_PER_CALL` numbers: memory stays bounded for long records.
        fit_initial_conditions: correct every model's (x0, x0') by one Gauss–Newton step
            on the simulated response (exact sensitivities from the variational equations,
            :meth:`scan_jvp`) before scoring; otherwise the given y0 is used as is.
        integrator: ``"scan"`` or ``"diffrax"`` (see the module docstring).
        devices: devices a batch is split over; default all of ``jax.devices()``.
        input_interpolation: how inputs are reconstructed at the RK4 stage times between
            samples, ``"linear"``, ``"bandlimited"`` or ``"hold"``
            (:func:`gpjax._data.between_samples`). With ``"hold"`` the forcing rows are
            split per step (:meth:`stage_rows`), so RK4 keeps its fourth order across the
            input's jumps at the sample times.

    Raises:
        ValueError: for an unknown integrator or input interpolation, or ``"hold"`` with
            the ``"diffrax"`` integrator; extra features or families with several
            coordinates (systems have the polynomial basis of
            :func:`system_state_features`).
    """

    def __init__(self, measurement: Measurement, symbols: Symbols, *, max_degree: int = 4,
                 substeps: int = 1, n_bins: int | None = None, w_time: float = 1.0,
                 w_freq: float = 1.0, extra_state_features: tuple[sp.Expr, ...] = (),
                 families: tuple[Family, ...] = (), batch: int = 500, fit_initial_conditions: bool = False,
                 integrator: str = "scan", devices: list | None = None,
                 input_interpolation: str = "linear"):
        if integrator not in INTEGRATORS:
            raise ValueError(f"integrator must be one of {INTEGRATORS}, got {integrator!r}")
        if integrator == "diffrax" and input_interpolation == "hold":
            raise ValueError(HOLD_WITH_DIFFRAX)
        self.n_coordinates = measurement.n_coordinates
        if self.n_coordinates > 1 and (extra_state_features or families):
            raise ValueError("a system of several coordinates has the polynomial basis only; "
                             "give no extra_state_features or families")
        enable_float64()
        self.measurement = measurement
        self.symbols = symbols
        self.families = tuple(families)
        self._family_column = {}
        self._inner_slots = []
        fixed = (polynomial_state_features(symbols, max_degree) + list(extra_state_features)
                 if self.n_coordinates == 1 else
                 system_state_features(measurement.response_names, max_degree)[0])
        for j, family in enumerate(self.families):
            self._family_column[family] = len(fixed) + j
            start = self._inner_slots[-1].stop if self._inner_slots else 0
            self._inner_slots.append(slice(start, start + family.n_inner))
        self.n_inner = self._inner_slots[-1].stop if self._inner_slots else 0
        self.state_features = fixed + [family.feature(symbols, (1.0, 0.0)[:family.n_inner])
                                       for family in self.families]
        self._state_index = {f: i for i, f in enumerate(fixed)}
        #: Per equation, its state features in column order (D = 1: :attr:`state_features`).
        self.equation_features = ((self.state_features,) if self.n_coordinates == 1 else
                                  system_state_features(measurement.response_names, max_degree))
        self._equation_index = [{f: i for i, f in enumerate(features)}
                                for features in self.equation_features]
        self.max_degree = max_degree
        self.substeps = substeps
        self.integrator = integrator
        self.input_interpolation = input_interpolation
        #: Whether every RK4 step has its own three forcing rows (see :meth:`stage_rows`).
        self.split_stages = input_interpolation == "hold"
        self.devices = list(devices) if devices is not None else jax.devices()
        n_stage = self.stage_rows(measurement.n_samples)
        batch = max(1, min(batch, STAGE_ELEMENTS_PER_CALL // n_stage))
        self.batch = -(-batch // len(self.devices)) * len(self.devices)
        self.fit_initial_conditions = fit_initial_conditions
        self.w_time, self.w_freq = float(w_time), float(w_freq)
        n = measurement.n_samples
        self.h = measurement.dt / substeps
        self.n_steps = (n - 1) * substeps
        if self.split_stages:
            steps = np.arange(self.n_steps)[:, None] + np.array([0.0, 0.5, 1.0])
            self.stage_times = measurement.time[0] + self.h * steps.ravel()
        else:
            self.stage_times = measurement.time[0] + 0.5 * self.h * np.arange(2 * self.n_steps + 1)
        self.stage_times[-1] = measurement.time[-1]
        self._stage_inputs = {name: self._at_stages(values)
                              for name, values in measurement.inputs.items()}
        self.n_bins = n_bins if n_bins is not None else max(map(default_n_bins,
                                                                measurement.responses.T))
        self.n_bins = min(self.n_bins, n // 2 + 1)
        self._forcing_features: list[sp.Expr] = []
        self._forcing_columns: list[np.ndarray] = []
        self._forcing_index: dict[sp.Expr, int] = {}
        self._finite: dict[sp.Expr, bool] = {}  # forcing_finite's verdicts
        self._forcing_basis = np.zeros((self.stage_times.size, 0))
        self.compile_seconds = 0.0
        self._extra_fns = [sp.lambdify((symbols.x, symbols.x_dot, symbols.t), f, modules="jax")
                           for f in extra_state_features]
        responses = measurement.responses
        span = (np.ptp(responses, axis=0) + np.max(np.abs(responses), axis=0))[:, None]
        self._bound = (DIVERGENCE_RANGES * span, DIVERGENCE_RANGES * span / measurement.dt)
        #: Per coordinate, (largest |x|, largest |x'|) a simulation is clipped to.
        self._bounds = [(float(bx), float(bv)) for bx, bv in zip(*(b[:, 0] for b in self._bound))]
        if self.n_coordinates == 1:  # numbers: the one-coordinate program exactly as before
            self._bound = self._bounds[0]
        #: Coordinate d's weight in the objective, s_1/s_d (see the module docstring).
        self.weights = np.std(responses[:, :1]) / np.std(responses, axis=0)
        self._dft = _dft_matrix(n, self.n_bins)
        self._measured_amplitude = _amplitude(self._dft, responses, self.n_bins)
        run = self._simulate_and_score
        if len(self.devices) > 1:
            mesh = jax.make_mesh((len(self.devices),), ("population",),
                                 axis_types=(AxisType.Auto,), devices=self.devices)
            split = PartitionSpec("population")
            run = jax.shard_map(run, mesh=mesh, in_specs=(split,) * 5 + (PartitionSpec(),),
                                out_specs=split, check_vma=False)
        #: Fingerprint of everything the compiled programs close over: the arguments.
        self.key = fingerprint(measurement.fingerprint(), symbols, self.state_features,
                               self.families, max_degree, substeps, self.n_bins, w_time, w_freq,
                               self.batch, fit_initial_conditions, integrator, input_interpolation,
                               [str(d) for d in self.devices])
        self._run = Program(run, name="population", key=self.key)
        self._compiled: set[tuple] = set()

    def stage_rows(self, samples: int) -> int:
        """Forcing rows that the first ``samples`` samples need (the rows of
        :attr:`stage_times` and of every forcing matrix).

        Shared layout, 2·(samples − 1)·substeps + 1 rows: t0, t0 + h/2, t0 + h, … with a
        step's end row the next step's start. Split layout (``"hold"``),
        3·(samples − 1)·substeps rows: every step's start, middle and end, the end row
        holding the input's left limit, since a held input jumps at every sample time.
        """
        steps = (samples - 1) * self.substeps
        return 3 * steps if self.split_stages else 2 * steps + 1

    def _at_stages(self, values: np.ndarray) -> np.ndarray:
        """An input's samples (N,) reconstructed at every forcing row (:meth:`stage_rows`)."""
        if self.split_stages:  # every stage of a step sees the value held over that step
            return np.repeat(between_samples(values, self.substeps, "hold")[:-1], 3)
        return between_samples(values, 2 * self.substeps, self.input_interpolation)

    # --- feature bookkeeping ----------------------------------------------------------
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
        return self._equation_index[equation].get(feature)

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
            self._forcing_index[feature] = len(self._forcing_features)
            self._forcing_features.append(feature)
            self._forcing_columns.append(values)
            capacity = _capacity(len(self._forcing_features))
            basis = np.zeros((self.stage_times.size, capacity))
            basis[:, :len(self._forcing_columns)] = np.stack(self._forcing_columns, axis=1)
            self._forcing_basis = basis
        return self._forcing_index[feature]

    @property
    def compile_count(self) -> int:
        """Shapes compiled so far (one per forcing capacity used; :attr:`compile_seconds`)."""
        return len(self._compiled)

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

    def narrowed(self, population: Population) -> Population:
        """``population`` on :attr:`plain_layout` (its family columns dropped)."""
        return Population(population.mass, population.state[..., :self.plain_layout.n_state],
                          population.forcing, population.y0, population.inner[:, :0])

    def _layout_of(self, width: int) -> FlatLayout:
        return self.layout if width == self.layout.width else self.plain_layout

    def forcing_values(self, feature: sp.Expr, times: np.ndarray,
                       inputs: dict[str, np.ndarray]) -> np.ndarray:
        """A forcing feature ψ(t, u) evaluated (numpy) at ``times`` with ``inputs``."""
        args = (self.symbols.t, *self.symbols.u)
        fn = sp.lambdify(args, feature, modules="numpy")
        values = fn(times, *(inputs[name] for name in self.symbols.inputs))
        return np.broadcast_to(np.asarray(values, dtype=np.float64), times.shape).copy()

    # --- evaluation ---------------------------------------------------------------------
    def empty(self, count: int) -> Population:
        """A population of ``count`` placeholder models (m = 1, no terms, y0 = 0)."""
        rows = (count,) if self.n_coordinates == 1 else (count, self.n_coordinates)
        return Population(mass=np.ones(rows), state=np.zeros(rows + (len(self.state_features),)),
                          forcing=np.zeros(rows + (self.forcing_capacity,)),
                          y0=np.zeros(rows + (2,)), inner=np.zeros((count, self.n_inner)))

    def score(self, population: Population) -> Scores:
        """Objective (eq. 7), its parts (eqs. 8–9), RMS and status for every model."""
        return self._batched(population, responses=False)[0]

    def simulate(self, population: Population) -> tuple[np.ndarray, Scores]:
        """Simulated responses (P, N) ((P, D, N) for a system) at the sample times, and the
        scores."""
        scores, responses = self._batched(population, responses=True)
        return responses, scores

    def _batched(self, population: Population, *, responses: bool):
        """Scores (and responses) of ``population`` in padded batches, models that use no
        family apart on :attr:`plain_layout` (one more compile;
        ``benchmarks/bench_feature_bank.py``)."""
        count = len(population)
        if count == 0:
            empty = np.zeros(0)
            return (Scores(empty, empty, empty, empty, empty.astype(int),
                           self.empty(0).y0), np.zeros((0, 0)))
        plain = self.plain_rows(population)
        parts, paths, order = [], [], []
        for rows in (np.flatnonzero(plain), np.flatnonzero(~plain)):
            if not rows.size:
                continue
            part = population.rows(rows)
            part = self.narrowed(part) if plain[rows[0]] else part
            forcing = _pad_columns(part.forcing, self.forcing_capacity)
            for size, chunk in padded_chunks((part.mass, part.state, forcing, part.y0,
                                              part.inner), self.batch):
                out = self._call(*chunk)
                parts.append([np.asarray(o)[:size] for o in out[:6]])
                if responses:
                    paths.append(np.asarray(out[6])[:size])
            order.append(rows)
        back = np.argsort(np.concatenate(order))
        stacked = [np.concatenate(p)[back] for p in zip(*parts)]
        scores = Scores(objective=stacked[0], f_time=stacked[1], f_freq=stacked[2],
                        rms=stacked[3], status=stacked[4].astype(int), y0=stacked[5])
        return scores, (np.concatenate(paths)[back] if responses else None)

    def _call(self, mass, state, forcing, y0, inner):
        key = (self.forcing_capacity, state.shape[-1])
        start = time.perf_counter()
        out = jax.block_until_ready(self._run(
            *map(jnp.asarray, (mass, state, forcing, y0, inner, self._forcing_basis))))
        if key not in self._compiled:  # the first call of a shape includes its compile
            self._compiled.add(key)
            self.compile_seconds += time.perf_counter() - start
        return out

    # --- the compiled computation: arrays carry a coordinate axis (length D) ---------------
    def _coordinates(self, array, axis: int):
        """``array`` with the coordinate axis at ``axis`` (inserted when D = 1)."""
        return jnp.expand_dims(array, axis) if self.n_coordinates == 1 else array

    def _public(self, array, axis: int):
        """``array`` without the coordinate axis at ``axis`` when D = 1."""
        return jnp.squeeze(array, axis) if self.n_coordinates == 1 else array

    def _internal(self, mass, state, forcing_matrix, y0):
        """Caller arrays with the coordinate axis: mass (D, P), state (P, D, F), forcing
        rows (n_stage, D, P), y0 (P, D, 2)."""
        return (jnp.swapaxes(self._coordinates(mass, -1), -1, -2), self._coordinates(state, -2),
                self._coordinates(forcing_matrix, -2), self._coordinates(y0, -2))

    def _acceleration_fn(self, mass, state, inner):
        """x''(x, v, force, t) for all models, states clipped; ``mass`` (D, P), ``state``
        (P, D, F). One coordinate: x, x' and the force as one-element sequences of (P,)
        arrays, the acceleration returned likewise (the scan carries no stacked state: faster
        for D = 1). D > 1: (D, P) arrays in and out (one stacked Horner sum).

        The one right-hand side both integrators use (:meth:`_restoring_fn`).
        """
        inverse_mass = 1.0 / mass
        rows = self._restoring_fn(state, inner, stacked=False)
        if self.n_coordinates > 1:  # (D, P) arrays in and out
            def clipped(z, which):  # row by row: faster than one broadcast clip in scan_jvp
                return [jnp.clip(z[e], -b[which], b[which]) for e, b in enumerate(self._bounds)]

            def system_acceleration(xs, vs, forces, t):
                r = rows(clipped(xs, 0), clipped(vs, 1), t)
                return jnp.stack([(forces[e] - r_e) * inverse_mass[e] for e, r_e in enumerate(r)])

            return system_acceleration
        (bx, bv), = self._bounds

        def acceleration(xs, vs, forces, t):
            (r,) = rows([jnp.clip(xs[0], -bx, bx)], [jnp.clip(vs[0], -bv, bv)], t)
            return [(forces[0] - r) * inverse_mass[0]]

        return acceleration

    def _restoring_fn(self, state, inner, *, stacked: bool = True):
        """Σ c·φ per equation for coefficients ``state`` of shape (..., P, D, F) and the
        families' inner constants ``inner`` (P, F_inner): Horner sums over the powers of each
        equation's variables (:func:`system_state_features`), plus, for D = 1, the compiled
        extra features and families. The function takes the positions and velocities as
        (D, P) arrays or sequences of D (P,) arrays and returns (..., D, P) (``stacked``
        False: a list of D (..., P) arrays). A family no model of the call uses is skipped
        (``lax.cond`` on a loop-invariant flag)."""
        if self.n_coordinates > 1:
            return self._system_restoring(state, stacked=stacked)
        d = self.max_degree
        position, velocity = (jnp.moveaxis(state[..., 0, k * d:(k + 1) * d], -1, 0)
                              for k in (0, 1))
        n_poly, n_extra = 2 * d, len(self._extra_fns)
        extra = jnp.moveaxis(state[..., 0, n_poly:n_poly + n_extra], -1, 0)
        bank = jnp.moveaxis(state[..., 0, n_poly + n_extra:], -1, 0)
        used = [jnp.any(c != 0) for c in bank]

        def horner(c, z):
            total = c[d - 1]
            for k in range(d - 2, -1, -1):
                total = total * z + c[k]
            return total * z

        def restoring(xs, vs, t):
            x, v = xs[0], vs[0]
            total = horner(position, x) + horner(velocity, v)
            for c, fn in zip(extra, self._extra_fns):
                total = total + c * fn(x, v, t)
            for c, flag, family, slots in zip(bank, used, self.families, self._inner_slots):
                z = x if family.role == "x" else v
                term = jax.lax.cond(flag, lambda z=z, c=c, family=family, slots=slots:
                                    c * family(z, inner[..., slots]),
                                    lambda c=c: jnp.zeros(jnp.broadcast_shapes(c.shape, x.shape)))
                total = total + term
            return [total]

        if stacked:
            return lambda xs, vs, t: jnp.stack(restoring(xs, vs, t), axis=-2)
        return restoring

    def integrate(self, mass, state, forcing_matrix, y0, inner=None):
        """x at the sample times, shape (N, P) ((N, D, P) for D > 1), by the configured
        integrator.

        Differentiable in forward and reverse mode (the diffrax path in forward mode).
        """
        if self.integrator == "diffrax":
            return self.solve(mass, state, forcing_matrix, y0, inner,
                              adjoint=diffrax.ForwardMode())
        return self.scan_solve(mass, state, forcing_matrix, y0, inner)

    def scan_solve(self, mass, state, forcing_matrix, y0, inner=None):
        """Integrate all models with RK4 in ``lax.scan``; x at the sample times, (N, P)
        ((N, D, P) for D > 1).

        Args:
            mass: (P,); state: (P, F_state) coefficients; y0: (P, 2) — for D > 1 with a
                coordinate axis after P: (P, D), (P, D, F_state), (P, D, 2).
            forcing_matrix: (n_stage, P) ((n_stage, D, P)) forcing of every model (and
                equation) at every RK4 stage time.
            inner: (P, F_inner) the families' inner constants (``None``: no families).
        """
        inner = _no_inner(inner, mass)
        rows = forcing_matrix  # (n_stage, P) or (n_stage, D, P): scanned as given
        mass, state, forcing_matrix, y0 = self._internal(mass, state, forcing_matrix, y0)
        acceleration = self._acceleration_fn(mass, state, inner)
        if self.n_coordinates > 1:  # one carried (2, D, P) array
            def stacked_rates(y, force, t):
                (y,) = y
                return (jnp.stack([y[1], acceleration(y[0], y[1], force, t)]),)

            (path,) = self._rk4_scan(stacked_rates, (jnp.transpose(y0, (2, 1, 0)),), rows,
                                     lambda y: (y[0][0],))
            return path

        def rates(y, force, t):  # x and x' carried as two (P,) arrays
            (x, v) = y
            return (v, *acceleration([x], [v], [force], t))

        (path,) = self._rk4_scan(rates, (y0[:, 0, 0], y0[:, 0, 1]), rows, lambda y: y[:1])
        return path

    def scan_jvp(self, mass, state, forcing_matrix, y0, d_y0, *, inner=None, d_mass=None,
                 d_state=None, d_forcing=None, d_inner=None, fold=None):
        """x at the sample times (N, P) and its derivatives (N, Q, P) along Q directions
        (D > 1: (N, D, P) and (N, D, Q, P)).

        The variational equations s' = w, w' = ∂a/∂x·s + ∂a/∂x'·w + ∂a/∂θ·dθ run in the same
        RK4 scan as the model (∂a/∂x a D × D matrix per model, one forward derivative per
        coordinate). RK4 commutes with linearisation, so this is the exact derivative of the
        discrete solution — what forward-mode autodiff of :meth:`scan_solve` gives
        (tested) — without differentiating through the scan.

        Args:
            mass, state, forcing_matrix, y0: as :meth:`scan_solve`.
            d_y0: (Q, P, 2) ((Q, P, D, 2)) directions of the initial state.
            inner: (P, F_inner) the families' inner constants (``None``: no families).
            d_mass: (Q, P), d_state: (Q, P, F_state), d_forcing: (n_stage, Q, P),
                d_inner: (Q, P, F_inner) directions of the constants (``None``: zero); for
                D > 1 with a coordinate axis before F (after P for d_mass, before P for
                d_forcing). Directions come first so the population axis stays the minor
                one that XLA vectorises.
            fold: ``(fn, acc)``: return only ``acc`` folded over the samples by
                ``fn(acc, y, k)`` at step k, y the carried (2, 1 + Q, D, P) array
                [[x, s], [x', w]], from ``fn(acc, start, 0)``; nothing is saved.
        """
        inner = _no_inner(inner, mass)
        mass, state, forcing_matrix, y0 = self._internal(mass, state, forcing_matrix, y0)
        d_y0 = self._coordinates(d_y0, -2)
        if d_mass is not None:
            d_mass = jnp.swapaxes(self._coordinates(d_mass, -1), -1, -2)
        if d_state is not None:
            d_state = self._coordinates(d_state, -2)
        d_forcing = (jnp.zeros((forcing_matrix.shape[0], 1, 1, 1)) if d_forcing is None
                     else self._coordinates(d_forcing, -2))
        acceleration = self._acceleration_fn(mass, state, inner)
        restoring = self._restoring_fn(state, inner)
        d_restoring = self._restoring_fn(d_state, inner) if d_state is not None else None
        inverse_mass = 1.0 / mass
        count = self.n_coordinates
        system_partials = self._system_partials(state) if count > 1 else None

        def partials(xs, vs, t, which):
            """∂r/∂x_j (which 0) or ∂r/∂x_j' (1), (D, P) each, for every coordinate j."""
            ones = jnp.ones_like(xs[0])
            out = []
            for j in range(count):
                def moved(z, j=j):
                    states = [list(xs), list(vs)]
                    states[which][j] = z
                    return restoring(*states, t)
                out.append(jax.jvp(moved, ((xs, vs)[which][j],), (ones,))[1])
            return out

        def rates(y, force, t):
            (y,) = y
            x, v, s, w = y[0, 0], y[1, 0], y[0, 1:], y[1, 1:]
            f, df = force
            a = acceleration(x, v, f, t) if count > 1 else jnp.stack(acceleration(x, v, f, t))
            xs, vs = [x[e] for e in range(count)], [v[e] for e in range(count)]
            r_x, r_v = (system_partials(xs, vs) if count > 1 else
                        (partials(xs, vs, t, 0), partials(xs, vs, t, 1)))
            explicit = df
            if d_restoring is not None:
                explicit = explicit - d_restoring(x, v, t)
            if d_inner is not None and self.families:
                explicit = explicit - jax.vmap(lambda d: jax.jvp(
                    lambda th: restoring_at(th, x, v, t), (inner,), (d,))[1])(d_inner)
            if d_mass is not None:
                explicit = explicit - a * d_mass
            for j, r in enumerate(r_x):
                explicit = explicit - r * s[:, j:j + 1]
            for j, r in enumerate(r_v):
                explicit = explicit - r * w[:, j:j + 1]
            dw = explicit * inverse_mass
            return (jnp.stack([jnp.concatenate([v[None], w]),
                               jnp.concatenate([a[None], jnp.broadcast_to(dw, s.shape)])]),)

        def restoring_at(theta, x, v, t):
            return self._restoring_fn(state, theta)(x, v, t)

        # One carried array [[x, s], [x', w]], (2, 1 + Q, D, P): fewer loops and copies per
        # step than four separate states (the initial-condition step runs ~2× faster).
        start = jnp.concatenate([jnp.transpose(y0, (2, 1, 0))[:, None],
                                 jnp.swapaxes(jnp.moveaxis(d_y0, -1, 0), -1, -2)], axis=1)
        if fold is not None:
            _, acc = self._rk4_scan(rates, (start,), (forcing_matrix, d_forcing), lambda y: (),
                                    fold=(lambda a, y, k: fold[0](a, y[0], k),
                                          fold[0](fold[1], start, 0)))
            return acc
        (path,) = self._rk4_scan(rates, (start,), (forcing_matrix, d_forcing),
                                 lambda y: (y[0][0],))
        if count == 1:
            return path[:, 0, 0], path[:, 1:, 0]
        return path[:, 0], jnp.swapaxes(path[:, 1:], 1, 2)

    def unpack(self, constants, forcing_basis):
        """Flat constant vectors (:attr:`layout`), one model's (W,) or a population's
        (P, W), as :meth:`scan_solve` arguments (a population of one for one vector):
        mass (P,), state (P, F_state), forcing (n_stage, P) from the rows of
        ``forcing_basis`` (which set n_stage), y0 (P, 2), inner (P, F_inner) (for D > 1
        with the coordinate axis, :meth:`scan_solve`)."""
        mass, state, forcing, inner, y0 = self._layout_of(constants.shape[-1]).split(
            jnp.atleast_2d(constants))
        return mass, state, _forcing_rows(forcing_basis, forcing), y0, inner

    def constant_jacobian(self, constants, directions, forcing_basis):
        """x at the sample times and its derivatives along ``directions`` of the flat
        constant vector, by :meth:`scan_jvp`: one model's constants (W,) and directions
        (Q, W) give (N,) and (N, Q); a population's (P, W) and (P, Q, W) give (N, P) and
        (N, Q, P) (:meth:`unpack`); for D > 1 a coordinate axis follows N."""
        single = constants.ndim == 1
        directions = jnp.swapaxes(directions[None] if single else directions, 0, 1)
        d_mass, d_state, d_forcing, d_inner, d_y0 = self._layout_of(
            constants.shape[-1]).split(directions)
        mass, state, forcing_matrix, y0, inner = self.unpack(constants, forcing_basis)
        rows = ("qpk,sk->sqp" if self.n_coordinates == 1 else "qpdk,sk->sqdp")
        x, dx = self.scan_jvp(mass, state, forcing_matrix, y0, d_y0, inner=inner,
                              d_mass=d_mass, d_state=d_state, d_inner=d_inner,
                              d_forcing=jnp.einsum(rows, d_forcing, forcing_basis))
        return (x[..., 0], dx[..., 0]) if single else (x, dx)

    def _rk4_scan(self, rates, y0, forces, saved, fold=None):
        """:func:`gpjax._integrate.rk4_scan` on this evaluator's stage grid."""
        return rk4_scan(rates, y0, forces, saved, h=self.h, t0=float(self.stage_times[0]),
                        substeps=self.substeps, split_stages=self.split_stages, fold=fold)

    def solve(self, mass, state, forcing_matrix, y0, inner=None, *, adjoint=None):
        """Integrate all models with diffrax; returns x at the sample times, shape (N, P)
        ((N, D, P) for D > 1).

        ``adjoint=diffrax.ForwardMode()`` makes the solve forward-differentiable (for
        Levenberg–Marquardt); the default suits plain evaluation.

        Raises:
            ValueError: for ``"hold"`` inputs: the vector field looks the forcing up by time
                alone, which cannot tell a step's end (the input's left limit) from the next
                step's start; use the ``"scan"`` integrator.
        """
        if self.split_stages:
            raise ValueError(HOLD_WITH_DIFFRAX)
        t0 = float(self.stage_times[0])
        half = 0.5 * self.h
        inner = _no_inner(inner, mass)
        mass, state, forcing_matrix, y0 = self._internal(mass, state, forcing_matrix, y0)
        acceleration = self._acceleration_fn(mass, state, inner)

        def field(t, y, args):  # y: (2, D, P)
            index = jnp.clip(jnp.round((t - t0) / half).astype(jnp.int32), 0,
                             forcing_matrix.shape[0] - 1)
            velocity = jnp.clip(y[1], -self._bound[1], self._bound[1])
            return jnp.stack([velocity, jnp.stack(acceleration(y[0], y[1],
                                                               forcing_matrix[index], t))])

        solution = diffrax.diffeqsolve(
            diffrax.ODETerm(field), RK4(), t0=t0, t1=float(self.stage_times[-1]), dt0=self.h,
            y0=jnp.transpose(y0, (2, 1, 0)), saveat=diffrax.SaveAt(t0=True, steps=True),
            stepsize_controller=diffrax.ConstantStepSize(), max_steps=self.n_steps,
            throw=False, adjoint=adjoint or diffrax.RecursiveCheckpointAdjoint())
        states = solution.ys[:: self.substeps, 0]
        return self._public(states[: self.measurement.n_samples], 1)

    def _simulate_and_score(self, mass, state, forcing, y0, inner, forcing_basis):
        forcing_matrix = _forcing_rows(forcing_basis, forcing)  # (n_stage, [D,] P)
        if self.fit_initial_conditions:
            y0 = self._fitted_initial_conditions(mass, state, forcing_matrix, y0, inner)
        if self.integrator == "diffrax":
            x = self.solve(mass, state, forcing_matrix, y0, inner)  # (N, [D,] P)
        else:
            x = self.scan_solve(mass, state, forcing_matrix, y0, inner)
        paths = jnp.transpose(x)  # (P, [D,] N)
        x = self._coordinates(x, 1)
        finite = jnp.all(jnp.isfinite(x), axis=(0, 1))
        bounded = jnp.all(jnp.abs(x) < self._bound[0], axis=(0, 1))
        positive = jnp.all(self._coordinates(mass, -1) > 0, axis=-1)
        status = jnp.where(positive, jnp.where(finite & bounded, OK, DIVERGED), NONPOSITIVE_MASS)
        x = jnp.where(jnp.isfinite(x), x, 0.0)
        measured = jnp.asarray(self.measurement.responses)
        f_time, f_freq, rms = _objective_parts(  # (D, P) each
            measured[:, :, None], x, jnp.asarray(self._dft),
            jnp.asarray(self._measured_amplitude)[:, :, None], self.n_bins)
        if self.n_coordinates == 1:
            f_time, f_freq, rms = f_time[0], f_freq[0], rms[0]
        else:
            weights = jnp.asarray(self.weights)[:, None]
            f_time, f_freq = jnp.sum(weights * f_time, 0), jnp.sum(weights * f_freq, 0)
            rms = jnp.sqrt(jnp.mean((weights * rms) ** 2, 0))
        objective = self.w_time * f_time + self.w_freq * f_freq
        good = status == OK
        out = (jnp.where(good, objective, PENALTY), jnp.where(good, f_time, PENALTY),
               jnp.where(good, f_freq, PENALTY), jnp.where(good, rms, PENALTY), status, y0)
        return out + (paths,)


def _forcing_rows(forcing_basis, forcing):
    """Forcing of every model at every stage row: (n_stage, P) from coefficients (P, K),
    (n_stage, D, P) from a system's (P, D, K)."""
    if forcing.ndim == 2:
        return forcing_basis @ forcing.T
    return jnp.einsum("sk,pdk->sdp", forcing_basis, forcing)


def _no_inner(inner, mass):
    """``inner``, or an empty (P, 0) array for an evaluator call without families."""
    return jnp.zeros((mass.shape[0], 0)) if inner is None else inner


def _capacity(count: int) -> int:
    capacity = 16
    while capacity < count:
        capacity *= 2
    return capacity


def _pad_columns(array: np.ndarray, columns: int) -> np.ndarray:
    """``array`` zero-padded to ``columns`` along its last axis."""
    if array.shape[-1] == columns:
        return array
    out = np.zeros(array.shape[:-1] + (columns,))
    out[..., : array.shape[-1]] = array
    return out
