import os
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import sympy as sp
from scipy.integrate import solve_ivp

from gpjax import Measurement, Symbols
from gpjax.engine import PopulationEvaluator, objective_parts
from gpjax._coefficients import Population
from gpjax._evaluator import DIVERGED, NONPOSITIVE_MASS, OK, PENALTY
from gpjax._integrate import enable_float64
from gpjax._objective import _amplitude, _dft_matrix

S = Symbols("x", "t", ("u",))


def _measurement(n=401, duration=2.0):
    t = np.linspace(0.0, duration, n)
    u = np.sin(2 * np.pi * 1.3 * t) + 0.5 * np.cos(2 * np.pi * 3.1 * t)
    response = 0.1 * np.sin(2 * np.pi * 0.7 * t) + 0.01 * t
    return Measurement(time=t, response=response, inputs={"u": u}, response_name="x",
                       time_name="t")


def _random_models(evaluator, rng, count):
    """Stable models: m > 0, stiffness k1 > 0, k3 >= 0, damping c1 >= 0, an input gain."""
    columns = {str(f): i for i, f in enumerate(evaluator.state_features)}
    u = evaluator.forcing_index(S.u[0])
    one = evaluator.forcing_index(sp.Integer(1))
    pop = evaluator.empty(count)
    for i in range(count):
        pop.mass[i] = rng.uniform(0.5, 2.0)
        pop.state[i, columns["x"]] = rng.uniform(5.0, 40.0)
        pop.state[i, columns["x**3"]] = rng.uniform(0.0, 50.0)
        pop.state[i, columns["x**2"]] = rng.uniform(-5.0, 5.0)
        pop.state[i, columns["x_dot"]] = rng.uniform(0.0, 1.0)
        pop.forcing[i, u] = 1.0
        pop.forcing[i, one] = rng.uniform(-0.5, 0.5)
        pop.y0[i] = rng.uniform(-0.1, 0.1, size=2)
    return pop


def test_batched_evaluator_matches_solve_ivp_on_20_random_models():
    measurement = _measurement()
    evaluator = PopulationEvaluator(measurement, S, max_degree=3, substeps=8, batch=20)
    rng = np.random.default_rng(7)
    pop = _random_models(evaluator, rng, 20)
    simulated, scores = evaluator.simulate(pop)
    assert np.all(scores.status == OK)
    columns = {str(f): i for i, f in enumerate(evaluator.state_features)}
    t, u = measurement.time, measurement.inputs["u"]
    for i in range(20):
        m, c = pop.mass[i], pop.state[i]
        g_u = pop.forcing[i, evaluator.forcing_index(S.u[0])]
        g_1 = pop.forcing[i, 1]

        def field(time, y):
            x, v = y
            force = g_u * np.interp(time, t, u) + g_1
            restoring = (c[columns["x"]] * x + c[columns["x**2"]] * x**2
                         + c[columns["x**3"]] * x**3 + c[columns["x_dot"]] * v)
            return [v, (force - restoring) / m]

        reference = solve_ivp(field, (t[0], t[-1]), pop.y0[i], t_eval=t, method="DOP853",
                              rtol=1e-12, atol=1e-14, max_step=t[1] - t[0]).y[0]
        error = np.max(np.abs(simulated[i] - reference)) / np.max(np.abs(reference))
        assert error < 1e-6, (i, error)


def test_objective_equals_a_hand_computation():
    rng = np.random.default_rng(3)
    measured = rng.standard_normal(64)
    calculated = measured + 0.1 * rng.standard_normal(64)
    f_time, f_freq, rms = objective_parts(measured[:, None], calculated[:, None], 5)
    assert float(f_time[0]) == pytest.approx(np.sqrt(np.sum((measured - calculated) ** 2)))
    assert float(rms[0]) == pytest.approx(np.sqrt(np.mean((measured - calculated) ** 2)))
    n = 64
    def amplitudes(signal):
        out = []
        for j in range(5):
            value = abs(sum(signal[k] * np.exp(-2j * np.pi * j * k / n) for k in range(n)))
            out.append(value / n if j == 0 else 2 * value / n)
        return np.array(out)
    expected = np.sum(np.abs(amplitudes(measured) - amplitudes(calculated)))
    assert float(f_freq[0]) == pytest.approx(expected, rel=1e-10)


def test_weights_combine_the_two_parts():
    measurement = _measurement()
    evaluator = PopulationEvaluator(measurement, S, max_degree=3, w_time=2.0, w_freq=0.5)
    pop = _random_models(evaluator, np.random.default_rng(0), 3)
    scores = evaluator.score(pop)
    np.testing.assert_allclose(scores.objective, 2.0 * scores.f_time + 0.5 * scores.f_freq)


