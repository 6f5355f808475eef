"""The refinement's stop rule: Levenberg–Marquardt stops once its accepted point lies within
0.1 standard error of the Gauss–Newton optimum (gpjax._levenberg_marquardt)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest

from gpjax._levenberg_marquardt import (RESOLUTION, ResolvedLevenbergMarquardt,
                                         standard_errors_to_optimum)

jax.config.update("jax_enable_x64", True)

T = jnp.linspace(0.0, 10.0, 400)
TRUTH = jnp.array([1.3, 0.25, 2.1, 0.4])


def _model(p):
    return p[0] * jnp.exp(-p[1] * T) * jnp.sin(p[2] * T + p[3])


MEASURED = _model(TRUTH) + 0.05 * jax.random.normal(jax.random.PRNGKey(0), T.shape)
DOF = T.size - TRUTH.size


def _residual(p, args):
    return _model(p) - MEASURED


def _plain_iterates(start, steps=60):
    """The accepted points of optimistix's own Levenberg–Marquardt from ``start``, stepped by
    hand: (points, steps taken to reach each)."""
    solver = optx.LevenbergMarquardt(rtol=1e-12, atol=1e-12)
    fn = lambda y, args: (_residual(y, args), None)  # noqa: E731
    f_struct = jax.eval_shape(lambda: _residual(start, None))
    state = solver.init(fn, start, None, {}, f_struct, None, frozenset())
    y, points, taken = start, [], []
    step = eqx.filter_jit(lambda y, state: solver.step(fn, y, None, {}, state, frozenset())[:2])
    for n in range(1, steps + 1):
        y_new, state = step(y, state)
        if n == 1 or not np.array_equal(y_new, y):
            points.append(np.asarray(y_new))
            taken.append(n)
        y = y_new
    return points, taken


def _distance(p):
    return float(standard_errors_to_optimum(jax.jacfwd(_model)(p), _residual(p, None), DOF))


def _mahalanobis(p, optimum):
    jacobian = jax.jacfwd(_model)(optimum)
    sigma2 = float(jnp.sum(_residual(optimum, None) ** 2)) / DOF
    d = np.asarray(p - optimum)
    return float(np.sqrt(d @ np.asarray(jacobian.T @ jacobian) @ d / sigma2))


def test_the_distance_is_the_mahalanobis_distance_of_a_linear_fit_and_ignores_empty_columns():
    rng = np.random.default_rng(1)
    design = rng.normal(size=(200, 3))
    measured = design @ np.array([1.0, -2.0, 0.5]) + 0.1 * rng.normal(size=200)
    optimum = np.linalg.lstsq(design, measured, rcond=None)[0]
    sigma2 = np.sum((measured - design @ optimum) ** 2) / 197
    point = optimum + np.array([0.01, -0.02, 0.005])
    residual = measured - design @ point
    expected = np.sqrt((point - optimum) @ design.T @ design @ (point - optimum)
                       / (residual @ residual / 197))
    padded = np.concatenate([design, np.zeros((200, 2))], axis=1)  # unused constants
    got = float(standard_errors_to_optimum(jnp.asarray(padded), jnp.asarray(residual), 197))
    assert got == pytest.approx(expected, rel=1e-9)
    assert sigma2 > 0


@pytest.mark.parametrize("start", [TRUTH * jnp.array([1.2, 0.8, 1.02, 1.1]),
                                   TRUTH * jnp.array([0.5, 2.0, 0.97, 0.3])])
def test_the_solve_stops_at_the_first_resolved_point_of_the_plain_solver(start):
    points, taken = _plain_iterates(start)
    optimum = points[-1]
    first = next(i for i, p in enumerate(points) if _distance(jnp.asarray(p)) < RESOLUTION)
    solver = ResolvedLevenbergMarquardt(1e-12, 1e-12, dof=DOF)
    solution = optx.least_squares(_residual, solver, start, max_steps=60, throw=False)
    assert solution.result == optx.RESULTS.successful
    np.testing.assert_allclose(solution.value, points[first], rtol=1e-10, atol=1e-12)
    assert int(solution.stats["num_steps"]) == taken[first] < taken[-1]
    assert _mahalanobis(solution.value, optimum) < RESOLUTION
    # and not earlier: every accepted point before it was farther than the resolution
    assert all(_distance(jnp.asarray(p)) >= RESOLUTION for p in points[:first])
