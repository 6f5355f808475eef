"""The paper's tree-constant mode: feature sets, Lamarckian refinement, interval-drawn
extensions and named-constant inertias, recovery of eq. 14, reproducibility and resume."""

import os
import subprocess
import sys

import numpy as np
import pytest
import sympy as sp
from _runs import kill_and_resume

from gpjax import GPConfig, Identifier
from gpjax.engine import Coefficients
from gpjax._evolve import Evolution, _best_distinct
from gpjax._fitness import Fitness, Record, feature_set_key
from gpjax.gear import generate_gear_example

EXAMPLE = generate_gear_example(revolutions=0.35, seed=0)
K1, K2 = EXAMPLE.truth["K1"], EXAMPLE.truth["K2"]


def _intervals(low, high):
    return {"K1": ((low * K1, high * K1),), "K2": ((low * K2, high * K2),)}


def _tree(k1, k2):
    """J·x'' + k1·x + k2·x·x − T as a tree."""
    return ("sub", ("add", ("mul", ("c", "J"), ("x_ddot",)),
                    ("add", ("mul", ("n", k1), ("x",)),
                     ("mul", ("n", k2), ("mul", ("x",), ("x",))))), ("u", 0))


def test_coefficient_variants_share_a_feature_set_key():
    trees = [_tree(400.0, 5e4), _tree(300.0, 6e4)]
    tree_fitness = Fitness(EXAMPLE.measurement, GPConfig.paper(population=4,
                                                               coefficients="tree"))
    a, b = tree_fitness.records_for(trees)
    assert a.key != b.key
    assert feature_set_key(a) == feature_set_key(b) == "m | phi, phi**2 | T"
    ls_fitness = Fitness(EXAMPLE.measurement, GPConfig.paper(population=4))
    c, d = ls_fitness.records_for(trees)
    assert c is d and feature_set_key(c) == c.key


def test_best_distinct_takes_the_best_variant_of_each_feature_set():
    x, T = sp.symbols("x T")

    def record(key, state, objective):
        return Record(key=key, valid=True, objective=objective, status=0,
                      coefficients=Coefficients(mass=1.0, state=state, forcing={T: 1.0}))

    records = [record("a", {x: 1.0}, 0.3), record("b", {x: 2.0}, 0.1),
               record("c", {x: 3.0}, 0.2), record("d", {x**2: 1.0}, 0.4),
               record("e", {x: 1.0, x**2: 1.0}, 0.5)]
    best = _best_distinct(records, 2)
    assert [r.key for r in best] == ["b", "d"]


def test_extensions_draw_stiffness_terms_from_the_intervals():
    config = GPConfig.paper(population=4, coefficients="tree",
                            interval_constants={"K1": ((1.0, 2.0), (50.0, 60.0)),
                                                "K2": ((7.0, 8.0),)})
    evolution = Evolution(Fitness(EXAMPLE.measurement, config), config)
    rng = np.random.default_rng(0)
    state = np.array([evolution._new_coefficient("state", "phi**2", rng) for _ in range(300)])
    inside = [(state >= lo) & (state <= hi) for lo, hi in ((1, 2), (50, 60), (7, 8))]
    assert np.all(np.any(inside, axis=0)) and all(np.sum(i) > 30 for i in inside)
    assert evolution._new_coefficient("forcing", "T", rng) == 1.0
    forces = [evolution._new_coefficient("forcing", "1", rng) for _ in range(50)]
    assert all(-10 <= f <= 10 for f in forces) and np.std(forces) > 1


def test_tree_mode_extensions_try_each_named_constant_as_the_inertia():
    config = GPConfig.paper(population=4, coefficients="tree", local_search=1)
    fitness = Fitness(EXAMPLE.measurement, config)
    parent = ("sub", ("add", ("x_ddot",), ("mul", ("n", 400.0), ("x",))), ("u", 0))
    extensions = Evolution(fitness, config)._extensions([parent], np.random.default_rng(0))
    forms = [fitness.classify(tree)[1] for tree in extensions]
    same_terms = {form.mass for form in forms if len(form.state) + len(form.forcing) == 2}
    assert same_terms == set(config.named_constants.values())
    added = [form for form in forms if len(form.state) + len(form.forcing) == 3]
    assert added and all(form.mass == 1.0 for form in added)
    assert all(r.refined for r in fitness.records_for(extensions))


