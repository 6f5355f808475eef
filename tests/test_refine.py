import numpy as np
import pytest

from gpjax import Measurement, PopulationEvaluator, Symbols
from gpjax._refine import Refiner

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
