import gc
import os
import subprocess
import sys
import weakref
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import sympy as sp

from gpjax import Measurement, Symbols
from gpjax.engine import PopulationEvaluator
from gpjax._refine import CONVERGED, Refiner, refined_to_convergence, until_converged

S = Symbols("x", "t", ("u",))
TRUE = {"m": 1.0, "k1": 40.0, "k2": 30.0, "y0": (0.02, -0.1)}


def _setup():
    t = np.linspace(0.0, 3.0, 601)
    u = np.sin(2 * np.pi * 1.1 * t) + 0.6 * np.sin(2 * np.pi * 2.3 * t + 1.0)
    data = Measurement(time=t, response=np.sin(t), inputs={"u": u}, response_name="x",
                       time_name="t")
    generator = PopulationEvaluator(data, S, max_degree=2, batch=1)
    truth = _models(generator, np.zeros(1), np.random.default_rng(0))
    response = generator.simulate(truth)[0][0]
    measurement = Measurement(time=t, response=response, inputs={"u": u}, response_name="x",
                              time_name="t")
    return PopulationEvaluator(measurement, S, max_degree=2, batch=4)


def _models(evaluator, spread, rng):
    count = spread.size
    u = evaluator.forcing_index(S.u[0])
    pop = evaluator.empty(count)
    pop.mass[:] = TRUE["m"] * (1 + spread * rng.uniform(-1, 1, count))
    pop.state[:, 0] = TRUE["k1"] * (1 + spread * rng.uniform(-1, 1, count))
    pop.state[:, 1] = TRUE["k2"] * (1 + spread * rng.uniform(-1, 1, count))
    pop.forcing[:, u] = 1.0
    pop.y0[:] = TRUE["y0"]
    return pop


@pytest.fixture(scope="module")
def refiner():
    return Refiner(_setup(), iterations=10, batch=4)


def test_refinement_recovers_perturbed_constants_and_keeps_zeros(refiner):
    evaluator = refiner.evaluator
    start = _models(evaluator, np.full(3, 0.1), np.random.default_rng(1))
    fixed = np.full(3, evaluator.forcing_index(S.u[0]))
    out = refiner.refine(start, fixed)
    pop = out.population
    np.testing.assert_allclose(pop.mass, TRUE["m"], rtol=1e-4)
    np.testing.assert_allclose(pop.state[:, 0], TRUE["k1"], rtol=1e-4)
    np.testing.assert_allclose(pop.state[:, 1], TRUE["k2"], rtol=1e-4)
    assert np.all(pop.forcing[:, fixed[0]] == 1.0)  # the normalised coefficient stays fixed
    assert np.all(pop.state[:, 2:] == 0.0)          # absent terms stay absent
    assert out.succeeded.all()


def test_refinement_does_not_depend_on_position_in_the_batch(refiner):
    evaluator = refiner.evaluator
    start = _models(evaluator, np.full(4, 0.05), np.random.default_rng(2))
    fixed = np.full(4, evaluator.forcing_index(S.u[0]))
    order = np.array([2, 0, 3, 1])
    shuffled = type(start)(start.mass[order], start.state[order], start.forcing[order],
                           start.y0[order])
    a = refiner.refine(start, fixed).population
    b = refiner.refine(shuffled, fixed).population
    np.testing.assert_array_equal(b.state, a.state[order])
    np.testing.assert_array_equal(b.mass, a.mass[order])


@pytest.mark.parametrize("horizons", [(), (0.5, 0.2), (0.0, 1.0), (1.0, 1.0)])
def test_bad_horizons_are_refused(refiner, horizons):
    with pytest.raises(ValueError, match="horizons"):
        Refiner(refiner.evaluator, horizons=horizons)