def test_one_bad_candidate_never_spoils_the_others():
    measurement = _measurement()
    evaluator = PopulationEvaluator(measurement, S, max_degree=3, batch=8)
    pop = _random_models(evaluator, np.random.default_rng(1), 7)
    alone = evaluator.score(Population(pop.mass[:2], pop.state[:2], pop.forcing[:2], pop.y0[:2]))
    pop.state[2, 0] = -1e6        # x'' = +1e6 x: explodes
    pop.mass[3] = 0.0             # zero mass
    pop.mass[4] = -1.0            # negative mass
    pop.state[5, 2] = -1e9        # strongly softening cubic: blows up
    pop.y0[5] = [5.0, 0.0]
    pop.mass[6] = 1e-9            # stiff: omega*h ~ 500, beyond RK4's stability region
    scores = evaluator.score(pop)
    assert list(scores.status[2:]) == [DIVERGED, NONPOSITIVE_MASS, NONPOSITIVE_MASS, DIVERGED,
                                       DIVERGED]
    assert np.all(np.isfinite(scores.objective))
    assert np.all(scores.objective[2:] == PENALTY)
    np.testing.assert_array_equal(scores.objective[:2], alone.objective)


def test_results_do_not_depend_on_position_in_the_batch_and_barely_on_its_shape():
    measurement = _measurement()
    small = PopulationEvaluator(measurement, S, max_degree=3, batch=4)
    large = PopulationEvaluator(measurement, S, max_degree=3, batch=16)
    pop = _random_models(small, np.random.default_rng(5), 10)
    order = np.random.default_rng(6).permutation(10)
    shuffled = Population(pop.mass[order], pop.state[order], pop.forcing[order], pop.y0[order])
    # Same batch shape: bit for bit, wherever a model sits.
    np.testing.assert_array_equal(small.score(shuffled).objective, small.score(pop).objective[order])
    # Another batch shape: XLA may vectorise differently; the last bit may differ.
    _random_models(large, np.random.default_rng(5), 10)
    np.testing.assert_allclose(large.score(pop).objective, small.score(pop).objective, rtol=1e-13)


def test_scan_and_diffrax_integrators_agree():
    measurement = _measurement()
    scan = PopulationEvaluator(measurement, S, max_degree=3, substeps=2, batch=6)
    reference = PopulationEvaluator(measurement, S, max_degree=3, substeps=2, batch=6,
                                    integrator="diffrax")
    pop = _random_models(scan, np.random.default_rng(11), 6)
    _random_models(reference, np.random.default_rng(11), 6)
    x_scan, s_scan = scan.simulate(pop)
    x_diffrax, s_diffrax = reference.simulate(pop)
    np.testing.assert_allclose(x_scan, x_diffrax, rtol=0, atol=1e-12 * np.abs(x_diffrax).max())
    np.testing.assert_array_equal(s_scan.status, s_diffrax.status)


def test_unknown_integrator_is_refused():
    with pytest.raises(ValueError, match="integrator"):
        PopulationEvaluator(_measurement(), S, integrator="euler")


def test_initial_condition_fit_recovers_a_models_own_start():
    measurement = _measurement()
    plain = PopulationEvaluator(measurement, S, max_degree=3, batch=4)
    pop = _random_models(plain, np.random.default_rng(2), 4)
    pop.state[:, 1:] = 0.0  # linear models: one Gauss–Newton step is exact
    simulated, _ = plain.simulate(pop)
    own = Measurement(time=measurement.time, response=simulated[0], inputs=measurement.inputs,
                      response_name="x", time_name="t")
    fitter = PopulationEvaluator(own, S, max_degree=3, batch=4, fit_initial_conditions=True)
    _random_models(fitter, np.random.default_rng(2), 4)
    start = Population(pop.mass[:1], pop.state[:1], pop.forcing[:1], np.zeros((1, 2)))
    scores = fitter.score(start)
    np.testing.assert_allclose(scores.y0[0], pop.y0[0], rtol=1e-6, atol=1e-9)
    assert scores.f_time[0] < 1e-8


