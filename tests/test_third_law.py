"""Newton's third law between the coordinates of a system (issue 14): one coupling force,
entering its two equations with opposite signs, its constants fitted once."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import sympy as sp

from gpjax._system_couplings import (NOTHING_FIXED, components, couple,
                                     coupled_least_squares, fixed_columns, normalisation)
from gpjax.systems import generate, get_system
from test_mdof import U, V1, V2, X1, X2, _chain, _truth_model

X3, V3 = sp.symbols("x3 x3_dot")


def test_couple_adds_each_mirror_with_the_sign_of_its_power():
    structure = (((V1, X1 - X2, (X1 - X2) ** 2, (V1 - V2) ** 3), {U: 1.0}), ((X2,), {}))
    full, ties = couple(structure, ("x1", "x2"))
    assert set(full[1][0]) == {X2, X2 - X1, (X2 - X1) ** 2, (V2 - V1) ** 3}
    assert {(t.mirror[1], t.sign) for t in ties} == {
        (X2 - X1, 1.0), ((X2 - X1) ** 2, -1.0), ((V2 - V1) ** 3, 1.0)}
    assert all(t.source[0] == 0 and t.mirror[0] == 1 for t in ties)
    again, same = couple(full, ("x1", "x2"))  # a structure holding both sides: one tie each
    assert again == full and same == ties
    assert couple(((( V1,), {U: 1.0}), ((X2,), {})), ("x1", "x2"))[1] == ()


def test_components_and_normalisation_hold_one_constant_per_coupled_group():
    structure = (((X1 - X2,), {U: 1.0}), ((X2,), {U: 1.0}), ((X3,), {}))
    _, ties = couple(structure, ("x1", "x2", "x3"))
    assert components(3, ties) == [[0, 1], [2]]
    assert normalisation(structure, ties, (U,)) == [U, None, None]
    assert normalisation(structure, (), (U,)) == [U, U, None]
    held = {U: 1.0}, {U: None}, {}
    given = tuple((s, h) for (s, _), h in zip(structure, held))
    assert fixed_columns(given, ties, lambda f: 7) == [7, NOTHING_FIXED, -1]
    assert fixed_columns(given, (), lambda f: 7) == [7, -1, -1]
    free = tuple((s, {U: None} if g else {}) for s, g in given)
    assert fixed_columns(free, ties, lambda f: 7) == [-1, NOTHING_FIXED, -1]


def test_coupled_least_squares_ties_the_coupling_and_identifies_the_second_mass():
    """Without the third law equation 2 (no input) is known up to a factor; with it the
    shared coupling fixes that factor, so its mass comes out as m2."""
    from gpjax._weak_form import smoothed_weak_form

    system, _, measurement = _chain(duration=5.0)
    c = system.constants
    structure = (((V1, X1, X1 - X2, (X1 - X2) ** 3), {U: 1.0}), ((V2, X2), {}))
    full, ties = couple(structure, ("x1", "x2"))
    first, second = coupled_least_squares(smoothed_weak_form(measurement), full, ties)
    assert second.mass == pytest.approx(c["m2"], rel=0.01)
    assert first.state[X1 - X2] == second.state[X2 - X1] == pytest.approx(c["kc"], rel=0.01)
    assert first.state[(X1 - X2) ** 3] == second.state[(X2 - X1) ** 3]
    assert first.state[(X1 - X2) ** 3] == pytest.approx(c["k3"], rel=0.02)
    assert second.state[X2] == pytest.approx(c["k"], rel=0.01)


@pytest.mark.slow  # 13-21 s: the fast tier stays within 5 minutes on 2 cores
def test_fit_system_with_the_third_law_keeps_the_tie_and_recovers_the_chain():
    from gpjax.engine import fit_system

    system, _, measurement = _chain(duration=3.0)
    c = system.constants
    structure = (((V1, X1, X1 - X2, (X1 - X2) ** 3), {U: 1.0}), ((V2, X2), {}))
    fit = fit_system(measurement, structure, input_interpolation="bandlimited",
                     substeps=2, third_law=True, iterations=10)
    first, second = fit.model.system
    assert fit.model.third_law
    assert second.state[X2 - X1] == pytest.approx(first.state[X1 - X2], rel=1e-12)
    assert second.state[(X2 - X1) ** 3] == pytest.approx(first.state[(X1 - X2) ** 3], rel=1e-12)
    for value, want in ((second.mass, c["m2"]), (first.state[X1 - X2], c["kc"]),
                        (first.state[(X1 - X2) ** 3], c["k3"]), (second.state[V2], c["c"])):
        assert value == pytest.approx(want, rel=2e-3)
    (pair, force), = fit.model.couplings().items()
    assert pair == (0, 1) and force.has(X1 - X2) and force.has((X1 - X2) ** 3)


def test_third_law_model_file_round_trip_and_a_broken_mirror_is_refused(tmp_path):
    from gpjax import ModelFileError
    from gpjax import Model
    from gpjax.engine import load_model

    system, record, _ = _chain(duration=1.0)
    model = dataclasses.replace(_truth_model(system, record), third_law=True)
    model.save(tmp_path / "model.json")
    loaded = load_model(tmp_path / "model.json")
    assert loaded == model
    data = model.to_json()
    assert data["couplings"][0]["coordinates"] == ["x1", "x2"]
    for term in data["canonical"][1]["terms"]:
        if term["feature"] == "-x1 + x2":
            term["coefficient"] *= 1.01
    with pytest.raises(ModelFileError, match="needs the term -x1 \\+ x2"):
        Model.from_json(data)
    data["third_law"] = "yes"
    with pytest.raises(ModelFileError, match="third_law"):
        Model.from_json(data)
    del data["third_law"]  # files written before the option: no tie, loaded as they are
    assert Model.from_json(data).third_law is False


def test_third_law_needs_several_responses(tmp_path, capsys):
    from gpjax.cli import main

    _, _, measurement = _chain(duration=1.0)
    measurement.to_csv(tmp_path / "data.csv")
    assert main(["fit", str(tmp_path / "data.csv"), "--time", "t", "--response", "x1",
                 "--input", "u", "--third-law", "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert "--third-law" in err and err.count("\n") == 1
    assert not (tmp_path / "run").exists()


# --- the settings of a system search: the one GPConfig ---------------------------------
def test_system_search_takes_the_one_gpconfig_and_refuses_one_coordinate_fields(tmp_path):
    from gpjax import ConfigError, GPConfig, Identifier

    config = GPConfig(population=60, generations=2, third_law=True, p_swap=0.5)
    assert config.third_law and config.p_swap == 0.5 and config.local_steps == 4
    assert not GPConfig().third_law  # the same defaults for one and several coordinates
    with pytest.raises(ConfigError, match="p_swap must be in"):
        GPConfig(p_swap=1.5)
    with pytest.raises(ConfigError, match="third_law must be true or false"):
        GPConfig(third_law="yes")
    with pytest.raises(ConfigError, match="local_steps must be >= 0"):
        GPConfig(local_steps=-1)
    _, _, measurement = _chain(duration=1.0)
    with pytest.raises(ConfigError, match="coefficients is not supported with several"):
        Identifier(GPConfig(coefficients="tree")).fit(measurement)
    with pytest.raises(ConfigError, match="function 'exp' is not supported with several"):
        Identifier(GPConfig(functions=("add", "sub", "mul", "exp"))).fit(measurement)
    path = tmp_path / "run.toml"
    path.write_text("population = 30\ngenerations = 1\nthird_law = true\np_swap = 0.5\n")
    read = GPConfig.from_toml(path)
    assert read.population == 30 and read.third_law and read.p_swap == 0.5
    path.write_text("population = 30\nthird_lw = true\n")
    with pytest.raises(ConfigError, match="unknown key 'third_lw'"):
        GPConfig.from_toml(path)
    path.write_text("third_law = 1\n")
    with pytest.raises(ConfigError, match="third_law must be true or false"):
        GPConfig.from_toml(path)


def test_system_search_takes_the_substeps_setting_and_guards_its_memory(monkeypatch):
    """``substeps`` acts on a system search as on one coordinate's: a number is its RK4
    steps per sample, ``"auto"`` the data's bandwidth rule; a search the machine cannot
    hold is refused before it allocates, with the one-line fix."""
    from gpjax import GPConfig, UserInputError
    from gpjax import _memory
    from gpjax._convergence import initial_substeps
    from gpjax._system_search import SystemEvolution

    _, _, measurement = _chain(duration=1.0)
    fixed = SystemEvolution(measurement, GPConfig(population=20, substeps=3))
    assert fixed.substeps == fixed.scorer.evaluator.substeps == 3
    auto = SystemEvolution(measurement, GPConfig(population=20))
    assert auto.scorer.evaluator.substeps == initial_substeps(measurement)
    two = _memory.fit_bytes(n_samples=10_000, substeps=1, population=500, coordinates=2)
    assert two > _memory.fit_bytes(n_samples=10_000, substeps=1, population=500)
    monkeypatch.setattr(_memory, "available_bytes", lambda: 10 ** 6)
    with pytest.raises(UserInputError, match="lower population or substeps"):
        SystemEvolution(measurement, GPConfig(population=20))


def test_system_refinements_take_the_refine_iterations_setting(monkeypatch):
    """``refine_iterations`` acts on a system as on one coordinate: the search's
    refinements and every round of the reported fit take that many steps."""
    from gpjax import GPConfig
    from gpjax import _system_fit
    from gpjax._system_search import SystemEvolution

    _, _, measurement = _chain(duration=1.0)
    search = SystemEvolution(measurement, GPConfig(population=20, refine_iterations=4))
    assert search.scorer.iterations == 4
    taken = []

    class Taken(Exception):
        pass

    def refiner(*args, iterations, **kwargs):
        taken.append(iterations)
        raise Taken

    monkeypatch.setattr(_system_fit, "Refiner", refiner)
    structure = (((V1, X1, X1 - X2), {U: 1.0}), ((V2, X2, X2 - X1), {}))
    with pytest.raises(Taken):
        _system_fit.fit_system(measurement, structure, substeps=1, iterations=4)
    assert taken == [4]


def test_system_config_errors_are_one_line_exit_2(tmp_path, capsys):
    from gpjax.cli import main

    _, _, measurement = _chain(duration=1.0)
    measurement.to_csv(tmp_path / "data.csv")
    (tmp_path / "run.toml").write_text("p_swap = 2\n")
    assert main(["fit", str(tmp_path / "data.csv"), "--time", "t", "--response", "x1",
                 "--response", "x2", "--input", "u", "--config", str(tmp_path / "run.toml"),
                 "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert "p_swap must be in [0, 1]" in err and err.count("\n") == 1
    assert main(["fit", str(tmp_path / "data.csv"), "--time", "t", "--response", "x1",
                 "--response", "x2", "--input", "u", "--functions", "add,sub,mul,exp",
                 "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert "function 'exp' is not supported with several responses" in err
    assert err.count("\n") == 1 and not (tmp_path / "run").exists()
    assert not (tmp_path / "run").exists()


def test_tied_step_moves_both_coefficients_and_its_jacobian_is_exact():
    """A free constant with a tied mirror: the refiner's Jacobian column (variational
    equations) equals forward-mode autodiff through the simulation of the tied move."""
    import jax
    import jax.numpy as jnp

    from gpjax._coefficients import to_system_population
    from gpjax._refine import Refiner, _moved
    from test_mdof import _equations, _evaluator

    system, _, measurement = _chain(duration=1.0)
    ev = _evaluator(measurement)
    population = to_system_population([_equations(system.constants)], ev)
    layout = ev.layout
    start = jnp.asarray(layout.pack(population)[0])
    a = layout.state_column(ev.equation_index(X1 - X2, 0), 0)
    b = layout.state_column(ev.equation_index(X2 - X1, 1), 1)
    moves = (jnp.asarray([a, 0]), jnp.asarray([20.0, 0.0]), jnp.asarray([b, 0]),
             jnp.asarray([1.0, 0.0]))
    moved = _moved(start, moves, jnp.asarray([0.1, 0.0]))
    assert moved[a] - start[a] == moved[b] - start[b] == pytest.approx(2.0)
    samples = measurement.n_samples
    response = Refiner(ev, iterations=2, max_free=2)._response(samples)
    basis = jnp.asarray(ev.forcing_basis)

    def plain(delta):
        constants = _moved(start, moves, delta)
        return ev.scan_solve(*ev.unpack(constants, basis[:ev.stage_rows(samples)]))[..., 0]

    delta = jnp.asarray([0.01, 0.0])
    custom = jax.jacfwd(lambda d: response(d, start, moves, basis, ev.record_arrays))(delta)
    reference = jax.jacfwd(plain)(delta)
    assert float(jnp.max(jnp.abs(reference[..., 0]))) > 0
    np.testing.assert_allclose(custom, reference, rtol=0,
                               atol=1e-9 * float(jnp.max(jnp.abs(reference))))


# --- per-equation diagnosis: each coordinate's residual on its own --------------------
def _noisy_chain():
    system = get_system("chain2")
    record = generate(dataclasses.replace(system, duration=10.0), seed=1).fit
    return record, record.system_measurement(), _truth_model(system, record)


def test_residual_statistics_of_the_truth_sit_at_the_noise_floor():
    from gpjax._system_diagnose import residual_statistics, summary_line

    record, measurement, truth = _noisy_chain()
    right = residual_statistics(truth, measurement)
    assert list(right) == ["x1", "x2"]
    assert all(0.9 < s["noise"]["ratio"] < 1.3 and s["unexplained"] is None
               for s in right.values())
    assert right["x1"]["nrms"] == pytest.approx(right["x1"]["rms"] / np.std(
        measurement.responses[:, 0]))
    assert "misses" not in summary_line("x1", right["x1"])
    with pytest.raises(ValueError, match="not the model's coordinates"):
        residual_statistics(truth, record.measurement("x1"))


@pytest.mark.slow
def test_residual_statistics_point_at_the_coordinate_that_misses_something():
    from gpjax._system_diagnose import residual_statistics, summary_line

    _, measurement, truth = _noisy_chain()
    right = residual_statistics(truth, measurement)
    equations = list(truth.equations)
    equations[1] = dataclasses.replace(equations[1], state={
        k: v for k, v in equations[1].state.items() if k != str(V2)})  # mass 2 loses its damper
    wrong = residual_statistics(dataclasses.replace(truth, equations=tuple(equations)),
                                measurement)
    assert wrong["x2"]["noise"]["ratio"] > 3 * right["x2"]["noise"]["ratio"]
    assert wrong["x2"]["unexplained"] is not None
    assert "misses something" in summary_line("x2", wrong["x2"])
    assert any("x'" in line for line in wrong["x2"]["unexplained"]["suggestions"])


@pytest.mark.slow  # ~60 s: a whole `gpjax fit` of the gear pair, 2,001 samples at 300 kHz
def test_the_front_door_finds_the_gear_pair_with_its_mesh_damping(tmp_path):
    """Eqs. 21–22 in line-of-action coordinates through ``gpjax fit --third-law``: the mesh
    stiffness and the mesh damping (5 % of critical, the weakest term) in both equations
    by one law, every constant within 1 % (:mod:`benchmarks.gear_front_door`'s seed 0).
    With the test-function windows at the system's band (2× narrower here) the search
    put the damping on the ground instead, on 5 seeds of 5."""
    import sys
    from pathlib import Path

    import gpjax
    from gpjax import cli
    from gpjax.gear import two_dof_record

    sys.path.insert(0, str(Path(__file__).parents[1] / "benchmarks"))
    from gear_front_door import found, truth

    record = two_dof_record(seed=0)
    path = tmp_path / "gear.csv"
    record.line_of_action().to_csv(path)
    assert cli.main(["fit", str(path), "--time", "t", "--response", "s1", "--response", "s2",
                     "--input", "T1", "--input", "T2", "--third-law", "--input-interpolation",
                     "bandlimited", "--seed", "0", "--out", str(tmp_path / "run")]) == 0
    right, constants = found(gpjax.Model.load(tmp_path / "run" / "model.json"))
    assert right
    errors = {k: constants[k] / v - 1 for k, v in truth(record).items()}
    print("relative errors:", errors)
    assert max(map(abs, errors.values())) < 0.01