def test_refiner_jacobian_equals_autodiff_of_the_simulated_response(refiner):
    """The custom derivative rule (variational equations) gives the Jacobian that forward
    mode through the plain scan gives, free forcing coefficient and initial state included."""
    evaluator = refiner.evaluator
    one = evaluator.forcing_index(sp.Integer(1))
    pop = _models(evaluator, np.full(1, 0.1), np.random.default_rng(5))
    pop.forcing[0, one] = 0.2
    n_state, capacity = pop.state.shape[1], evaluator.forcing_capacity
    forcing = np.zeros(capacity)
    forcing[: pop.forcing.shape[1]] = pop.forcing[0]
    start = jnp.asarray(np.concatenate([pop.mass, pop.state[0], forcing, pop.y0[0]]))
    index = jnp.asarray([0, 1, 2, 1 + n_state + one, start.size - 2, start.size - 1, 0])
    scale = jnp.asarray([1.0, 40.0, 30.0, 0.2, 0.02, 0.1, 0.0])  # last: padding
    basis = jnp.asarray(evaluator._forcing_basis)
    samples = evaluator.measurement.n_samples
    response = refiner._response(samples)

    def plain(delta):
        p = start.at[index].add(scale * delta)
        stages = basis[: evaluator.stage_rows(samples)]
        return evaluator.scan_solve(p[0:1], p[None, 1:1 + n_state],
                                    (stages @ p[1 + n_state:-2])[:, None], p[None, -2:])[:, 0]

    delta = jnp.full(7, 0.01)
    custom = jax.jacfwd(lambda d: response(d, start, (index, scale), basis,
                                           evaluator.record_arrays))(delta)
    reference = jax.jacfwd(plain)(delta)
    np.testing.assert_allclose(custom, reference, rtol=0,
                               atol=1e-10 * float(jnp.max(jnp.abs(reference))))
    assert np.all(np.asarray(custom[:, -1]) == 0.0)


@pytest.mark.slow  # 20-30 s: CI's slow step; the fast tier stays within 5 min on 2 cores
def test_variational_and_autodiff_refinement_agree(refiner):
    """The same Levenberg–Marquardt run with the Jacobian from the variational equations
    and from forward-mode autodiff through diffrax reaches the same constants."""
    evaluator = refiner.evaluator
    start = _models(evaluator, np.full(2, 0.1), np.random.default_rng(6))
    fixed = np.full(2, evaluator.forcing_index(S.u[0]))
    diffrax_evaluator = PopulationEvaluator(evaluator.measurement, S, max_degree=2, batch=4,
                                            integrator="diffrax")
    for feature in evaluator.forcing_features:  # the same bank, whatever other tests added
        diffrax_evaluator.forcing_index(feature)
    reference = Refiner(diffrax_evaluator, iterations=10, batch=4, jacobian="autodiff")
    a = refiner.refine(start, fixed).population
    b = reference.refine(start, fixed).population
    np.testing.assert_allclose(a.state[:, :2], b.state[:, :2], rtol=1e-8)
    np.testing.assert_allclose(a.mass, b.mass, rtol=1e-8)


def test_a_population_laid_out_on_another_forcing_bank_is_refused(refiner):
    """Forcing coefficients laid out on one evaluator's columns would multiply other
    features on an evaluator that registered its forcing features in another order: that
    is refused, where it used to refit the wrong model silently; the same bank passes."""
    evaluator = refiner.evaluator
    start = _models(evaluator, np.zeros(2), np.random.default_rng(0))
    other = PopulationEvaluator(evaluator.measurement, S, max_degree=2, batch=4)
    other.forcing_index(sp.sin(S.t))
    for feature in evaluator.forcing_features:
        other.forcing_index(feature)
    column = np.full(2, other.forcing_index(S.u[0]))
    with pytest.raises(ValueError, match="forcing columns hold"):
        other.score(start)
    with pytest.raises(ValueError, match="forcing columns hold"):
        Refiner(other, iterations=1, batch=4).refine(start, column)
    with pytest.raises(ValueError, match="different forcing banks"):
        start.concatenate([start, other.empty(1)])
    assert np.all(evaluator.score(start.concatenate([start.rows([0]), start.rows([1])]))
                  .status == 0)


def test_unknown_jacobian_is_refused(refiner):
    with pytest.raises(ValueError, match="jacobian"):
        Refiner(refiner.evaluator, jacobian="finite differences")


def test_two_programs_serve_every_call_size_and_count_of_free_constants(refiner):
    """Calls of up to SMALL_BATCH models run one program, larger ones the other, and
    models with fewer free constants (k2 absent) run the same ones: a width or batch of
    their own would compile again."""
    from gpjax._refine import SMALL_BATCH

    evaluator = refiner.evaluator
    assert refiner.batch_sizes == (SMALL_BATCH, refiner.batch)
    fixed = np.full(4, evaluator.forcing_index(S.u[0]))
    full = _models(evaluator, np.full(4, 0.05), np.random.default_rng(3))
    refiner.refine(full, fixed)
    refiner.refine(full.rows([0]), fixed[:1])
    before = refiner.compile_count
    fewer = full.rows([0, 1, 2])
    fewer.state[:, 1] = 0.0
    out = refiner.refine(fewer, fixed[:3]).population
    one = refiner.refine(fewer.rows([0]), fixed[:1]).population
    assert refiner.compile_count == before
    assert np.all(out.state[:, 1] == 0.0) and len(out) == 3 and len(one) == 1
    assert np.allclose(one.state, out.state[:1], rtol=1e-9)


