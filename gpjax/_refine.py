"""Output-error refinement of constants with optimistix Levenberg–Marquardt.

Each model's free constants (mass, its state and forcing coefficients except the
normalised one, and the initial conditions) are refined so the *simulated* response
matches the measured one in the least-squares sense (the square of eq. 8). Parameters are
scaled by their starting magnitudes, so constants spanning nine orders of magnitude
(J ~ 1e-4, K2 ~ 5e4) are all of order one to the solver. Models are refined together
under ``vmap``; a model whose solve fails keeps its start values (status returned, never
raised).

The Jacobian has ``max_free`` columns whatever a call's models need (unused ones have
scale 0; a refiner of batch 1, which refits one model, sizes it to that model), and every
call is padded to the refiner's batch: one compiled program per
layout, not one per Jacobian width and batch size. With the wide function set the
program of the families' layout takes ~20 s to compile on 2 cores, far more than the
narrower columns and smaller calls it would save (a cold 8,000-sample fit compiled seven
refinement programs, 150 s of 262 s; now two). The augmented solve of a call is one
population scan (``custom_vmap``), split over the evaluator's devices like its
evaluations: on the gear example (64 models, 10 iterations, 2 host devices) 1.9× the
models/s of one padded 8-column Jacobian per model under ``vmap``
(benchmarks/bench_population.py, ``--baseline``).

The fit grows its horizon (continuation): Levenberg–Marquardt first matches a leading part
of the record, then the whole. A wrong stiffness shifts the phase in proportion to the time
elapsed, so on the full record (~24 periods on the gear example) a start a few per cent
off already lies past a phase wrap; on a short horizon it does not. The Jacobian comes
from the variational equations integrated beside the model in the evaluator's RK4 scan
(:meth:`PopulationEvaluator.scan_jvp`, exact for the discrete solution), through a custom
derivative rule: one augmented solve per Levenberg–Marquardt step. Refinement runs ~5×
faster than with forward-mode autodiff through the scan and ~9× faster than through
``diffrax.diffeqsolve`` (``jacobian="autodiff"``; benchmarks/bench_population.py).
"""

from __future__ import annotations

import dataclasses
import weakref

import jax
import jax.numpy as jnp
import numpy as np

from jax.sharding import AxisType, PartitionSpec

from ._aot import CompileFigures, Program, fingerprint
from ._coefficients import Population, padded_chunks
from ._evaluator import STAGE_ELEMENTS_PER_CALL, PopulationEvaluator

JACOBIANS = ("variational", "autodiff")


#: Default models per compiled refinement call and free constants per model.
BATCH, MAX_FREE = 8, 8
#: The continuation of a search's refinement (fractions of the record fitted in turn).
HORIZONS = (0.25, 1.0)
#: The continuation of a fit from a start (weak-form, least-squares or a search's constants)
#: whose constants are reported or decide the selection: from the same first quarter, each
#: horizon twice the last. A constant's error shifts the phase in proportion to the time
#: elapsed, so a fit that holds the phase over a horizon holds it to about twice its error
#: over twice that horizon, where four times can slip a revolution: on two coupled pendulums
#: driven over the top (a record outside the repository) the true structure from a weak-form
#: start within 2 % of every constant stopped at objective 74 with 25 → 100 %, at 11 with
#: 25 → 50 → 100 %. A shorter first horizon is no better: over 6 % of the record a sine's
#: inner scale is barely determined and drifts (one pendulum refitted from its true
#: constants: 3.0 here, 96 with 25 → 100 %, 81–281 from 6 %). A refit from a fit (a finer
#: step, narrower signs) starts near and fits the whole record at once
#: (:func:`refit_horizons`).
REFIT_HORIZONS = (0.25, 0.5, 1.0)
#: No continuation: the whole record at once.
WHOLE_RECORD = (1.0,)
#: The smaller batch a refiner also compiles (on first use): the final selection refines
#: neighbours one or two at a time, and a call padded to 8 models costs 2–3× one of 2
#: (``benchmarks/call_cost.json``: 8,000 samples, the wide function set, 2 cores).
SMALL_BATCH = 2
#: A refinement to convergence stops when a round of Levenberg–Marquardt steps lowers the
#: objective by less than this fraction (a convergence check on the objective itself: the
#: selection's tests compare models whose objectives differ by percents, :mod:`gpjax._select`).
CONVERGED = 1e-3
#: Rounds of ``refine_iterations`` steps a refinement to convergence takes at most.
MAX_ROUNDS = 10