@pytest.mark.parametrize("shape", [(4000, 3), (4000, 2, 3)])  # models; coordinates, models
def test_dft_matrix_and_fft_amplitudes_agree(shape):
    enable_float64()  # as every evaluator does; the test may run first
    signal = np.random.default_rng(4).standard_normal(shape)
    by_matrix = _amplitude(jnp.asarray(_dft_matrix(4000, 400)), signal, 400)
    by_fft = _amplitude(jnp.asarray(_dft_matrix(4000, 600)), signal, 400)
    assert _dft_matrix(4000, 600).shape == (1, 600)  # over the size limit: weights only
    assert by_matrix.shape == by_fft.shape == (400,) + shape[1:]
    np.testing.assert_allclose(by_fft, by_matrix, rtol=1e-10, atol=1e-14)


def test_variational_scan_equals_forward_mode_autodiff_of_the_solve():
    """scan_jvp's sensitivities = jax.jvp of scan_solve, for directions in every kind of
    constant (mass, polynomial and extra state features, forcing, initial state); the
    extra features (a tanh, a parametric term, a dead zone's kinks, a jump) with their
    slopes from sympy in one pass (_extra_pass), the rest by the generic path."""
    measurement = _measurement()
    extra = (sp.tanh(20 * S.x_dot), sp.cos(9 * S.t) * S.x,
             sp.Abs(S.x - 0.01) - sp.Abs(S.x + 0.02), sp.sign(S.x_dot))
    evaluator = PopulationEvaluator(measurement, S, max_degree=3, batch=6,
                                    extra_state_features=extra)
    pop = _random_models(evaluator, np.random.default_rng(3), 6)
    pop.state[:, -4:] = [0.3, 4.0, 2.0, 0.05]
    basis = jnp.asarray(evaluator._forcing_basis)
    mass, state, forcing, y0 = map(jnp.asarray, (pop.mass, pop.state, pop.forcing, pop.y0))
    rng = np.random.default_rng(4)
    q = 3
    d_mass, d_state, d_forcing, d_y0 = (jnp.asarray(rng.normal(size=(q,) + a.shape))
                                        for a in (pop.mass, pop.state, pop.forcing, pop.y0))
    x, sensitivities = evaluator.scan_jvp(
        mass, state, basis @ forcing.T, y0, d_y0, d_mass=d_mass, d_state=d_state,
        d_forcing=jnp.einsum("qpk,sk->sqp", d_forcing, basis))

    def solve(m, c, g, start):
        return evaluator.scan_solve(m, c, basis @ g.T, start)

    for j in range(q):
        x_ad, s_ad = jax.jvp(solve, (mass, state, forcing, y0),
                             (d_mass[j], d_state[j], d_forcing[j], d_y0[j]))
        np.testing.assert_allclose(x, x_ad, rtol=0, atol=1e-14 * float(jnp.max(jnp.abs(x_ad))))
        np.testing.assert_allclose(sensitivities[:, j], s_ad, rtol=0,
                                   atol=1e-10 * float(jnp.max(jnp.abs(s_ad))))