def test_refits_of_one_model_share_a_program_across_counts_of_free_constants(refiner):
    """A refiner of one model per call (a final fit) sizes its Jacobian by free_width, and
    a second refiner of another max_free on the same evaluator reuses the executable: the
    structures a final selection refits compile one program, not one per count."""
    from gpjax import _aot
    from gpjax._refine import MAX_FREE, Refiner, free_width

    assert [free_width(n) for n in (1, 8, 9, 15, 16, 17)] == [8, 8, 16, 16, 16, 24]
    evaluator = refiner.evaluator
    fixed = np.full(1, evaluator.forcing_index(S.u[0]))
    model = _models(evaluator, np.full(4, 0.05), np.random.default_rng(5)).rows([0])
    Refiner(evaluator, iterations=5, batch=1, max_free=MAX_FREE).refine(model, fixed)
    fewer = model.rows([0])
    fewer.state[:, 1] = 0.0
    kept, count = set(_aot._KEPT), _aot.compile_ledger()[1]
    Refiner(evaluator, iterations=5, batch=1, max_free=2 * MAX_FREE).refine(fewer, fixed)
    assert set(_aot._KEPT) == kept  # the executable in memory served it: no new key
    assert _aot.compile_ledger()[1] == count + 1  # the ledger counts the new Program's one


#: Refines four models of this file's problem with the augmented solve split over two
#: host devices and on one device; prints the largest relative difference.
SPLIT_PROBE = """
import numpy as np, jax
import tests.test_refine as t
from gpjax.engine import PopulationEvaluator
from gpjax._refine import Refiner
assert len(jax.devices()) == 2
data = t._setup().measurement
out = []
for devices in (jax.devices(), jax.devices()[:1]):
    ev = PopulationEvaluator(data, t.S, max_degree=2, batch=4, devices=devices)
    start = t._models(ev, np.full(4, 0.1), np.random.default_rng(1))
    fixed = np.full(4, ev.forcing_index(t.S.u[0]))
    out.append(Refiner(ev, iterations=10, batch=4).refine(start, fixed).population.state[:, :2])
print(np.max(np.abs(out[0] / out[1] - 1)))
"""