def until_converged(refine_round, objectives, *, rounds: int = MAX_ROUNDS) -> None:
    """The convergence loop of every fit whose constants are reported or compared (a
    search's selection, :func:`gpjax._refit.refit`, :func:`gpjax._system_fit.fit_system`):
    rounds of refinement while a round lowers a model's objective by at least
    :data:`CONVERGED` (relative), at most ``rounds``. ``refine_round(active)`` refines the
    models at the indices ``active`` once from their current constants (a model keeps them
    where the refined ones do not score lower) and returns their objectives, or
    (objectives, settled): ``settled`` marks the models whose solver met its own stop rule
    on the whole record this round (:attr:`Refinement.settled`), which converge without
    another round, since one would start where that rule holds already;
    ``objectives``: every model's objective before the first round."""
    before = np.asarray(objectives, dtype=float).copy()
    active = np.arange(before.size)
    for _ in range(rounds):
        if not active.size:
            return
        out = refine_round(active)
        after, settled = out if isinstance(out, tuple) else (out, False)
        after = np.asarray(after, dtype=float)
        falling = ~(after > (1 - CONVERGED) * before[active]) & ~np.asarray(settled)
        before[active] = after
        active = active[falling]


def refined_to_convergence(refiner: Refiner, population: Population,
                           fixed_forcing: np.ndarray, score, *, ties=None
                           ) -> tuple[Population, np.ndarray]:
    """The models of ``population`` refined by ``refiner`` in rounds until each converges
    (:func:`until_converged`), each keeping the constants of its best round; the rounds
    after the first start from a fit and fit the whole record at once
    (:data:`WHOLE_RECORD`, a second refiner where ``refiner`` grows its horizon).
    ``score(population) -> (P,)`` objectives; ``fixed_forcing``, ``ties`` as
    :meth:`Refiner.refine` takes them (``ties`` one entry per model). Returns
    (population, (P,) objectives); a start that does not score (NaN) counts as +inf, so
    any finite refinement replaces it."""
    def scored(candidates) -> np.ndarray:
        return np.nan_to_num(np.asarray(score(candidates), dtype=float), nan=np.inf)

    best = [population]
    objectives = scored(population)
    current = [refiner]  # this round's refiner: ``refiner``, then its whole-record twin

    def refine_round(active):
        refinement = current[0].refine(best[0].rows(active), fixed_forcing[active],
                                       ties=None if ties is None else [ties[i] for i in active])
        current[0] = refiner.whole_record()
        refined = refinement.population
        after = scored(refined)
        better = after < objectives[active]
        rows = np.arange(len(best[0]))
        rows[active[better]] = len(best[0]) + np.flatnonzero(better)
        best[0] = Population.concatenate([best[0], refined]).rows(rows)
        objectives[active[better]] = after[better]
        return objectives[active], refinement.settled

    until_converged(refine_round, objectives)
    return best[0], objectives


def refit_horizons(near: bool) -> tuple[float, ...]:
    """The continuation of a reported model's fit: :data:`WHOLE_RECORD` from a ``near``
    start (the constants of a fit), else :data:`REFIT_HORIZONS`."""
    return WHOLE_RECORD if near else REFIT_HORIZONS


