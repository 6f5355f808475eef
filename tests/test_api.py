"""The user-facing shape: one coefficient type and its array forms, the public API, and no
global side effects on import."""

import subprocess
import sys

import numpy as np
import pytest
import sympy as sp

import gpjax
from gpjax import Measurement
from gpjax.engine import (Coefficients, FlatLayout, PopulationEvaluator, Status, Symbols,
                          from_population, to_population)

S = Symbols("x", "t", ("u",))
X, V, U = S.x, S.x_dot, S.u[0]


def test_importing_gpjax_changes_no_global_state():
    probe = (
        "import jax, matplotlib\n"
        "import gpjax, gpjax.engine, gpjax.silverbox, gpjax.gear\n"
        "from gpjax import Identifier, Model, diagnose\n"
        "from gpjax._report import fit_figure\n"
        "assert not jax.config.jax_enable_x64, 'x64 switched on by an import'\n"
        "import numpy as np\n"
        "t = np.linspace(0, 1, 64)\n"
        "fit_figure(t, np.sin(t), np.cos(t), response_name='x', n_bins=4, title='')\n"
        "assert matplotlib.get_backend() == 'svg', matplotlib.get_backend()\n"
        "from gpjax.engine import PopulationEvaluator\n"
        "m = gpjax.Measurement(time=t, response=np.sin(7 * t), inputs={'u': np.cos(t)})\n"
        "PopulationEvaluator(m, gpjax.Symbols('x', 't', ('u',)))\n"
        "assert jax.config.jax_enable_x64, 'gpjax computes in float64'\n")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          env={"MPLBACKEND": "svg", "JAX_PLATFORMS": "cpu",
                               "PATH": "/usr/bin:/bin"}, timeout=120)
    assert done.returncode == 0, done.stderr


def test_top_level_names_are_the_user_api():
    engine = {"Population", "PopulationEvaluator", "Scores", "check_tree", "tree_to_sympy",
              "load_silverbox", "segment_rms", "simulate_model", "objective_parts"}
    assert not engine & set(gpjax.__all__)
    assert {"Identifier", "GPConfig", "Model", "Measurement", "load_csv", "diagnose"} <= set(
        gpjax.__all__)
    assert Status.OK == 0 and Status(3) is Status.DIVERGED


def _record():
    t = np.linspace(0.0, 2.0, 201)
    return Measurement(time=t, response=np.sin(3 * t), inputs={"u": np.cos(2 * t)},
                       time_name="t", response_name="x")


def test_coefficients_round_trip_through_population_and_flat_layout():
    evaluator = PopulationEvaluator(_record(), S, max_degree=3)
    models = [Coefficients(mass=2.0, state={X: 5.0, V ** 3: 0.5},
                           forcing={U: 1.0, sp.Integer(1): -0.3}, y0=(0.1, -0.2)),
              Coefficients(mass=1.0, state={X ** 2: 7.0}, forcing={S.t * U: 0.25},
                           y0=(0.0, 1.0))]
    population = to_population(models, evaluator)
    assert population.state[0, evaluator.state_index(V ** 3)] == 0.5
    assert population.forcing[1, evaluator.forcing_index(S.t * U)] == 0.25
    assert from_population(population, evaluator, models) == models
    layout = evaluator.layout
    flat = layout.pack(population)
    assert flat.shape == (2, layout.width) and flat[0, layout.state_column(
        evaluator.state_index(X))] == 5.0
    again = layout.population(flat, population.forcing.shape[1])
    for name in ("mass", "state", "forcing", "y0"):
        np.testing.assert_array_equal(getattr(again, name), getattr(population, name))
    assert FlatLayout(2, 3).width == 1 + 2 + 3 + 2
    with pytest.raises(ValueError, match="outside the evaluator's basis"):
        to_population([Coefficients(mass=1.0, state={X ** 7: 1.0}, forcing={})], evaluator)


def test_coefficients_json_round_trip_parses_with_the_whitelist():
    model = Coefficients(mass=2.0, state={X ** 2: 3.0}, forcing={U: 1.0}, y0=(0.5, 0.0))
    assert Coefficients.from_json(model.to_json(), S.names()) == model