@pytest.mark.slow  # two tree-mode runs: CI's slow step (fast tier <= 5 min on 2 cores)
def test_tree_mode_refines_every_new_candidate_and_refine_top_0_none():
    config = GPConfig.paper(population=30, coefficients="tree", generations=1)
    fitness = Fitness(EXAMPLE.measurement, config)
    Evolution(fitness, config).start(0)
    valid = [r for r in fitness.records.values() if r.valid]
    assert len(valid) >= 3 and all(r.refined for r in valid)
    config = config.replace(refine_top=0)
    fitness = Fitness(EXAMPLE.measurement, config)
    Evolution(fitness, config).start(0)
    assert not any(r.refined for r in fitness.records.values())


def _recovered(model):
    if sorted(model.state) != ["phi", "phi**2"] or list(model.forcing) != ["T"]:
        return False
    scale = model.forcing["T"]
    found = (model.mass / scale, model.state["phi"] / scale, model.state["phi**2"] / scale)
    truth = (EXAMPLE.truth["J"], K1, K2)
    return all(abs(f / t - 1) <= 0.02 for f, t in zip(found, truth))


@pytest.mark.slow
def test_tree_mode_recovers_eq14_from_an_interval_that_excludes_the_truth():
    # The interval is 0.3–0.6 times the true K1 and K2, so it cannot hold the answer: the
    # structure comes from the search, the constants from refinement, which leaves the
    # interval. On this short record a wrong structure can reach f <= epsilon, so the run
    # goes all ten generations (epsilon = 0). A run's outcome is a draw: seeds 1, 2, 4 and 5
    # of 0–5 recover eq. 14 with numpy 2.4 and scipy 1.17 (0 and 2 of 0–2 with the
    # versions before), so the test asks for one of seeds 0–2 (a 4/6 rate misses all three
    # with probability 0.04); before every tree-mode candidate was refined, all runs
    # stalled at phi'' = 0.
    config = GPConfig.paper(coefficients="tree", population=200, generations=10, epsilon=0.0,
                            interval_constants=_intervals(0.3, 0.6))
    found = []
    for seed in range(3):
        found.append(Identifier(config).fit(EXAMPLE.measurement, seed=seed))
        if _recovered(found[-1].model_):
            return
    pytest.fail("no seed of 0–2 recovered eq. 14:\n" + "\n".join(map(str, found)))


@pytest.mark.slow
@pytest.mark.handrun  # 5-14 min: the hand-run tier (README, Quick start)
def test_tree_mode_is_bit_reproducible_and_resumes_after_sigkill(tmp_path):
    csv = tmp_path / "data.csv"
    EXAMPLE.measurement.to_csv(csv)
    config = tmp_path / "config.toml"
    k1, k2 = _intervals(0.5, 2.0).values()
    config.write_text(f'population = 60\ngenerations = 3\nepsilon = 0.0\ncoefficients = "tree"\n'
                      f"[interval_constants]\nK1 = {[list(p) for p in k1]}\n"
                      f"K2 = {[list(p) for p in k2]}\n")
    base = [sys.executable, "-m", "gpjax", "fit", str(csv), "--time", "t", "--response", "phi",
            "--input", "T", "--config", str(config), "--seed", "2"]
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    for name in ("a", "b"):
        subprocess.run(base + ["--out", str(tmp_path / name)], check=True, env=env,
                       capture_output=True)
    expected = (tmp_path / "a" / "model.json").read_text()
    assert (tmp_path / "b" / "model.json").read_text() == expected
    assert kill_and_resume(base, tmp_path / "killed", 1, env) == expected
