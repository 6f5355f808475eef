"""Parts of :class:`gpjax._evaluator.PopulationEvaluator`: what only systems (several
coordinates, D > 1) use — the per-equation basis of own and relative coordinates, the
restoring forces of all equations as one stacked Horner sum, their D × D Jacobians from one
value-and-slope pass — and the initial-state Gauss–Newton step (one coordinate as before;
D coordinates with the normal equations summed in the scan)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import sympy as sp

from ._system_bank import bank_feature, bank_values, system_variables


def system_state_features(names: tuple[str, ...], max_degree: int, kinds: tuple[str, ...] = (),
                          scales=None) -> tuple[list[sp.Expr], ...]:
    """Per equation i of a system with coordinates ``names``: the powers 1 … max_degree of
    x_i, of x_i − x_j (j ≠ i, in order), of x_i' and of x_i' − x_j', then per bank kind
    (:mod:`gpjax._system_bank`) its feature of each of them (``scales``: the (D·2D,) sign
    θ; default 1). One name gives :func:`gpjax._evaluator.polynomial_state_features'`
    order (x, …, x', …)."""
    variables = system_variables(names)
    scales = np.ones(len(names) * 2 * len(names)) if scales is None else scales
    return tuple([z ** k for z in zs for k in range(1, max_degree + 1)]
                 + [bank_feature(kind, z, float(scales[i * len(zs) + p]))
                    for kind in kinds for p, z in enumerate(zs)]
                 for i, zs in enumerate(variables))


class SystemTerms:
    """Mixin of :class:`gpjax._evaluator.PopulationEvaluator` (uses its ``max_degree``,
    ``n_coordinates``, ``record`` (:mod:`gpjax._record`) and :meth:`scan_jvp`)."""

    def _system_coefficients(self, state):
        """(max_degree, D·2D, ..., P) coefficients of every equation's variables (the
        powers' order of :func:`system_state_features`) from ``state`` (..., P, D, F)."""
        d, count = self.max_degree, self.n_coordinates
        lead = state.ndim - 3
        shaped = state[..., :2 * count * d].reshape(state.shape[:-1] + (2 * count, d))
        order = (lead + 3, lead + 1, lead + 2, *range(lead), lead)
        return jnp.transpose(shaped, order).reshape(
            (d, 2 * count * count) + shaped.shape[:lead] + shaped.shape[lead:lead + 1])

    def _system_variables(self, xs, vs):
        """(D·2D, P): per equation i, x_i, x_i − x_j (j ≠ i), x_i', x_i' − x_j'."""
        count = self.n_coordinates
        return jnp.stack([w[e] if j == e else w[e] - w[j] for e in range(count)
                          for w in (xs, vs) for j in [e, *(j for j in range(count) if j != e)]])

    def _system_bank_coefficients(self, state):
        """(K, D·2D, ..., P) coefficients of the bank kinds' columns (after the powers,
        :func:`system_state_features`) from ``state`` (..., P, D, F)."""
        count, kinds = self.n_coordinates, len(self.kinds)
        lead = state.ndim - 3
        shaped = state[..., 2 * count * self.max_degree:].reshape(
            state.shape[:-1] + (kinds, 2 * count))
        order = (lead + 2, lead + 1, lead + 3, *range(lead), lead)
        return jnp.transpose(shaped, order).reshape(
            (kinds, 2 * count * count) + shaped.shape[:lead] + shaped.shape[lead:lead + 1])

    def _system_bank(self, state, lead: int):
        """``terms(z, slope)``: Σ over the bank kinds of c·g(z) (and with ``slope``, also
        Σ c·g'(z)) for the stacked variables ``z`` (D·2D, [1]*lead, P); a kind no model of
        the call uses is skipped (``lax.cond`` on a loop-invariant flag)."""
        c = self._system_bank_coefficients(state)
        used = [jnp.any(c_k != 0) for c_k in c]
        scales = self.record.sign_scales.reshape((-1,) + (1,) * (lead + 1))

        def terms(z, slope: bool):
            value = jnp.zeros(jnp.broadcast_shapes(z.shape, c.shape[1:]))
            derivative = value
            for kind, c_k, flag in zip(self.kinds, c, used):
                def on(kind=kind, c_k=c_k):
                    g, dg = bank_values(kind, z, scales)
                    return c_k * g, (c_k * dg if slope else jnp.zeros_like(value))

                term, d_term = jax.lax.cond(flag, on, lambda: (value * 0.0, value * 0.0))
                value, derivative = value + term, derivative + d_term
            return value, derivative

        return terms

    def _system_restoring(self, state, *, stacked: bool):
        """:meth:`_restoring_fn` of a system (D > 1): all equations' variables stacked into
        one (D·2D, P) array, one Horner sum over it and the bank's kinds on it — a few large
        operations per RK4 stage instead of D·2D·max_degree small ones."""
        d, count = self.max_degree, self.n_coordinates
        lead = state.ndim - 3
        c = self._system_coefficients(state)
        bank = self._system_bank(state, lead) if self.kinds else None

        def restoring(xs, vs, t):
            z = self._system_variables(xs, vs)
            z = z.reshape(z.shape[:1] + (1,) * lead + z.shape[1:])
            total = c[d - 1]
            for k in range(d - 2, -1, -1):
                total = total * z + c[k]
            total = total * z
            if bank is not None:
                total = total + bank(z, False)[0]
            total = total.reshape((count, 2 * count) + total.shape[1:]).sum(axis=1)
            return jnp.moveaxis(total, 0, -2) if stacked else [total[e] for e in range(count)]

        return restoring

    def _system_forces(self, state):
        """``forces(xs, vs)``: a system's restoring forces r (D, P) and their partials
        ∂r/∂x_j and ∂r/∂x_j' ((D, P) each, j = 1 … D), from one Horner pass that carries
        each variable's derivative: the variational step's right-hand side without a second
        pass for r. The chain rule through x_e − x_j gives ∂r_e/∂x_e the sum of equation
        e's slopes and ∂r_e/∂x_j (j ≠ e) minus the slope of x_e − x_j (written out: an
        einsum with the 0/±1 chain matrix compiled to four small batched products per step,
        13 % of a D = 2 evaluation with the initial-state step)."""
        d, count = self.max_degree, self.n_coordinates
        c = self._system_coefficients(state)
        bank = self._system_bank(state, 0) if self.kinds else None

        def forces(xs, vs):
            z = self._system_variables(xs, vs)
            value, slope = c[d - 1], jnp.zeros_like(z)
            for k in range(d - 2, -1, -1):
                slope = slope * z + value
                value = value * z + c[k]
            slope = slope * z + value
            value = value * z
            if bank is not None:
                g, dg = bank(z, True)
                value, slope = value + g, slope + dg
            slope = slope.reshape((count, 2, count) + z.shape[1:])  # (eq. e, x or x', pos.)
            own = slope.sum(axis=2)

            def column(w: int, j: int):  # ∂r_e/∂x_j (w 0) or ∂r_e/∂x_j' (1), every e
                return jnp.stack([own[e, w] if e == j else
                                  -slope[e, w, j + 1 if j < e else j] for e in range(count)])

            r = value.reshape((count, 2 * count) + z.shape[1:]).sum(axis=1)
            return (r, [column(0, j) for j in range(count)],
                    [column(1, j) for j in range(count)])

        return forces

    def _fitted_initial_conditions(self, mass, state, forcing_matrix, y0, inner):
        """(P, D, 2) initial states after one Gauss–Newton step of every model's (x0, x0')
        per coordinate (D = 1: (P, 2)), residuals weighted per coordinate as in the
        objective. The normal equations SᵀS, Sᵀr are summed inside the scan that
        integrates the sensitivities (:meth:`scan_jvp`'s ``fold``): the (N, D, 2D, P)
        sensitivities are never written, which was half the step's time (P = 500, D = 2)
        and a fifth of a family model's evaluation for D = 1."""
        count = self.n_coordinates
        q = 2 * count
        directions = jnp.broadcast_to(jnp.eye(q).reshape((q,) + y0.shape[1:])[:, None],
                                      (q,) + y0.shape)
        measured, valid = self.record.responses, self.record.valid
        weights = self.record.weights[:, None]

        def add(acc, y, k):  # y: (2, 1 + Q, D, P) at sample k
            a, b = acc
            row = jax.lax.dynamic_index_in_dim(measured, k, keepdims=False)
            residual = (row[:, None] - y[0, 0]) * weights  # (D, P)
            s = y[0, 1:] * weights  # (Q, D, P)
            # Sums over the D coordinates written as adds of their slices, the whole Q × Q
            # product taken: one fused kernel per sum (a triangle's gathers and a reduction
            # over D were four more kernels per sample, ~8 % of a D = 2 evaluation).
            da = sum(s[:, None, e] * s[None, :, e] for e in range(count))  # (Q, Q, P)
            db = sum(s[:, e] * residual[e] for e in range(count))
            on = valid[k] > 0  # a sample of the record, not of its padding
            da, db = jnp.where(on, da, 0.0), jnp.where(on, db, 0.0)
            return a + da, b + db

        p = y0.shape[0]
        a, b = self.scan_jvp(mass, state, forcing_matrix, y0, directions, inner=inner,
                             fold=(add, (jnp.zeros((q, q, p)), jnp.zeros((q, p)))))
        delta = _solve_normal_equations(jnp.moveaxis(a, -1, 0), jnp.moveaxis(b, -1, 0))
        return y0 + delta.reshape(y0.shape)


def _solve_normal_equations(a, b):
    """(P, Q) solutions of the (P, Q, Q) normal equations ``a``·δ = ``b``; zero where
    singular or not finite."""
    scale = jnp.max(jnp.diagonal(a, axis1=1, axis2=2), axis=1)[:, None, None]
    delta = jnp.linalg.solve(a + 1e-12 * scale * jnp.eye(a.shape[-1]), b[..., None])[..., 0]
    usable = jnp.all(jnp.isfinite(delta), axis=1, keepdims=True)
    return jnp.where(usable, delta, 0.0)
