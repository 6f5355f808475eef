"""Levenberg–Marquardt that stops when the fit is resolved to its own uncertainty.

optimistix's Levenberg–Marquardt stops on a Cauchy test: every residual and every
parameter changed by less than ``rtol``/``atol`` between two accepted steps. Set to rounding
level (1e-9), a refinement runs until it meets it by chance or reaches its step cap (the
same Silverbox refit took 17 or 38 steps); set loosely, it stops wherever a damped step is
short, which in a narrow valley (the scale inside sinh(a·x) against its coefficient) is far
from the optimum.

:class:`ResolvedLevenbergMarquardt` keeps optimistix's steps and adds a **score test** at
each accepted point: to first order the full Gauss–Newton step would lower |r|² by
|P_J r|² (P_J the projection onto the Jacobian's columns). With the residual variance
σ² = |r|²/dof (dof = fitted residuals − free constants), the optimum then lies |P_J r|/σ
standard errors away, jointly (covariance σ²(JᵀJ)⁻¹). The solve stops when that distance
is below :data:`RESOLUTION`: a further step cannot move the fit by more than a tenth of
its own uncertainty. The undamped step, not the one taken, so a short damped step in a
narrow valley does not stop it. This rule is gpjax's, not the paper's (docs/method.md).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import lineax as lx
import optimistix as optx

#: Stop when the optimum lies within this many standard errors (Mahalanobis distance).
RESOLUTION = 0.1


def linear_solver(jacobian: str = "variational"):
    """The damped Gauss–Newton step's linear solver. With the variational Jacobian the
    normal equations (JᵀJ + λI)·δ = Jᵀr by LU: the default QR of the (N + k) × k system
    slows sharply on XLA's CPU from k = 8 (optimistix alone, 64 models: 1,204 models/s at
    k = 6, 583 at k = 8, 248 at k = 12; LU 1,604 at k = 8; ``lm_floor`` in
    benchmarks/bench_population.py). Constants are scaled by their start values, so JᵀJ
    stays well conditioned. Autodiff through a while loop (diffrax) cannot be transposed,
    so that path keeps QR. This module (and with it optimistix and lineax) is imported when
    a refinement is traced (:meth:`gpjax._refine.Refiner._refine_one`)."""
    return lx.Normal(lx.LU()) if jacobian == "variational" else lx.QR()


def standard_errors_to_optimum(jacobian, residual, dof):
    """|P_J r|/σ with σ² = |r|²/``dof``: how many standard errors the Gauss–Newton optimum
    lies from the point of ``residual`` (N,) with ``jacobian`` (N, k). Columns of zeros
    (padding, unused constants) are dropped; the normal matrix is scaled to a unit
    diagonal before it is solved (LU: an SVD in this program hangs on two host devices)."""
    gradient = jacobian.T @ residual
    normal = jacobian.T @ jacobian
    diagonal = jnp.diag(normal)
    used = diagonal > 0
    scale = jnp.where(used, 1 / jnp.sqrt(jnp.where(used, diagonal, 1.0)), 0.0)
    scaled = normal * scale[:, None] * scale[None, :] + jnp.diag(jnp.where(used, 0.0, 1.0))
    gradient = gradient * scale
    explained = gradient @ jnp.linalg.solve(scaled, gradient)
    return jnp.sqrt(jnp.maximum(explained, 0.0) * dof / jnp.maximum(residual @ residual,
                                                                    jnp.finfo(float).tiny))


class ResolvedLevenbergMarquardt(optx.LevenbergMarquardt):
    """optimistix's Levenberg–Marquardt that also stops when the last accepted point is
    within :data:`RESOLUTION` standard errors of the Gauss–Newton optimum (module
    docstring); ``dof``: fitted residuals less free constants (a number or a traced
    scalar). Residuals must be one flat vector or an array the Jacobian flattens
    alike."""

    dof: jnp.ndarray

    def __init__(self, rtol: float, atol: float, *, dof, linear_solver=lx.QR()):
        super().__init__(rtol, atol, linear_solver=linear_solver)
        self.dof = jnp.asarray(dof, dtype=float)

    def step(self, fn, y, args, options, state, tags):
        y, state, aux = super().step(fn, y, args, options, state, tags)
        residual = jnp.ravel(state.f_info.residual)
        jacobian = state.f_info.jac.as_matrix()
        resolved = standard_errors_to_optimum(jacobian, residual, self.dof) < RESOLUTION
        return y, eqx.tree_at(lambda s: s.terminate, state, state.terminate | resolved), aux