def free_width(free: int) -> int:
    """The Jacobian width a refiner is compiled for to fit ``free`` constants: the next
    multiple of :data:`MAX_FREE`, so the structures a search and its final fits meet
    share a few programs instead of compiling one per count (the columns past ``free``
    are padding whose moves are 0)."""
    return -(-int(free) // MAX_FREE) * MAX_FREE


@dataclasses.dataclass(frozen=True)
class Refinement:
    """Refined models and, per model, whether the solver reported success, its
    Levenberg–Marquardt steps over every horizon, and whether the last horizon's solve
    (the whole record) stopped by the solver's own rule (rounding level, or resolved to
    0.1 standard error) rather than at the step cap: ``settled``."""

    population: Population
    succeeded: np.ndarray
    steps: np.ndarray
    settled: np.ndarray


@dataclasses.dataclass(frozen=True)
class Sensitivity:
    """One model's simulated response and its derivatives by its free constants.

    Attributes:
        response: (N,) or (N, D): x at the record's samples.
        jacobian: (N, k) or (N, D, k): ∂x/∂constant, per unit of each constant (a tied
            constant, :mod:`gpjax._system_couplings`, moves with its source).
        columns: (k,) the constants' indices in ``layout``'s flat vector.
        values: (k,) their values.
        layout: the flat layout ``columns`` index.
        tied: the model's ties (as :meth:`Refiner.refine` takes them) or ``None``.
    """

    response: np.ndarray
    jacobian: np.ndarray
    columns: np.ndarray
    values: np.ndarray
    layout: object
    tied: object = None


def refine_batch(batch: int, *, n_samples: int, substeps: int, max_free: int) -> int:
    """``batch`` capped so stages × ``max_free`` × models ≤ ``STAGE_ELEMENTS_PER_CALL``."""
    stages = 2 * (n_samples - 1) * substeps + 1
    return max(1, min(batch, STAGE_ELEMENTS_PER_CALL // (stages * max_free)))


class Refiner(CompileFigures):
    """Compiles the batched Levenberg–Marquardt refinement once per evaluator.

    Args:
        evaluator: supplies the simulation and the measured response.
        iterations: maximum Levenberg–Marquardt steps.
        batch: models refined per compiled call (padded; split over the evaluator's
            devices when it divides evenly among them); a call of at most
            :data:`SMALL_BATCH` models is padded to that instead (a second program, compiled
            on first use; a convergence loop that refines one model makes a refiner of
            batch 1). Capped so one call's forcing
            directions (stages × ``max_free`` × models) hold at most
            :data:`gpjax._evaluator.STAGE_ELEMENTS_PER_CALL` numbers (on a 10⁶-sample
            record one model per call: 2.2 GB peak instead of 5.5 GB for eight).
        max_free: free constants per model, the Jacobian's columns (further ones stay at
            their start values). A refit of one model sizes it to that model's free
            constants by :func:`free_width`, so refits of different structures share
            programs.
        horizons: increasing fractions of the record fitted in turn, each for up to
            ``iterations`` steps; the last should be 1.
        jacobian: ``"variational"`` (default: the variational equations in the scan, see
            :meth:`_response`) or ``"autodiff"`` (forward-mode differentiation of the
            evaluator's integrator — through ``diffrax.diffeqsolve`` with
            ``ForwardMode`` when it is ``"diffrax"``; slower, kept as the reference that
            ``benchmarks/bench_population.py`` compares against).

    Raises:
        ValueError: if ``horizons`` is empty, not increasing or outside (0, 1], or for an
            unknown ``jacobian``.
    """

    def __init__(self, evaluator: PopulationEvaluator, *, iterations: int = 20, batch: int = BATCH,
                 max_free: int = MAX_FREE, horizons: tuple[float, ...] = HORIZONS,
                 jacobian: str = "variational"):
        if not horizons or any(not 0 < h <= 1 for h in horizons) or list(horizons) != sorted(
                set(horizons)):
            raise ValueError(f"horizons must increase within (0, 1], got {horizons}")
        if jacobian not in JACOBIANS:
            raise ValueError(f"jacobian must be one of {JACOBIANS}, got {jacobian!r}")
        self.jacobian = jacobian
        self.evaluator = evaluator
        self.iterations = iterations
        # Each horizon integrates its share of the padded record (a length of the bucket,
        # so the program serves every record of it, gpjax._record) and fits its share of
        # the record itself: residuals past ``horizon_limits`` samples are masked out.
        padded, n = evaluator.n_padded, evaluator.measurement.n_samples
        self.horizon_samples = tuple(max(3, min(padded, int(round(h * padded))))
                                     for h in horizons)
        #: Samples of the record each horizon fits (a program argument).
        self.horizon_limits = np.array([max(3, min(n, int(round(h * n)))) for h in horizons],
                                       dtype=float)
        self.batch = refine_batch(batch, n_samples=padded, substeps=evaluator.substeps,
                                  max_free=max_free)
        #: The batch sizes compiled (each on first use).
        self.batch_sizes = tuple(sorted({min(SMALL_BATCH, self.batch), self.batch}))
        self.max_free = max_free
        self._sensitivity: Program | None = None  # compiled on first use (sensitivity)
        self._whole: Refiner | None = None  # its whole-record twin (:meth:`whole_record`)
        responses = evaluator.measurement.responses
        self._state_scale = np.stack([np.std(responses, axis=0), np.std(np.diff(
            responses, axis=0), axis=0) / evaluator.measurement.dt], axis=1).ravel() + 1e-300
        # The Jacobian's width and the batch are the arguments' shapes, which key each
        # executable: refiners of different ``max_free`` share the calls of one width.
        self._run = Program(jax.vmap(self._refine_one, in_axes=(0, 0, None, None, None)),
                            name="refine",
                            key=fingerprint(evaluator.time_key, iterations, self.horizon_samples,
                                            jacobian))

    def whole_record(self) -> "Refiner":
        """This refiner's twin that fits the whole record at once (:data:`WHOLE_RECORD`):
        the same evaluator, steps, batch and Jacobian width; cached (this refiner itself
        if it fits the whole record at once already)."""
        if len(self.horizon_limits) == 1:
            return self
        if self._whole is None:
            self._whole = Refiner(self.evaluator, iterations=self.iterations, batch=self.batch,
                                  max_free=self.max_free, horizons=WHOLE_RECORD,
                                  jacobian=self.jacobian)
        return self._whole

    def _programs(self) -> list[Program]:
        """Its programs and its whole-record twin's (:class:`gpjax._aot.CompileFigures`)."""
        return super()._programs() + (self._whole._programs() if self._whole else [])

    def refine(self, population: Population, fixed_forcing: np.ndarray,
               held_inner: np.ndarray | None = None, *, ties=None) -> Refinement:
        """Refine every model of ``population``; coefficients that are 0 stay 0.

        Args:
            population: start values (typically from equation-error least squares).
            fixed_forcing: (P,) column of each model's forcing coefficient held at 1 (the
                first input), or −1 where the mass is the normalised constant instead; for
                a system of D equations (P, D), one per equation (each equation's scale is
                free on its own), −2 where nothing of that equation is held.
            held_inner: (P, n_inner) booleans, inner constants held at their start values
                (a snapped phase or scale, :mod:`gpjax._select_moves`); default none.
            ties: per model, (equation, column, equation, column, sign) state coefficients
                that move together, the second by ``sign`` × the first's step (Newton's
                third law, :mod:`gpjax._system_couplings`; the start must obey them);
                ``None``: none.

        Raises:
            ValueError: ``population`` was laid out on another forcing bank than the
                evaluator's (:meth:`~PopulationEvaluator.check_forcing_bank`).
        """
        ev = self.evaluator
        ev.check_forcing_bank(population)
        groups = ev.layout_groups(population)
        if ties is not None and not any(ties):
            ties = None
        if held_inner is None:
            held_inner = np.zeros(population.inner.shape, dtype=bool)
        if len(groups) <= 1 and all(plain for _, plain in groups):
            return self._refine(population, fixed_forcing, True, held_inner, ties)
        if ties is not None:
            raise ValueError("tied coefficients are for systems, which use no family")
        parts = [self._refine(population.rows(r), np.asarray(fixed_forcing)[r], plain,
                              held_inner[r]) for r, plain in groups]
        back = np.argsort(np.concatenate([r for r, _ in groups]))
        merged = Population.concatenate(p.population for p in parts)
        return Refinement(population=merged.rows(back),
                          succeeded=np.concatenate([p.succeeded for p in parts])[back],
                          steps=np.concatenate([p.steps for p in parts])[back],
                          settled=np.concatenate([p.settled for p in parts])[back])

    def _moves(self, population: Population, fixed_forcing: np.ndarray, plain: bool,
               held_inner: np.ndarray, ties=None):
        """(layout, flat start (P, W), moves) of ``population``'s free constants, as
        :meth:`_refine_one` and :meth:`sensitivity` take them: ``moves`` = (index,
        index_scale[, mirror, mirror_sign]), one row per model of ``max_free`` columns
        (:func:`_moved`); padding columns have scale 0."""
        ev = self.evaluator
        count = len(population)
        layout = ev.plain_layout if plain else ev.layout
        start = layout.pack(ev.narrowed(population) if plain else population)
        scale = np.abs(start)
        states = 2 * ev.n_coordinates
        scale[:, -states:] = self._state_scale
        free = scale > 0
        free[:, -states:] = True
        fixed = np.asarray(fixed_forcing).reshape(count, -1)
        for i, row in enumerate(fixed):
            for e, column in enumerate(row):
                if column >= -1:
                    free[i, layout.forcing_column(column, e) if column >= 0 else
                         layout.mass_column(e)] = False
        follows = np.zeros(start.shape, dtype=np.int64)  # tied column -> its source + 1
        for i, model in enumerate(ties or []):
            for ea, ca, eb, cb, sign in model:
                b = layout.state_column(cb, eb)
                free[i, b] = False
                follows[i, b] = (layout.state_column(ca, ea) + 1) * (1 if sign > 0 else -1)
        for column, slots in ([] if plain else ev.inner_columns()):  # θ move where used
            used = population.state[:, column] != 0
            free[:, [layout.inner_column(k) for k in range(slots.start, slots.stop)]] = \
                used[:, None] & ~held_inner[:, slots]
        scale = np.where(scale > 0, scale, 1.0)
        # Only free parameters are differentiated: index (P, width), padded with scale 0.
        most = int(free.sum(axis=1).max())
        width = self.max_free if self.batch > 1 else min(self.max_free, free_width(most))
        index = np.zeros((count, width), dtype=np.int32)
        index_scale = np.zeros((count, width))
        for i, row in enumerate(free):
            columns = np.flatnonzero(row)[:width]
            index[i, : columns.size] = columns
            index_scale[i, : columns.size] = scale[i, columns]
        moves = [index, index_scale]
        if ties is not None:  # the tied column of each free one (0 with sign 0: none)
            mirror = np.zeros((count, width), dtype=np.int32)
            mirror_sign = np.zeros((count, width))
            for i, b in zip(*np.nonzero(follows)):
                j = np.flatnonzero(index[i] == abs(follows[i, b]) - 1)
                mirror[i, j], mirror_sign[i, j] = b, np.sign(follows[i, b])
            moves += [mirror, mirror_sign]
        return layout, start, moves

    def _refine(self, population: Population, fixed_forcing: np.ndarray,
                plain: bool, held_inner: np.ndarray, ties=None) -> Refinement:
        """:meth:`refine` of models that all use no family (``plain``: on the evaluator's
        :attr:`~PopulationEvaluator.plain_layout`) or all on its full layout."""
        ev = self.evaluator
        layout, start, moves = self._moves(population, fixed_forcing, plain, held_inner, ties)
        outputs = []
        basis = jnp.asarray(ev.forcing_basis)
        for size, chunk in padded_chunks((start, *moves), self.batch_sizes):
            out = jax.block_until_ready(self._run(chunk[0], tuple(chunk[1:]), basis,
                                                  ev.time_record, self.horizon_limits))
            outputs.append([np.asarray(o)[:size] for o in out])
        params, ok, steps, settled = (np.concatenate(p) for p in zip(*outputs))
        refined = dataclasses.replace(layout.population(params, population.forcing.shape[-1]),
                                      forcing_features=population.forcing_features)
        if plain:  # back on the full layout: the family columns and θ as they were
            refined = dataclasses.replace(refined, state=np.concatenate(
                [refined.state, population.state[..., layout.n_state:]], axis=-1),
                inner=population.inner)
        return Refinement(population=refined, succeeded=ok.astype(bool), steps=steps,
                          settled=settled.astype(bool))

    def sensitivity(self, population: Population, fixed_forcing: np.ndarray,
                    held_inner: np.ndarray | None = None, *, ties=None,
                    forcing_basis: np.ndarray | None = None) -> Sensitivity:
        """The simulated response of a population of one model at its constants, and its
        derivatives by the constants :meth:`refine` would move (the variational equations
        over the whole record, one augmented solve); arguments as :meth:`refine`'s,
        ``forcing_basis`` another reconstruction of the inputs
        (:meth:`~PopulationEvaluator.forcing_basis_as`). One compiled program per
        layout."""
        ev = self.evaluator
        ev.check_forcing_bank(population)
        if len(population) != 1:
            raise ValueError(f"sensitivity takes a population of one, got {len(population)}")
        if held_inner is None:
            held_inner = np.zeros(population.inner.shape, dtype=bool)
        if ties is not None and not any(ties):
            ties = None
        plain = bool(ev.plain_rows(population)[0])
        layout, start, moves = self._moves(population, fixed_forcing, plain, held_inner, ties)
        if self._sensitivity is None:
            ev_weak, n_stage = weakref.proxy(ev), ev.stage_rows(self.horizon_samples[-1])

            def jacobian(start, moves, forcing_basis, record):  # ev weakly: see _response
                with ev_weak.tracing(record):
                    return ev_weak.constant_jacobian(start, _directions(start, moves),
                                                     forcing_basis[:n_stage])
            self._sensitivity = Program(jacobian, name="sensitivity", key=fingerprint(
                ev.time_key, self.horizon_samples[-1]))
        x, jacobian = jax.block_until_ready(self._sensitivity(
            start[0], tuple(m[0] for m in moves),
            jnp.asarray(ev.forcing_basis if forcing_basis is None else forcing_basis),
            ev.time_record))
        n = ev.measurement.n_samples
        used = moves[1][0] != 0
        jacobian = np.asarray(jacobian)[:n, ..., used] / moves[1][0][used]
        return Sensitivity(response=np.asarray(x)[:n], jacobian=jacobian,
                           columns=moves[0][0][used], values=start[0][moves[0][0][used]],
                           layout=layout, tied=None if ties is None else ties[0])

    def _refine_one(self, start, moves, forcing_basis, record, limits):
        ev = self.evaluator
        single = ev.n_coordinates == 1
        measured = record.responses[:, 0] if single else record.responses
        index = jnp.arange(record.valid.size)
        index = index if single else index[:, None]
        noise_scale = record.noise_scale[0] if single else record.noise_scale
        import optimistix as optx  # traced only when compiled: a loaded program needs neither

        from ._levenberg_marquardt import ResolvedLevenbergMarquardt, linear_solver

        free = jnp.sum(moves[1] != 0)
        delta = jnp.zeros(moves[0].shape)
        ok, steps = jnp.array(True), jnp.array(0)
        for samples, limit in zip(self.horizon_samples, limits):
            response = self._response(samples)
            valid = index < limit  # the horizon's samples of the record (never its padding)

            # JAX's tracing caches keep this function (optx's static argument) after the
            # run: it holds the response, which holds the evaluator weakly, and the data
            # come in ``args`` — so a finished fit's programs can be freed (_response).
            def residuals(d, args, response=response):
                x = response(d, *args[:4])
                measured, valid, noise_scale = args[4:]
                return jnp.where(valid, x - measured, 0.0) / noise_scale

            # Stops at rounding level (Cauchy) or once resolved to 0.1 standard error.
            solver = ResolvedLevenbergMarquardt(
                rtol=1e-9, atol=1e-9, dof=jnp.maximum(limit * ev.n_coordinates - free, 1),
                linear_solver=linear_solver(self.jacobian))
            solution = optx.least_squares(
                residuals, solver, delta,
                args=(start, moves, forcing_basis, record, measured[:samples], valid[:samples],
                      noise_scale),
                max_steps=self.iterations, throw=False)
            finite = jnp.all(jnp.isfinite(solution.value))
            delta = jnp.where(finite, solution.value, delta)
            ok = ok & finite & ((solution.result == optx.RESULTS.successful) | (
                solution.result == optx.RESULTS.nonlinear_max_steps_reached))
            steps = steps + solution.stats["num_steps"]
        settled = finite & (solution.result == optx.RESULTS.successful)  # the last horizon
        return _moved(start, moves, delta), ok, steps, settled

    def _response(self, samples: int):
        """x over the first ``samples`` samples as a function of the scaled step ``delta``
        of one model's free constants, with its Jacobian from the variational equations.

        The derivative rule computes the whole Jacobian (samples, width) from primal
        values only — one :meth:`PopulationEvaluator.constant_jacobian` pass — and returns
        J·t; so the linearisation Levenberg–Marquardt takes each step costs one augmented
        solve, and materialising J is a matrix product, not one tangent solve per constant.
        """
        # Weakly: JAX's caches outlive the run and keep these closures (_refine_one); a
        # strong reference would keep the evaluator and its compiled programs with them.
        ev = weakref.proxy(self.evaluator)
        n_stage = ev.stage_rows(samples)
        if self.jacobian == "autodiff":
            def plain(delta, start, moves, forcing_basis, record):
                constants = _moved(start, moves, delta)
                with ev.tracing(record):
                    return ev.integrate(*ev.unpack(constants, forcing_basis))[:samples, ..., 0]
            return plain

        def jacobian_with(constants, directions, forcing_basis, record):
            with ev.tracing(record):
                return ev.constant_jacobian(constants, directions, forcing_basis[:n_stage])

        @jax.custom_jvp
        def response(delta, start, moves, forcing_basis, record):
            constants = _moved(start, moves, delta)
            with ev.tracing(record):
                return ev.scan_solve(*ev.unpack(constants, forcing_basis[:n_stage]))[..., 0]

        @jax.custom_batching.custom_vmap
        def augmented(constants, directions, forcing_basis, record):
            return jacobian_with(constants, directions, forcing_basis, record)

        @augmented.def_vmap
        def augmented_batched(axis_size, in_batched, constants, directions, forcing_basis,
                              record):
            # Models are the population axis of one scan, not a vmap of one-model scans.
            if in_batched[2] or any(jax.tree_util.tree_leaves(in_batched[3])):
                raise ValueError("the forcing basis and the record are shared by every model; "
                                 "batch the constants and directions only")
            constants, directions = (a if batched else jnp.broadcast_to(a, (axis_size,) + a.shape)
                                     for a, batched in zip((constants, directions), in_batched))
            x, jacobian = _split_over(ev.devices, jacobian_with, axis_size,
                                      2 + (ev.n_coordinates > 1))(
                constants, directions, forcing_basis, record)
            return (jnp.moveaxis(x, -1, 0), jnp.moveaxis(jacobian, -1, 0)), (True, True)

        @response.defjvp
        def response_jvp(primals, tangents):
            delta, start, moves, forcing_basis, record = primals
            # Row j of the directions: constant index[j] moved by index_scale[j] (and its
            # tied one by ±index_scale[j]).
            x, jacobian = augmented(_moved(start, moves, delta), _directions(start, moves),
                                    forcing_basis, record)
            return x, jacobian @ tangents[0]

        return response


def _split_over(devices, fn, count, x_rank: int = 2):
    """``fn(constants, directions, basis, record)`` with the models (first axis of the first two,
    last of the outputs, x of rank ``x_rank``, its Jacobian one more) split over
    ``devices`` by ``shard_map`` where there are several and ``count`` divides evenly."""
    if len(devices) < 2 or count % len(devices):
        return fn
    mesh = jax.make_mesh((len(devices),), ("population",), axis_types=(AxisType.Auto,),
                         devices=devices)
    models = PartitionSpec("population")
    return jax.shard_map(fn, mesh=mesh, in_specs=(models, models, PartitionSpec(),
                                                  PartitionSpec()),
                         out_specs=(PartitionSpec(*[None] * (x_rank - 1), "population"),
                                    PartitionSpec(*[None] * x_rank, "population")),
                         check_vma=False)


def _directions(start, moves):
    """(width, W): row j moves constant ``index[j]`` by ``index_scale[j]`` (and its tied
    one by ±``index_scale[j]``) in the flat vector ``start`` (:func:`_moved`)."""
    columns = jnp.arange(start.size)[None, :]
    index, index_scale = moves[:2]
    directions = (index[:, None] == columns) * index_scale[:, None]
    if len(moves) > 2:
        directions = directions + (moves[2][:, None] == columns) * (
            moves[3] * index_scale)[:, None]
    return directions


def _moved(start, moves, delta):
    """The flat constant vector ``start`` with constant ``index[j]`` moved by
    ``index_scale[j]·delta[j]`` (the solver's scaled step), ``moves`` = (index,
    index_scale[, mirror, mirror_sign]): with a tied ``mirror[j]`` moved by
    ``mirror_sign[j]`` × as much (sign 0: none)."""
    index, index_scale = moves[:2]
    moved = start.at[index].add(index_scale * delta)
    if len(moves) > 2:
        moved = moved.at[moves[2]].add(moves[3] * index_scale * delta)
    return moved