@pytest.mark.slow  # a long run: CI's slow step (fast tier <= 5 min)
def test_refinement_split_over_two_host_devices_matches_one_device():
    root = Path(__file__).resolve().parent.parent
    env = dict(os.environ, PYTHONPATH=str(root), JAX_PLATFORMS="cpu",
               XLA_FLAGS="--xla_force_host_platform_device_count=2")
    done = subprocess.run([sys.executable, "-c", SPLIT_PROBE], capture_output=True, text=True,
                          env=env, cwd=root, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert float(done.stdout.split()[-1]) < 1e-9


def _tiny_record() -> Measurement:
    """101 samples of a sine driven by a cosine: the smallest record the leak tests trace."""
    t = np.linspace(0.0, 1.0, 101)
    return Measurement(time=t, response=np.sin(t), inputs={"u": np.cos(t)}, response_name="x",
                       time_name="t")


def test_a_dropped_refiner_frees_its_evaluator_and_compiled_programs(monkeypatch):
    """JAX's tracing caches outlive a run and keep the functions traced in it; they must not
    keep a dropped refiner's evaluator and compiled programs alive (a process fitting one
    record after another ran out of memory maps after ~70 fits)."""
    monkeypatch.setenv("GPJAX_COMPILATION_CACHE", "off")  # traced here, not loaded
    evaluator = PopulationEvaluator(_tiny_record(), S, max_degree=1, batch=1)
    refiner = Refiner(evaluator, iterations=1, batch=1, horizons=(1.0,))
    start = _models(evaluator, np.full(1, 0.1), np.random.default_rng(1))
    refiner.refine(start, np.full(1, evaluator.forcing_index(S.u[0])))
    alive = [weakref.ref(evaluator), weakref.ref(refiner)]
    del evaluator, refiner, start
    gc.collect()
    assert [ref() for ref in alive] == [None, None]


def test_a_dropped_diffrax_evaluator_is_freed(monkeypatch):
    """The same for the ``"diffrax"`` integrator: its vector field is a static argument of
    ``diffeqsolve``, which JAX's caches keep."""
    monkeypatch.setenv("GPJAX_COMPILATION_CACHE", "off")

    def simulated() -> weakref.ref:
        # In a frame of its own: equinox's error_if reads every frame's f_locals while
        # tracing, and that snapshot would hold the evaluator as long as its frame lives.
        evaluator = PopulationEvaluator(_tiny_record(), S, max_degree=1, batch=1,
                                        integrator="diffrax")
        evaluator.simulate(_models(evaluator, np.full(1, 0.1), np.random.default_rng(1)))
        return weakref.ref(evaluator)

    alive = simulated()
    gc.collect()
    assert alive() is None


def test_rounds_stop_per_model_when_a_round_gains_less_than_the_tolerance():
    # Model 0 halves its objective each round (never converges: stops at the round cap),
    # model 1 gains 1 % then 0.01 % (stops after its second round), model 2 gains nothing.
    objectives = np.array([1.0, 1.0, 1.0])
    gains = {0: [0.5] * 10, 1: [0.99, 0.9999], 2: [1.0]}
    rounds = {0: 0, 1: 0, 2: 0}

    def refine_round(active):
        for i in active:
            objectives[i] *= gains[i][rounds[i]]
            rounds[i] += 1
        return objectives[active]

    until_converged(refine_round, objectives.copy(), rounds=4)
    assert rounds == {0: 4, 1: 2, 2: 1}
    assert 0.9999 > 1 - CONVERGED > 0.99  # model 1's second gain is below the tolerance


def test_a_refinement_to_convergence_keeps_its_best_round(refiner):
    ev = refiner.evaluator
    one = _models(ev, np.full(1, 0.15), np.random.default_rng(2))  # constants ≤ 15 % off
    fixed = np.full(1, ev.forcing_index(S.u[0]))
    before = float(ev.score(one).objective[0])
    refined, (objective,) = refined_to_convergence(refiner, one, fixed,
                                                   lambda p: ev.score(p).objective)
    assert objective < 0.1 * before
    assert objective == pytest.approx(float(ev.score(refined).objective[0]))
    # Rounds after the first fit the whole record at once: the twin of a refiner that
    # grows its horizon, made once.
    growing = Refiner(ev, iterations=10, batch=1, horizons=(0.25, 1.0))
    twin = growing.whole_record()
    assert twin is growing.whole_record() and twin.evaluator is ev
    assert list(twin.horizon_limits) == [ev.measurement.n_samples] and twin.iterations == 10
    # A score no refinement can lower keeps the start.
    kept, (same,) = refined_to_convergence(refiner, one, fixed, lambda p: np.array([0.0]))
    assert same == 0.0 and np.array_equal(kept.state, one.state)


def test_a_population_converges_model_by_model_and_a_settled_one_stops(refiner):
    # Three models refined together: each ends at its own converged constants, the same as
    # refined alone; a model whose solver met its own stop rule on the whole record is
    # settled, and a round from its constants is not run (it would start converged).
    ev = refiner.evaluator
    start = _models(ev, np.array([0.3, 0.05, 0.15]), np.random.default_rng(4))
    fixed = np.full(3, ev.forcing_index(S.u[0]))
    calls = []

    class Counting:  # the refiner, counting the models of each round
        def __init__(self, inner):
            self.inner = inner

        def refine(self, population, fixed_forcing, ties=None):
            out = self.inner.refine(population, fixed_forcing, ties=ties)
            calls.append((len(population), out.settled.copy()))
            return out

        def whole_record(self):
            return Counting(self.inner.whole_record())

    together, objectives = refined_to_convergence(Counting(refiner), start, fixed,
                                                  lambda p: ev.score(p).objective)
    for i in range(3):
        alone, (objective,) = refined_to_convergence(refiner, start.rows([i]), fixed[[i]],
                                                     lambda p: ev.score(p).objective)
        np.testing.assert_allclose(together.state[i], alone.state[0], rtol=1e-6)
        assert objectives[i] == pytest.approx(objective, rel=1e-6)
    np.testing.assert_allclose(together.state[:, 0], TRUE["k1"], rtol=1e-4)
    # rounds shrink to the models still falling and not settled
    sizes = [n for n, _ in calls]
    assert sizes[0] == 3 and sizes == sorted(sizes, reverse=True)
    for (n, settled), (m, _) in zip(calls, calls[1:]):
        assert m <= n - settled.sum()
    # a converged model settles at once: its refinement stops by the solver's rule
    again = refiner.whole_record().refine(together, fixed)
    assert again.settled.all() and np.all(again.steps < refiner.iterations)
