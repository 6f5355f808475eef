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
couplings of eqs. 21–22), then the system bank's kinds of them (:mod:`gpjax._system_bank`),
so coefficients are (P, D, F); the masses (P, D); the forcing
(P, D, F_forcing) over the shared forcing basis; the initial states (P, D, 2). With D = 1
the coordinate axis is absent from every array a caller sees, and the computation is the
one-coordinate one operation for operation. The objective sums eqs. 7–9 over the
coordinates, coordinate d's part weighted by s_1/s_d (s: the response's standard
deviation), so each is normalised by its own scale and f stays in the first response's
units. A model that blows up is marked ``DIVERGED`` and scored with a large
finite objective; it never aborts the population.

Two integrators run the same RK4 tableau on the same stage grid (``"scan"``, the default,
and ``"diffrax"``; :mod:`gpjax._evaluator_dynamics`, which holds the compiled right-hand
side, both integrators and the variational equations). When JAX sees more
than one device (GPUs, or host devices from
``XLA_FLAGS=--xla_force_host_platform_device_count=K`` set before JAX starts) each batch is
split over them with ``shard_map``; models never interact, so no communication is needed.
"""

from __future__ import annotations

import dataclasses
import enum

import jax
import jax.numpy as jnp
import numpy as np
import sympy as sp

from jax.sharding import AxisType, PartitionSpec

from ._aot import CompileFigures, Program, fingerprint
from ._canonical import Symbols, numbers_lifted
from ._coefficients import Population, padded_chunks
from ._data import Measurement, between_samples
from ._evaluator_columns import Columns, first_forcing_capacity
from ._evaluator_dynamics import HOLD_WITH_DIFFRAX, Dynamics, _forcing_rows
from ._evaluator_systems import SystemTerms, system_state_features
from ._features import SLOTS, Family, match
from ._integrate import enable_float64
from ._objective import _amplitude, _dft_matrix, _objective_parts, default_n_bins
from ._record import RecordArrays, RecordContext, padded_bins, padded_length, padded_rows


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
#: Most (RK4 stage × model) numbers one compiled call holds per array (200 MB in float64).
STAGE_ELEMENTS_PER_CALL = 25_000_000
#: Batch sizes compiled besides the population's, for calls of a few models (a front's
#: refits, the selection's neighbours): padded to the population, a call of one model cost
#: as much as 500 (1.3–3.8 s on 8,000 samples with the wide function set).
SMALL_BATCHES = (16, 128)


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


class PopulationEvaluator(Columns, Dynamics, SystemTerms, RecordContext, CompileFigures):
    """Simulates and scores populations against one measurement; compiles once per length
    bucket and settings (the record enters the programs as :attr:`record_arrays`,
    :mod:`gpjax._record`).

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
        devices: devices a batch is split over; default all of ``jax.devices()``, at most
            one per model of the largest batch the memory cap allows (:attr:`devices`).
        input_interpolation: how inputs are reconstructed at the RK4 stage times between
            samples, ``"linear"``, ``"bandlimited"`` or ``"hold"``
            (:func:`gpjax._data.between_samples`). With ``"hold"`` the forcing rows are
            split per step (:meth:`stage_rows`), so RK4 keeps its fourth order across the
            input's jumps at the sample times.
        pad_to_bucket: integrate the record padded to its length bucket, so its programs
            serve every record of the bucket (:mod:`gpjax._record`; the results are the
            same); ``False`` compiles for this length alone.
        kinds: several coordinates: the system bank's kinds (:mod:`gpjax._system_bank`),
            one column per kind and equation variable after the powers
            (:func:`system_state_features`).
        sign_scales: (2D²,) θ of the smoothed signs tanh(θ·z) of every equation variable
            (a program argument: new values never compile); default 1.
        forcing_capacity: forcing columns of the basis before it first doubles; default
            the search's (:func:`gpjax._evaluator_columns.first_forcing_capacity`: room for
            the features a search registers). A model's own evaluator knows its features:
            :meth:`gpjax.Model.evaluator` asks for no more than they need, as the basis is
            (stage rows × capacity) numbers, 250 MB at 16 columns on a 65,000-sample record
            at 20 steps per sample.

    Raises:
        ValueError: for an unknown integrator or input interpolation, or ``"hold"`` with
            the ``"diffrax"`` integrator; extra features or families with several
            coordinates (systems take ``kinds``), or ``kinds`` with one.
    """

    def __init__(self, measurement: Measurement, symbols: Symbols, *, max_degree: int = 4,
                 substeps: int = 1, n_bins: int | None = None, w_time: float = 1.0,
                 w_freq: float = 1.0, extra_state_features: tuple[sp.Expr, ...] = (),
                 families: tuple[Family, ...] = (), batch: int = 500, fit_initial_conditions: bool = False,
                 integrator: str = "scan", devices: list | None = None,
                 input_interpolation: str = "linear", pad_to_bucket: bool = True,
                 kinds: tuple[str, ...] = (), sign_scales=None,
                 forcing_capacity: int | None = None):
        if integrator not in INTEGRATORS:
            raise ValueError(f"integrator must be one of {INTEGRATORS}, got {integrator!r}")
        if integrator == "diffrax" and input_interpolation == "hold":
            raise ValueError(HOLD_WITH_DIFFRAX)
        self.n_coordinates = measurement.n_coordinates
        if self.n_coordinates > 1 and (extra_state_features or families):
            raise ValueError("a system of several coordinates has its own bank (kinds); "
                             "give no extra_state_features or families")
        if self.n_coordinates == 1 and kinds:
            raise ValueError("kinds are a system's bank; one coordinate takes families")
        names = measurement.response_names
        #: The system bank's kinds (:mod:`gpjax._system_bank`) and their sign scales θ.
        self.kinds = tuple(kinds)
        self.sign_scales = (np.ones(2 * len(names) ** 2) if sign_scales is None
                            else np.asarray(sign_scales, dtype=np.float64))
        enable_float64()
        self.measurement = measurement
        self.symbols = symbols
        self.families = tuple(families)
        self._family_column = {}
        self._inner_slots = []
        fixed = (polynomial_state_features(symbols, max_degree) + list(extra_state_features)
                 if self.n_coordinates == 1 else
                 system_state_features(names, max_degree, self.kinds, self.sign_scales)[0])
        for j, family in enumerate(self.families):
            self._family_column[family] = len(fixed) + j
            start = self._inner_slots[-1].stop if self._inner_slots else 0
            self._inner_slots.append(slice(start, start + family.n_inner))
        self.n_inner = self._inner_slots[-1].stop if self._inner_slots else 0
        self.state_features = fixed + [family.feature(symbols, family.unit)
                                       for family in self.families]
        self._state_index = {f: i for i, f in enumerate(fixed)}
        #: Per equation, its state features in column order (D = 1: :attr:`state_features`).
        self.equation_features = ((self.state_features,) if self.n_coordinates == 1 else
                                  system_state_features(names, max_degree, self.kinds,
                                                        self.sign_scales))
        self._equation_index = [{f: i for i, f in enumerate(features)}
                                for features in self.equation_features]
        self.max_degree = max_degree
        self.substeps = substeps
        self.integrator = integrator
        self.input_interpolation = input_interpolation
        #: Whether every RK4 step has its own three forcing rows (see :meth:`stage_rows`).
        self.split_stages = input_interpolation == "hold"
        self.devices = list(devices) if devices is not None else jax.devices()
        n = measurement.n_samples
        self.n_bins = n_bins if n_bins is not None else max(map(default_n_bins,
                                                                measurement.responses.T))
        self.n_bins = min(self.n_bins, n // 2 + 1)
        dft = _dft_matrix(n, self.n_bins)
        #: Samples the programs integrate: the record padded to its length bucket, or
        #: unpadded where the spectrum is an rfft (:mod:`gpjax._record`).
        self.n_padded = padded_length(n) if pad_to_bucket and dft.shape[0] > 1 else n
        #: DFT bins the programs hold (the record's :attr:`n_bins`, zero-padded).
        self.n_bins_padded = min(padded_bins(self.n_bins, self.n_padded),
                                 self.n_padded // 2 + 1)
        n_stage = self.stage_rows(self.n_padded)
        cap = max(1, STAGE_ELEMENTS_PER_CALL // n_stage)
        batch = max(1, min(batch, cap))
        # A call splits over no more devices than it has models, and rounding the batch up
        # to a multiple of them never passes the memory cap (a long record on many host
        # devices would otherwise hold a model per device, 16× the cap's numbers).
        self.devices = self.devices[:batch]
        count = len(self.devices)
        self.batch = min(-(-batch // count), cap // count) * count
        #: The batch sizes compiled (each on first use): :data:`SMALL_BATCHES` below
        #: :attr:`batch`, and it; a call of a few models runs at a small size.
        self.batch_sizes = tuple(sorted({-(-b // len(self.devices)) * len(self.devices)
                                         for b in SMALL_BATCHES if b < self.batch}
                                        | {self.batch}))
        self.fit_initial_conditions = fit_initial_conditions
        self.w_time, self.w_freq = float(w_time), float(w_freq)
        self.h = measurement.dt / substeps
        self.n_steps = (self.n_padded - 1) * substeps
        if self.split_stages:
            steps = np.arange(self.n_steps)[:, None] + np.array([0.0, 0.5, 1.0])
            self.stage_times = measurement.time[0] + self.h * steps.ravel()
        else:
            self.stage_times = measurement.time[0] + 0.5 * self.h * np.arange(2 * self.n_steps + 1)
        self.stage_times[self.stage_rows(n) - 1] = measurement.time[-1]
        self._stage_inputs = {name: padded_rows(self._at_stages(values), n_stage)
                              for name, values in measurement.inputs.items()}
        self._forcing_features: list[sp.Expr] = []
        self._forcing_index: dict[sp.Expr, int] = {}
        self._finite: dict[sp.Expr, bool] = {}  # forcing_finite's verdicts
        self._forcing_basis = np.zeros((self.stage_times.size, 0))
        self._first_forcing_capacity = (first_forcing_capacity(self.stage_times.size)
                                        if forcing_capacity is None else int(forcing_capacity))
        self._n_extra = len(extra_state_features)
        # the extra features' numbers are data, their shapes the program (lifted_numbers)
        extra_shapes, extra_numbers = lifted_numbers(extra_state_features)
        self._extra_jets = _jets(extra_shapes, symbols, extra_numbers.size)
        #: The record as the programs' argument (:class:`~gpjax._record.RecordArrays`).
        self.record_arrays = _record_arrays(measurement, self.n_padded, self.n_bins,
                                            self.n_bins_padded, dft, self.h, self.sign_scales,
                                            extra_numbers)
        run = self._simulate_and_score
        if len(self.devices) > 1:
            mesh = jax.make_mesh((len(self.devices),), ("population",),
                                 axis_types=(AxisType.Auto,), devices=self.devices)
            split = PartitionSpec("population")
            run = jax.shard_map(run, mesh=mesh, in_specs=(split,) * 5 + (PartitionSpec(),) * 2,
                                out_specs=split, check_vma=False)
        #: Fingerprint of everything the compiled programs close over (the record is an
        #: argument: records of one length bucket share the programs).
        #: The same without eq. 9's bins: the key of programs that integrate but take no
        #: spectrum (the refiner's; their record is :attr:`time_record`).
        unit = ([*polynomial_state_features(symbols, max_degree), *extra_shapes,  # numbers
                 *self.state_features[len(fixed):]] if self.n_coordinates == 1 else  # and θ
                system_state_features(names, max_degree, self.kinds)[0])  # are arguments
        self.time_key = fingerprint(self.n_padded, symbols, unit,
                                    self.families, max_degree, substeps, self.batch,
                                    fit_initial_conditions, integrator, input_interpolation,
                                    [str(d) for d in self.devices])
        self.key = fingerprint(self.time_key, self.n_bins_padded, w_time, w_freq)
        #: :attr:`record_arrays` without the spectrum, whose bins would be a shape.
        self.time_record = dataclasses.replace(
            self.record_arrays, dft=np.zeros((1, 1)),
            amplitude=np.zeros((1, self.n_coordinates)))
        self._run = Program(run, name="population", key=self.key)

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

    def _at_stages(self, values: np.ndarray, interpolation: str | None = None) -> np.ndarray:
        """An input's samples (N,) reconstructed at every forcing row (:meth:`stage_rows`),
        by ``interpolation`` (default the evaluator's; not ``"hold"`` on shared rows)."""
        if self.split_stages:  # every stage of a step sees the value held over that step
            return np.repeat(between_samples(values, self.substeps, "hold")[:-1], 3)
        return between_samples(values, 2 * self.substeps,
                               interpolation or self.input_interpolation)

    # --- evaluation ---------------------------------------------------------------------
    def empty(self, count: int) -> Population:
        """A population of ``count`` placeholder models (m = 1, no terms, y0 = 0)."""
        rows = (count,) if self.n_coordinates == 1 else (count, self.n_coordinates)
        return Population(mass=np.ones(rows), state=np.zeros(rows + (len(self.state_features),)),
                          forcing=np.zeros(rows + (self.forcing_capacity,)),
                          y0=np.zeros(rows + (2,)), inner=np.zeros((count, self.n_inner)),
                          forcing_features=self.forcing_features)

    def score(self, population: Population) -> Scores:
        """Objective (eq. 7), its parts (eqs. 8–9), RMS and status for every model."""
        return self._batched(population, responses=False)[0]

    def simulate(self, population: Population, *, forcing_basis: np.ndarray | None = None
                 ) -> tuple[np.ndarray, Scores]:
        """Simulated responses (P, N) ((P, D, N) for a system) at the sample times, and the
        scores; ``forcing_basis``: another (:meth:`forcing_basis_as`) in place of
        :attr:`forcing_basis`."""
        scores, responses = self._batched(population, responses=True,
                                          forcing_basis=forcing_basis)
        return responses, scores

    def _batched(self, population: Population, *, responses: bool,
                 forcing_basis: np.ndarray | None = None):
        """Scores (and responses) of ``population`` in padded batches, models that use no
        family apart on :attr:`plain_layout` (one more compile;
        ``benchmarks/bench_feature_bank.py``), the others by the families they use
        (:meth:`layout_groups`)."""
        self.check_forcing_bank(population)
        count = len(population)
        if count == 0:
            empty = np.zeros(0)
            return (Scores(empty, empty, empty, empty, empty.astype(int),
                           self.empty(0).y0), np.zeros((0, 0)))
        parts, paths, order = [], [], []
        for rows, plain in self.layout_groups(population):
            part = population.rows(rows)
            part = self.narrowed(part) if plain else part
            forcing = _pad_columns(part.forcing, self.forcing_capacity)
            for size, chunk in padded_chunks((part.mass, part.state, forcing, part.y0,
                                              part.inner), self.batch_sizes):
                out = self._call(*chunk, forcing_basis=forcing_basis)
                parts.append([np.asarray(o)[:size] for o in out[:6]])
                if responses:
                    paths.append(np.asarray(out[6])[:size, ..., :self.measurement.n_samples])
            order.append(rows)
        back = np.argsort(np.concatenate(order))
        stacked = [np.concatenate(p)[back] for p in zip(*parts)]
        scores = Scores(objective=stacked[0], f_time=stacked[1], f_freq=stacked[2],
                        rms=stacked[3], status=stacked[4].astype(int), y0=stacked[5])
        return scores, (np.concatenate(paths)[back] if responses else None)

    def _call(self, mass, state, forcing, y0, inner, *, forcing_basis=None):
        basis = self._forcing_basis if forcing_basis is None else forcing_basis
        return jax.block_until_ready(self._run(
            *map(jnp.asarray, (mass, state, forcing, y0, inner, basis)), self.record_arrays))

    def _simulate_and_score(self, mass, state, forcing, y0, inner, forcing_basis, record):
        with self.tracing(record):
            forcing_matrix = _forcing_rows(forcing_basis, forcing)  # (n_stage, [D,] P)
            if self.fit_initial_conditions:
                y0 = self._fitted_initial_conditions(mass, state, forcing_matrix, y0, inner)
            if self.integrator == "diffrax":
                x = self.solve(mass, state, forcing_matrix, y0, inner)  # (N', [D,] P)
            else:
                x = self.scan_solve(mass, state, forcing_matrix, y0, inner)
        paths = jnp.transpose(x)  # (P, [D,] N')
        x = self._coordinates(x, 1)
        padding = (record.valid == 0)[:, None, None]
        finite = jnp.all(jnp.isfinite(x) | padding, axis=(0, 1))
        bounded = jnp.all((jnp.abs(x) < record.bounds[:, :1]) | padding, axis=(0, 1))
        positive = jnp.all(self._coordinates(mass, -1) > 0, axis=-1)
        status = jnp.where(positive, jnp.where(finite & bounded, OK, DIVERGED), NONPOSITIVE_MASS)
        x = jnp.where(jnp.isfinite(x) & ~padding, x, 0.0)  # the padding's residual is 0
        f_time, f_freq, rms = _objective_parts(  # (D, P) each
            record.responses[:, :, None], x, record.dft, record.amplitude[:, :, None],
            self.n_bins_padded, count=record.count)
        if self.n_coordinates == 1:
            f_time, f_freq, rms = f_time[0], f_freq[0], rms[0]
        else:
            weights = record.weights[:, None]
            f_time, f_freq = jnp.sum(weights * f_time, 0), jnp.sum(weights * f_freq, 0)
            rms = jnp.sqrt(jnp.mean((weights * rms) ** 2, 0))
        objective = self.w_time * f_time + self.w_freq * f_freq
        good = status == OK
        out = (jnp.where(good, objective, PENALTY), jnp.where(good, f_time, PENALTY),
               jnp.where(good, f_freq, PENALTY), jnp.where(good, rms, PENALTY), status, y0)
        return out + (paths,)


def _record_arrays(measurement: Measurement, n_padded: int, n_bins: int, n_bins_padded: int,
                   dft: np.ndarray, step: float, sign_scales: np.ndarray,
                   extra_numbers: np.ndarray) -> RecordArrays:
    """``measurement`` as program arguments, padded to ``n_padded`` samples and
    ``n_bins_padded`` bins (:class:`~gpjax._record.RecordArrays`); ``dft`` is
    :func:`~gpjax._objective._dft_matrix` of the unpadded record."""
    n = measurement.n_samples
    responses = np.zeros((n_padded, measurement.n_coordinates))
    responses[:n] = measurement.responses
    if dft.shape[0] == 1:  # rfft weights: (1, m'), zero past m
        padded_dft = np.zeros((1, n_bins_padded))
        padded_dft[0, :n_bins] = dft[0, :n_bins]
    else:  # cos rows, then sin rows, each zero past m and past N
        padded_dft = np.zeros((2 * n_bins_padded, n_padded))
        padded_dft[:n_bins, :n] = dft[:n_bins]
        padded_dft[n_bins_padded:n_bins_padded + n_bins, :n] = dft[n_bins:]
    measured = measurement.responses
    span = np.ptp(measured, axis=0) + np.max(np.abs(measured), axis=0)
    bounds = DIVERGENCE_RANGES * np.stack([span, span / measurement.dt], axis=1)
    noise_scale = np.std(measured, axis=0)
    return RecordArrays(
        responses=responses, valid=(np.arange(n_padded) < n).astype(float),
        count=np.asarray(float(n)), dft=padded_dft,
        amplitude=_amplitude(padded_dft, responses, n_bins_padded, np),
        weights=np.std(measured[:, :1]) / np.std(measured, axis=0), bounds=bounds,
        step=np.asarray(step), start=np.asarray(float(measurement.time[0])),
        noise_scale=np.where(noise_scale == 0, 1.0, noise_scale), sign_scales=sign_scales,
        extra_numbers=extra_numbers)


def _pad_columns(array: np.ndarray, columns: int) -> np.ndarray:
    """``array`` zero-padded, or cut, to ``columns`` along its last axis: a population laid
    out on an evaluator of a shorter record has a wider forcing capacity (a basis of fewer
    stage rows starts wider, :func:`gpjax._evaluator_columns.first_forcing_capacity`); the
    columns past this evaluator's capacity hold no feature (:meth:`check_forcing_bank`), so
    they are 0.

    Raises:
        ValueError: a column past ``columns`` is not 0.
    """
    if array.shape[-1] == columns:
        return array
    if array.shape[-1] > columns:
        if np.any(array[..., columns:]):
            raise ValueError(f"forcing coefficients past this evaluator's {columns} columns")
        return array[..., :columns]
    out = np.zeros(array.shape[:-1] + (columns,))
    out[..., : array.shape[-1]] = array
    return out


#: The symbols that stand for the numbers of extra features (:func:`lifted_numbers`).
NUMBER = "_number"


def lifted_numbers(features) -> tuple[tuple[sp.Expr, ...], np.ndarray]:
    """(shapes, numbers): ``features`` with every number not in an exponent replaced by a
    real symbol ``_number{k}`` (k counting across the features;
    :func:`gpjax._canonical.numbers_lifted`, as the reference solve lifts them), and
    those numbers in order.

    A diagnosis's effects carry numbers that come from the record — a smoothed sign's
    θ = 1/ε, a backlash's centre and half width, a spectral line's frequency — so with the
    numbers compiled in every new record compiled its programs again (a gear record of
    2,001 samples: 26 s of compiling, 5 s warm). As data (:attr:`RecordArrays.extra_numbers`)
    one program serves every record of a shape."""
    numbers: list[float] = []

    def constant(value: float) -> sp.Symbol:
        numbers.append(value)
        return sp.Symbol(f"{NUMBER}{len(numbers) - 1}", real=True)  # |z|' is sign(z)

    shapes = tuple(numbers_lifted(f, constant) for f in features)
    return shapes, np.array(numbers, dtype=np.float64)


def _jets(features, symbols, count: int):
    """``jets(x, x', t, numbers)``: the features' values and their partial derivatives by x
    and by x' (three lists of arrays), from one function that computes their common
    subexpressions once (a tanh and its slope share the tanh); ``None`` without features.
    ``features`` are sympy expressions (parsed by the whitelist of
    :mod:`gpjax._expressions`) whose ``count`` numbers are the symbols of
    :func:`lifted_numbers`, given as ``numbers``."""
    if not features:
        return None
    x, v, t = (sp.Dummy(real=True) for _ in range(3))  # |x|' is sign(x) for a real x
    real = [f.subs({symbols.x: x, symbols.x_dot: v, symbols.t: t}) for f in features]
    numbers = sp.symbols(f"{NUMBER}0:{count}", real=True)

    def slope(f, z):  # a jump's delta is 0, as forward-mode autodiff takes it
        return sp.diff(f, z).replace(sp.DiracDelta, lambda *_: sp.S.Zero)

    jets = sp.lambdify((x, v, t, numbers), [real, [slope(f, x) for f in real],
                                            [slope(f, v) for f in real]],
                       modules="jax", cse=True)
    return lambda x, v, t, values: jets(x, v, t, [values[k] for k in range(count)])
