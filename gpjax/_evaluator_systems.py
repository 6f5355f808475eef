"""The parts of :class:`gpjax._evaluator.PopulationEvaluator` that only systems (several
coordinates, D > 1) use: the per-equation basis of own and relative coordinates, the
restoring forces of all equations as one stacked Horner sum, their D × D Jacobians from one
value-and-slope pass, and the initial-state Gauss–Newton step of D coordinates."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import sympy as sp


def system_state_features(names: tuple[str, ...], max_degree: int) -> tuple[list[sp.Expr], ...]:
    """Per equation i of a system with coordinates ``names``: the powers 1 … max_degree of
    x_i, of x_i − x_j (j ≠ i, in order), of x_i' and of x_i' − x_j'. One name gives
    :func:`gpjax._evaluator.polynomial_state_features`' order (x, …, x', …)."""
    positions = [sp.Symbol(name) for name in names]
    velocities = [sp.Symbol(f"{name}_dot") for name in names]
    out = []
    for i in range(len(names)):
        variables = [z[i] - z[j] if j != i else z[i] for z in (positions, velocities)
                     for j in [i, *(j for j in range(len(names)) if j != i)]]
        out.append([z ** k for z in variables for k in range(1, max_degree + 1)])
    return tuple(out)


class SystemTerms:
    """Mixin of :class:`gpjax._evaluator.PopulationEvaluator` (uses its ``max_degree`` and
    ``n_coordinates``)."""

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

    def _system_restoring(self, state, *, stacked: bool):
        """:meth:`_restoring_fn` of a system (D > 1, polynomial basis): all equations'
        variables stacked into one (D·2D, P) array and one Horner sum over it — a few large
        operations per RK4 stage instead of D·2D·max_degree small ones."""
        d, count = self.max_degree, self.n_coordinates
        lead = state.ndim - 3
        c = self._system_coefficients(state)

        def restoring(xs, vs, t):
            z = self._system_variables(xs, vs)
            z = z.reshape(z.shape[:1] + (1,) * lead + z.shape[1:])
            total = c[d - 1]
            for k in range(d - 2, -1, -1):
                total = total * z + c[k]
            total = (total * z).reshape((count, 2 * count) + total.shape[1:]).sum(axis=1)
            return jnp.moveaxis(total, 0, -2) if stacked else [total[e] for e in range(count)]

        return restoring

    def _system_partials(self, state):
        """``partials(xs, vs)``: ∂r/∂x_j and ∂r/∂x_j' ((D, P) each, j = 1 … D) of a
        system's restoring forces, from one Horner pass that carries each variable's
        derivative (the chain rule through x_i − x_j is a constant 0/±1 matrix)."""
        d, count = self.max_degree, self.n_coordinates
        c = self._system_coefficients(state)
        chain = np.zeros((2, count, 2, count, count))  # (x or x', eq., x or x', position, j)
        for e in range(count):
            for position, j in enumerate([e, *(j for j in range(count) if j != e)]):
                for w in (0, 1):
                    chain[w, e, w, position, e] += 1.0
                    if j != e:
                        chain[w, e, w, position, j] -= 1.0
        chain = jnp.asarray(chain.reshape(2, count, 2 * count, count))

        def partials(xs, vs):
            z = self._system_variables(xs, vs)
            value, slope = c[d - 1], jnp.zeros_like(z)
            for k in range(d - 2, -1, -1):
                slope = slope * z + value
                value = value * z + c[k]
            slope = (slope * z + value).reshape((count, 2 * count) + z.shape[1:])
            out = jnp.einsum("wekj,ekp->wjep", chain, slope)
            return [out[0, j] for j in range(count)], [out[1, j] for j in range(count)]

        return partials


def gauss_newton_step(measured, weights, base, sensitivity):
    """(P, 2D) step of every model's initial states (x0, x0' per coordinate) for
    ``base`` (N, D, P) and its ``sensitivity`` (N, D, 2D, P), residuals weighted per
    coordinate; zero where the normal equations are singular or not finite."""
    w = jnp.asarray(weights)[:, None]
    residual = (jnp.asarray(measured)[:, :, None] - base) * w
    sensitivity = sensitivity * w[:, None]
    a = jnp.einsum("ndqp,ndrp->pqr", sensitivity, sensitivity)
    b = jnp.einsum("ndqp,ndp->pq", sensitivity, residual)
    scale = jnp.max(jnp.diagonal(a, axis1=1, axis2=2), axis=1)[:, None, None]
    delta = jnp.linalg.solve(a + 1e-12 * scale * jnp.eye(a.shape[-1]), b[..., None])[..., 0]
    usable = jnp.all(jnp.isfinite(delta), axis=1, keepdims=True)
    return jnp.where(usable, delta, 0.0)
