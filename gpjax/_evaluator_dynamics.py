"""Parts of :class:`gpjax._evaluator.PopulationEvaluator`: the compiled right-hand side of
every model (Horner sums over the powers, the extra features and the feature bank), the two
integrators and the variational equations.

Two integrators run the same RK4 tableau on the same stage grid: ``"scan"`` (default), a
hand-written step in ``lax.scan`` over (x, x') arrays of shape (P,) with Horner-form
polynomials, and ``"diffrax"`` (:func:`~gpjax._integrate.rk4_solver`, one ``diffeqsolve``
of the (P, 2) state).
They agree to rounding; the scan step has none of diffrax's per-step bookkeeping: about
as fast on the CPU, several times faster on a GPU (``benchmarks/bench_population.py``
measures both; :mod:`gpjax._integrate`). Arrays inside carry a coordinate axis of length
D (inserted for one coordinate, :meth:`Dynamics._internal`).
"""

from __future__ import annotations

import weakref

import jax
import jax.numpy as jnp

from ._integrate import rk4_scan, rk4_solver

HOLD_WITH_DIFFRAX = ('the "diffrax" integrator cannot simulate "hold" inputs (it looks the '
                     'forcing up by time alone); use integrator="scan"')


class Dynamics:
    """Mixin of :class:`gpjax._evaluator.PopulationEvaluator` (uses its ``n_coordinates``,
    ``max_degree``, ``families``, ``_inner_slots``, ``_n_extra``, ``_extra_jets``,
    ``record`` (the record's step, start time and bounds, :mod:`gpjax._record`),
    ``substeps``, ``n_steps``, ``split_stages``, ``integrator``, :meth:`_layout_of` and the
    systems' :class:`SystemTerms`)."""

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

    def _acceleration_fn(self, mass, state, inner, *, families: bool = True,
                         extras: bool = True):
        """x''(x, v, force, t) for all models, states clipped; ``mass`` (D, P), ``state``
        (P, D, F). One coordinate: x, x' and the force as one-element sequences of (P,)
        arrays, the acceleration returned likewise (the scan carries no stacked state: faster
        for D = 1). D > 1: (D, P) arrays in and out (one stacked Horner sum).

        The one right-hand side both integrators use (:meth:`_restoring_fn`; ``families``
        or ``extras`` False: without the families' or the extra features' terms).
        """
        inverse_mass = 1.0 / mass
        rows = self._restoring_fn(state, inner, stacked=False, families=families,
                                  extras=extras)
        bounds = self.record.bounds
        if self.n_coordinates > 1:  # (D, P) arrays in and out
            def system_acceleration(xs, vs, forces, t):
                r = rows(self._clipped_rows(xs, 0), self._clipped_rows(vs, 1), t)
                return jnp.stack([(forces[e] - r_e) * inverse_mass[e] for e, r_e in enumerate(r)])

            return system_acceleration
        bx, bv = bounds[0, 0], bounds[0, 1]

        def acceleration(xs, vs, forces, t):
            (r,) = rows([jnp.clip(xs[0], -bx, bx)], [jnp.clip(vs[0], -bv, bv)], t)
            return [(forces[0] - r) * inverse_mass[0]]

        return acceleration

    def _clipped_rows(self, z, which: int):
        """The D rows of positions (``which`` 0) or velocities (1) ``z`` clipped to the
        record's bounds, as a list: row by row is faster than one broadcast clip in
        :meth:`scan_jvp`."""
        bounds = self.record.bounds
        return [jnp.clip(z[e], -bounds[e, which], bounds[e, which])
                for e in range(self.n_coordinates)]

    def _restoring_fn(self, state, inner, *, stacked: bool = True, families: bool = True,
                      extras: bool = True):
        """Σ c·φ per equation for coefficients ``state`` of shape (..., P, D, F) and the
        families' inner constants ``inner`` (P, F_inner): Horner sums over the powers of each
        equation's variables (:func:`system_state_features`), plus, for D = 1, the compiled
        extra features and families. The function takes the positions and velocities as
        (D, P) arrays or sequences of D (P,) arrays and returns (..., D, P) (``stacked``
        False: a list of D (..., P) arrays). A family no model of the call uses is skipped
        (:meth:`_family_sum`); ``families`` False: the families' terms are
        left out (:meth:`_family_pass` adds them); ``extras`` False: the extra features'
        (:meth:`_extra_pass` adds them)."""
        if self.n_coordinates > 1:
            return self._system_restoring(state, stacked=stacked)
        d = self.max_degree
        position, velocity = (jnp.moveaxis(state[..., 0, k * d:(k + 1) * d], -1, 0)
                              for k in (0, 1))
        n_poly, n_extra = 2 * d, self._n_extra if extras else 0
        extra = jnp.moveaxis(state[..., 0, n_poly:n_poly + n_extra], -1, 0)
        bank = self._bank_columns(state) if families else jnp.zeros((0,))
        family_sum = self._family_sum(bank, inner) if bank.shape[0] else None

        def horner(c, z):
            total = c[d - 1]
            for k in range(d - 2, -1, -1):
                total = total * z + c[k]
            return total * z

        def restoring(xs, vs, t):
            x, v = xs[0], vs[0]
            total = horner(position, x) + horner(velocity, v)
            if n_extra:  # the values only: jit drops the slopes no one uses
                numbers = self.record.extra_numbers
                for c, f in zip(extra, self._extra_jets(x, v, t, numbers)[0]):
                    total = total + c * f
            if family_sum is not None:
                total = total + family_sum(x, v)
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
            import diffrax  # on first use (gpjax._integrate.rk4_solver)

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
                ``fn(acc, y, k)`` at sample k, y the carried (2, 1 + Q, D, P) array
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
        # One coordinate with families: their terms, slopes and directional derivatives in
        # one pass per stage (one ``lax.cond`` per family instead of five).
        fused = self._has_families(state)
        # The extra features likewise: each, with its slopes, once per stage (the generic
        # path below evaluated it in the acceleration, in both slopes and for the
        # directions: a tanh of x' added 0.40 s to a 0.21 s Silverbox refit step, now 0.31).
        extra_pass = self._extra_pass(state, d_state) if self._extra_jets else None
        options = dict(families=not fused, extras=extra_pass is None)
        count = self.n_coordinates
        if count > 1:  # r and its D × D partials from one pass (no autodiff of r)
            system_forces = self._system_forces(state)
        else:
            acceleration = self._acceleration_fn(mass, state, inner, **options)
            restoring = self._restoring_fn(state, inner, **options)
        d_restoring = (self._restoring_fn(d_state, inner, **options)
                       if d_state is not None else None)
        family_pass = (self._family_pass(state, inner, d_state, d_inner, d_y0.shape[0])
                       if fused else None)
        inverse_mass = 1.0 / mass

        def partials(x, v, t):
            """One coordinate's ∂r/∂x and ∂r/∂x', [(1, P)] each, by autodiff of r."""
            ones = jnp.ones_like(x)
            return ([jax.jvp(lambda z: restoring([z], [v], t), (x,), (ones,))[1]],
                    [jax.jvp(lambda z: restoring([x], [z], t), (v,), (ones,))[1]])

        def rates(y, force, t):
            (y,) = y
            x, v, s, w = y[0, 0], y[1, 0], y[0, 1:], y[1, 1:]
            f, df = force
            if count > 1:  # at the clipped state, as the acceleration takes it
                r, r_x, r_v = system_forces(self._clipped_rows(x, 0), self._clipped_rows(v, 1))
                a = (f - r) * inverse_mass
            else:
                a = jnp.stack(acceleration(x, v, f, t))
                r_x, r_v = partials(x[0], v[0], t)
            explicit = df
            for one_pass in (family_pass, extra_pass):
                if one_pass is None:
                    continue
                value, slope_x, slope_v, pass_explicit = one_pass(x[0], v[0], t)
                a = a - value * inverse_mass
                r_x, r_v = [r_x[0] + slope_x], [r_v[0] + slope_v]
                if pass_explicit is not None:
                    explicit = explicit - pass_explicit[:, None]
            if d_restoring is not None:
                explicit = explicit - d_restoring(x, v, t)
            if d_mass is not None:
                explicit = explicit - a * d_mass
            for j, r in enumerate(r_x):
                explicit = explicit - r * s[:, j:j + 1]
            for j, r in enumerate(r_v):
                explicit = explicit - r * w[:, j:j + 1]
            dw = explicit * inverse_mass
            return (jnp.stack([jnp.concatenate([v[None], w]),
                               jnp.concatenate([a[None], jnp.broadcast_to(dw, s.shape)])]),)

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

    def _bank_columns(self, state):
        """One coordinate's family coefficients of ``state`` (internal, (..., P, 1, F)),
        family first: (F_bank, ..., P); none on the plain layout."""
        return jnp.moveaxis(state[..., 0, 2 * self.max_degree + self._n_extra:], -1, 0)

    def _has_families(self, state) -> bool:
        """Whether ``state`` (internal) is of one coordinate and holds the families'
        columns (not the plain layout)."""
        return (self.n_coordinates == 1 and bool(self.families)
                and self._bank_columns(state).shape[0] > 0)

    def _family_sum(self, bank, inner):
        """``terms(x, v)``: Σ c·g over the families for coefficients ``bank``
        (:meth:`_bank_columns`, (F, ..., P)) and inner constants ``inner`` (P, F_inner),
        one ``lax.switch`` per family the call's models use (:func:`_used_first`). Each
        branch takes the running sum and the whole arrays and returns the sum with its
        family's term added (fewer buffers per dispatch than returning the term)."""
        order, count = _used_first(bank)

        def branch(k, family, slots):
            def add(total, x, v, bank, inner):
                return total + bank[k] * family(x if family.role == "x" else v,
                                                inner[..., slots])

            return add

        branches = [branch(k, *p) for k, p in enumerate(zip(self.families, self._inner_slots))]

        def terms(x, v):
            zero = jnp.zeros(jnp.broadcast_shapes(bank.shape[1:], x.shape))
            return jax.lax.fori_loop(0, count, lambda i, total: jax.lax.switch(
                order[i], branches, total, x, v, bank, inner), zero)

        return terms

    def _family_pass(self, state, inner, d_state, d_inner, count: int):
        """``terms(x, v)`` for one coordinate: Σ c·g over the families (g at the clipped
        state, as :meth:`_acceleration_fn` takes it), its slopes by x and by x' ((P,)
        each), and along each of the ``count`` directions Σ (dc·g + c·∂g/∂θ·dθ) ((Q, P);
        ``None`` where the directions move no constant, as in the initial-state step).
        One ``lax.switch`` per family that the call's models or its directions use
        (:func:`_used_first`); each branch adds its family to the running sums."""
        bank = self._bank_columns(state)  # (F, P)
        d_bank = None if d_state is None else self._bank_columns(d_state)  # (F, Q, P)
        order, used = _used_first(bank if d_bank is None else
                                  jnp.concatenate([bank[:, None], d_bank], axis=1))
        bx, bv = self.record.bounds[0, 0], self.record.bounds[0, 1]
        directed = d_bank is not None or d_inner is not None

        def branch(k, family, slots):
            def add(sums, x, v, bank, inner, d_bank, d_inner):
                value, slope_x, slope_v, moved = sums
                c, theta = bank[k], inner[..., slots]
                z = x if family.role == "x" else v
                g, g_z = jax.jvp(lambda z: family(z, theta), (z,), (jnp.ones_like(z),))
                if d_bank is not None:
                    moved = moved + d_bank[k] * g
                if d_inner is not None and slots.stop > slots.start:
                    moved = moved + c * jax.vmap(lambda d: jax.jvp(
                        lambda th: family(z, th), (theta,), (d,))[1])(d_inner[..., slots])
                if family.role == "x":
                    slope_x = slope_x + c * g_z
                else:
                    slope_v = slope_v + c * g_z
                return value + c * g, slope_x, slope_v, moved

            return add

        branches = [branch(k, *p) for k, p in enumerate(zip(self.families, self._inner_slots))]

        def terms(x, v, t):
            del t  # the families are functions of the state alone
            x, v = jnp.clip(x, -bx, bx), jnp.clip(v, -bv, bv)
            zero = jnp.zeros_like(x)
            start = (zero, zero, zero, jnp.zeros(((count if directed else 0),) + x.shape))
            value, slope_x, slope_v, moved = jax.lax.fori_loop(
                0, used, lambda i, sums: jax.lax.switch(order[i], branches, sums, x, v, bank,
                                                        inner, d_bank, d_inner), start)
            return value, slope_x, slope_v, moved if directed else None

        return terms

    def _extra_pass(self, state, d_state):
        """``terms(x, v, t)`` for one coordinate, as :meth:`_family_pass`'s for the extra
        features: Σ c·f at the clipped state, its slopes by x and by x' ((P,) each), and
        Σ dc·f along the directions ((Q, P); ``None`` without ``d_state``), from one
        evaluation of every feature and its two partial derivatives
        (:attr:`_extra_jets`)."""
        first, count = 2 * self.max_degree, self._n_extra
        c = state[..., 0, first:first + count]  # (P, E)
        d_c = None if d_state is None else d_state[..., 0, first:first + count]  # (Q, P, E)
        bx, bv = self.record.bounds[0, 0], self.record.bounds[0, 1]

        def terms(x, v, t):
            x, v = jnp.clip(x, -bx, bx), jnp.clip(v, -bv, bv)
            f, f_x, f_v = (jnp.stack(jnp.broadcast_arrays(x, *part)[1:], axis=-1)
                           for part in self._extra_jets(x, v, t, self.record.extra_numbers))
            moved = None if d_c is None else jnp.sum(d_c * f, axis=-1)
            return (jnp.sum(c * f, axis=-1), jnp.sum(c * f_x, axis=-1),
                    jnp.sum(c * f_v, axis=-1), moved)

        return terms

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
        return rk4_scan(rates, y0, forces, saved, h=self.record.step, t0=self.record.start,
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
        import diffrax  # on first use (gpjax._integrate.rk4_solver)

        if self.split_stages:
            raise ValueError(HOLD_WITH_DIFFRAX)
        t0, h = self.record.start, self.record.step
        half = 0.5 * h
        inner = _no_inner(inner, mass)
        mass, state, forcing_matrix, y0 = self._internal(mass, state, forcing_matrix, y0)
        # The field is a static argument JAX's caches keep after the run: it holds this
        # evaluator weakly (else its compiled programs would live on) and takes the arrays
        # as diffrax's ``args``.
        ev = weakref.proxy(self)

        def field(t, y, args):  # y: (2, D, P)
            mass, state, inner, forcing_matrix, t0, half, speed = args
            index = jnp.clip(jnp.round((t - t0) / half).astype(jnp.int32), 0,
                             forcing_matrix.shape[0] - 1)
            velocity = jnp.clip(y[1], -speed, speed)
            acceleration = ev._acceleration_fn(mass, state, inner)
            return jnp.stack([velocity, jnp.stack(acceleration(y[0], y[1],
                                                               forcing_matrix[index], t))])

        solution = diffrax.diffeqsolve(
            diffrax.ODETerm(field), rk4_solver(), t0=t0, t1=t0 + h * self.n_steps, dt0=h,
            y0=jnp.transpose(y0, (2, 1, 0)),
            args=(mass, state, inner, forcing_matrix, t0, half, self.record.bounds[:, 1:]),
            saveat=diffrax.SaveAt(t0=True, steps=True),
            stepsize_controller=diffrax.ConstantStepSize(), max_steps=self.n_steps,
            throw=False, adjoint=adjoint or diffrax.RecursiveCheckpointAdjoint())
        return self._public(solution.ys[:: self.substeps, 0], 1)


def _forcing_rows(forcing_basis, forcing):
    """Forcing of every model at every stage row: (n_stage, P) from coefficients (P, K),
    (n_stage, D, P) from a system's (P, D, K)."""
    if forcing.ndim == 2:
        return forcing_basis @ forcing.T
    return jnp.einsum("sk,pdk->sdp", forcing_basis, forcing)


def _used_first(bank):
    """(order, count): the indices of the families (rows of ``bank``, (F, ...)) with a
    nonzero coefficient first, and how many there are — a loop over ``order[:count]``
    evaluates only the families a call uses, at one dispatch each (a ``lax.cond`` per
    family cost every call all F dispatches per RK4 stage)."""
    flags = jnp.any(bank.reshape(bank.shape[0], -1) != 0, axis=1)
    return jnp.argsort(~flags, stable=True), jnp.sum(flags)


def _no_inner(inner, mass):
    """``inner``, or an empty (P, 0) array for an evaluator call without families."""
    return jnp.zeros((mass.shape[0], 0)) if inner is None else inner