@pytest.mark.parametrize("sizes", [(16, 128, 512), (8,), (16, 100)])
def test_chunk_plans_cover_the_rows_and_never_pad_more_than_one_call_would(sizes):
    from gpjax._coefficients import CALL_OVERHEAD_ROWS, chunk_sizes

    for count in range(0, 3 * max(sizes) + 3):
        plan = chunk_sizes(count, sizes)
        assert set(plan) <= set(sizes) and sum(plan) >= count
        assert sum(plan) - count < max(sizes)  # no call is wholly padding
        remainder = count % max(sizes)
        if remainder:
            single = min(s for s in sizes if s >= remainder) + CALL_OVERHEAD_ROWS
            tail = plan[count // max(sizes):]
            assert sum(tail) + CALL_OVERHEAD_ROWS * len(tail) <= single


def test_a_call_of_a_few_models_runs_at_a_small_compiled_size():
    measurement = _measurement()
    evaluator = PopulationEvaluator(measurement, S, max_degree=3, batch=200)
    assert evaluator.batch_sizes == (16, 128, 200)
    pop = _random_models(evaluator, np.random.default_rng(7), 150)
    few = Population(pop.mass[:3], pop.state[:3], pop.forcing[:3], pop.y0[:3])
    alone = evaluator.score(few).objective
    assert evaluator.compile_count == 1  # one executable, of 16 rows
    together = evaluator.score(pop).objective  # 16 + 16 + 128 rows, not 200
    assert evaluator.compile_count == 2
    np.testing.assert_allclose(alone, together[:3], rtol=1e-13)
    assert np.all(np.isfinite(together))


def test_forcing_columns_past_the_capacity_are_cut_when_they_hold_nothing():
    """A population laid out on the estimation part's evaluator (a shorter record: a wider
    forcing capacity) is simulated on the whole record's (the diagnosis on a 20,000-sample
    Silverbox segment raised a broadcast error here); a coefficient past the capacity is
    refused."""
    from gpjax._evaluator import _pad_columns

    wide = np.zeros((8, 64))
    wide[:, :3] = 1.0
    assert _pad_columns(wide, 16).shape == (8, 16)
    assert np.array_equal(_pad_columns(wide, 16)[:, :3], wide[:, :3])
    assert _pad_columns(wide[:, :16], 64).shape == (8, 64)
    wide[0, 20] = 1.0
    with pytest.raises(ValueError, match="past this evaluator's 16 columns"):
        _pad_columns(wide, 16)


def test_a_batch_capped_by_memory_splits_over_no_more_devices_than_its_models():
    """Four host devices, a memory cap of three models: the batch is three, split over
    three devices (rounded up to a multiple of four it was four models, past the cap),
    and scores match one device's."""
    import subprocess
    import sys
    import textwrap

    program = textwrap.dedent("""
        import numpy as np
        from gpjax import Measurement, Symbols, _evaluator
        from gpjax._integrate import enable_float64
        enable_float64()
        import jax
        t = np.linspace(0.0, 2.0, 401)
        measurement = Measurement(time=t, response=np.sin(3 * t), inputs={"u": np.cos(2 * t)},
                                  response_name="x", time_name="t")
        symbols = Symbols("x", "t", ("u",))
        rows = 2 * 400 + 1
        _evaluator.STAGE_ELEMENTS_PER_CALL = 3 * rows
        ev = _evaluator.PopulationEvaluator(measurement, symbols, max_degree=3,
                                            pad_to_bucket=False)
        one = _evaluator.PopulationEvaluator(measurement, symbols, max_degree=3,
                                             pad_to_bucket=False,
                                             devices=jax.devices()[:1])
        def scores(evaluator):
            column = evaluator.forcing_index(symbols.u[0])
            population = evaluator.empty(5)
            population.state[:, 0] = [5.0, 9.0, 12.0, 3.0, 7.0]
            population.forcing[:, column] = 1.0
            return evaluator.score(population).objective
        same = np.allclose(scores(ev), scores(one), rtol=1e-12)
        print(len(jax.devices()), len(ev.devices), ev.batch, same)
    """)
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    done = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True,
                          timeout=300, env=env | {"JAX_PLATFORMS": "cpu", "XLA_FLAGS":
                                                  "--xla_force_host_platform_device_count=4"})
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split() == ["4", "3", "3", "True"]


def test_the_numbers_of_extra_features_are_data_not_the_program():
    # Two records whose effects carry different numbers (a sign's scale, a backlash's
    # edges, a line's frequency) share one program key, and each evaluator integrates its
    # own numbers: the response equals one with those numbers compiled into a fresh
    # evaluator of a single feature set, and differs from the other set's.
    measurement = _measurement()

    def effects(scale, edge, frequency):
        return (sp.tanh(scale * S.x_dot), sp.Abs(S.x - edge) / 2,
                S.x * sp.cos(frequency * S.t))

    a = PopulationEvaluator(measurement, S, max_degree=3, batch=4,
                            extra_state_features=effects(20.0, 0.01, 9.0))
    b = PopulationEvaluator(measurement, S, max_degree=3, batch=4,
                            extra_state_features=effects(35.0, 0.03, 11.0))
    assert a.key == b.key and a.time_key == b.time_key
    np.testing.assert_array_equal(a.record_arrays.extra_numbers, [20.0, 0.5, -0.01, 9.0])
    pop = _random_models(a, np.random.default_rng(5), 4)
    pop.state[:, -3:] = [0.3, 40.0, 4.0]
    for g in a.forcing_features:
        b.forcing_index(g)
    x_a, x_b = a.simulate(pop)[0], b.simulate(pop)[0]
    assert np.max(np.abs(x_a - x_b)) > 1e-3 * np.max(np.abs(x_a))
    # the same numbers by hand: the jets evaluate every feature at its own numbers
    x, v, t = 0.02, -0.3, 0.4
    values = a._extra_jets(jnp.asarray(x), jnp.asarray(v), jnp.asarray(t),
                           jnp.asarray(b.record_arrays.extra_numbers))[0]
    np.testing.assert_allclose([float(f) for f in values],
                               [np.tanh(35.0 * v), abs(x - 0.03) / 2, x * np.cos(11.0 * t)],
                               rtol=1e-14)
