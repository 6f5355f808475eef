"""End-to-end runs: determinism, resume after a kill, other column names."""

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from _runs import kill_and_resume, wait_for_generation

from gpjax import GPConfig, Identifier, load_csv
from gpjax.gear import Torque, generate_gear_example

SMALL = dict(population=60, generations=3, epsilon=0.0, refine_top=3)


def _short_example(**kw):
    return generate_gear_example(revolutions=0.35, **kw)


@pytest.mark.slow  # CI's slow step runs it; the fast tier stays within 5 min on 2 cores
def test_same_seed_same_model_bit_for_bit(tmp_path):
    measurement = _short_example(seed=1).measurement
    config = GPConfig.paper(**SMALL)
    Identifier(config).fit(measurement, seed=3, out=tmp_path / "a")
    Identifier(config).fit(measurement, seed=3, out=tmp_path / "b")
    a = (tmp_path / "a" / "model.json").read_text()
    assert a == (tmp_path / "b" / "model.json").read_text()
    for name in ("history.csv", "equations.csv", "fit.png", "config.json", "checkpoint.json"):
        assert (tmp_path / "a" / name).is_file()


def _cli_case(tmp_path, generations=4):
    example = _short_example(seed=2)
    csv = tmp_path / "data.csv"
    example.measurement.to_csv(csv)
    config = tmp_path / "config.toml"
    config.write_text(f"population = 60\ngenerations = {generations}\nepsilon = 0.0\n"
                      "refine_top = 3\n")
    base = [sys.executable, "-m", "gpjax", "fit", str(csv), "--time", "t", "--response", "phi",
            "--input", "T", "--config", str(config), "--seed", "5"]
    return base, dict(os.environ, JAX_PLATFORMS="cpu")


@pytest.mark.slow
def test_resume_after_sigkill_gives_the_same_model(tmp_path):
    base, env = _cli_case(tmp_path)
    subprocess.run(base + ["--out", str(tmp_path / "full")], check=True, env=env,
                   capture_output=True)
    expected = (tmp_path / "full" / "model.json").read_text()
    for trial, generation in enumerate((1, 2, 3)):  # kill at several generations
        resumed = kill_and_resume(base, tmp_path / f"killed{trial}", generation, env)
        assert resumed == expected, f"kill after generation {generation}"


@pytest.mark.slow
def test_ctrl_c_writes_the_best_model_so_far(tmp_path):
    base, env = _cli_case(tmp_path, generations=50)
    run = tmp_path / "interrupted"
    process = subprocess.Popen(base + ["--out", str(run)], env=env,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    wait_for_generation(run, 1, process)
    process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=300)
    assert process.returncode == 130, stderr.decode()[-2000:]
    assert b"Traceback" not in stderr
    model = json.loads((run / "model.json").read_text())
    assert model["provenance"]["stopped_by"] == "interrupted"
    assert all(isinstance(v, float) for v in model["constants"].values())


@pytest.mark.slow
def test_fit_with_other_names_and_torque_recovers_eq14_structure(tmp_path):
    torque = Torque(mean=9.0, shaft_amplitudes=(0.4, 0.2), shaft_phases=(1.0, 2.0),
                    mesh_amplitudes=(0.9, 0.4, 0.1), mesh_phases=(0.5, 1.5, 3.0))
    # Noise seed 4 is the hard case: a constant force buys 3 % by soaking up torque noise.
    example = generate_gear_example(seed=4, torque=torque, time_name="time_s",
                                    response_name="twist", input_name="drive_torque")
    identifier = Identifier(GPConfig()).fit(example.measurement, seed=0)
    model = identifier.model_
    assert sorted(model.state) == ["twist", "twist**2"]
    assert list(model.forcing) == ["drive_torque"]
    truth = example.truth
    constants = model.constants()
    assert constants["m"] == pytest.approx(truth["J"], rel=0.02)
    assert constants["k1"] == pytest.approx(truth["K1"], rel=0.02)
    assert constants["k2"] == pytest.approx(truth["K2"], rel=0.02)


@pytest.mark.slow  # 13-21 s: the fast tier stays within 5 minutes on 2 cores
def test_loader_and_reload_of_a_run(tmp_path):
    example = _short_example(seed=0)
    example.measurement.to_csv(tmp_path / "d.csv")
    measurement = load_csv(tmp_path / "d.csv", time="t", response="phi", inputs=["T"])
    identifier = Identifier(GPConfig.paper(**SMALL)).fit(measurement, seed=0, out=tmp_path / "r")
    again = Identifier.load(tmp_path / "r")
    assert again.model_ == identifier.model_
    assert str(again).splitlines()[0] == str(identifier).splitlines()[0]
    assert identifier.score() > 0.9
    assert list(again.model_.metrics["residuals"]) == ["phi"]  # as a system's coordinates


def test_a_population_where_every_candidate_diverges_ends_with_a_clear_error(tmp_path):
    from gpjax import UserInputError
    from gpjax.cli import main

    example = _short_example(seed=0)
    example.measurement.to_csv(tmp_path / "d.csv")
    config = GPConfig(population=20, generations=1, initial_conditions=(1e6, 0.0))
    with pytest.raises(UserInputError, match="no candidate model could be simulated"):
        Identifier(config).fit(example.measurement, seed=0)
    (tmp_path / "c.toml").write_text("population = 20\ngenerations = 1\n"
                                     "initial_conditions = [1e6, 0.0]\n")
    status = main(["fit", str(tmp_path / "d.csv"), "--time", "t", "--response", "phi",
                   "--input", "T", "--config", str(tmp_path / "c.toml"),
                   "--out", str(tmp_path / "run")])
    assert status == 2 and not (tmp_path / "run").exists()


def test_functions_option_sets_the_function_set_over_the_config_file(tmp_path):
    """``gpjax fit --functions`` widens the function set without a config file, and wins
    over one, as --population does."""
    from gpjax import cli

    (tmp_path / "c.toml").write_text('functions = ["add", "sub", "mul"]\npopulation = 20\n')
    args = cli._parser().parse_args([
        "fit", "d.csv", "--time", "t", "--response", "x", "--input", "u",
        "--functions", "add, sub,mul,sin,sign", "--config", str(tmp_path / "c.toml")])
    config = cli._config(args, GPConfig.from_toml(args.config))
    assert config.functions == ("add", "sub", "mul", "sin", "sign")
    assert config.population == 20
    plain = cli._parser().parse_args(["fit", "d.csv", "--time", "t", "--response", "x"])
    assert cli._config(plain, GPConfig()).functions == GPConfig().functions


def test_responses_and_inputs_may_be_repeated_or_separated_by_commas():
    """``--response x1,x2`` names the same coordinates as ``--response x1 --response x2``
    (as ``--functions`` takes a list), in order; the same for ``--input``."""
    from gpjax import cli

    def parsed(*names):
        args = cli._parser().parse_args(["fit", "d.csv", "--time", "t", *names])
        return args.responses, args.inputs

    assert (parsed("--response", "x1,x2", "--input", "u, v")
            == parsed("--response", "x1", "--response", "x2", "--input", "u", "--input", "v")
            == (["x1", "x2"], ["u", "v"]))
    assert parsed("--response", "x1,x2", "--response", "x3")[0] == ["x1", "x2", "x3"]
    with pytest.raises(cli.UserInputError, match="expected comma-separated names"):
        parsed("--response", ",")


def test_one_coordinate_gets_its_residual_against_the_noise_floor(capsys):
    """A fit of one coordinate reports its residual as a system's coordinates do: the true
    Duffing model sits at its noise floor, the same model without its cubic spring is
    flagged with the hint (printed by ``gpjax fit``)."""
    import dataclasses

    import sympy as sp

    from gpjax import Model
    from gpjax._coefficients import Coefficients
    from gpjax._synthetic import generate
    from gpjax._config import WIDE_FUNCTIONS
    from gpjax._system_diagnose import hint, residual_statistics
    from gpjax.cli import _print_residuals
    from gpjax.systems import get_system

    system = dataclasses.replace(get_system("duffing"), duration=8.0)
    measurement = generate(system, seed=0).fit.measurement()
    x, v = sp.symbols("x x_dot")
    c = system.constants
    state = {v: c["c"], x: c["k"], x ** 3: c["k3"]}

    def model(state):
        return Model.from_equations(("x",), "t", ("u",), [Coefficients(
            1.0, state, {sp.Symbol("u"): 1.0}, (0.0, 0.0))], substeps=4)

    truth = residual_statistics(model(state), measurement)["x"]
    assert truth["noise"]["ratio"] < 1.25 and truth["unexplained"] is None
    linear = model({f: value for f, value in state.items() if f != x ** 3})
    missing = residual_statistics(linear, measurement)["x"]
    assert missing["noise"]["ratio"] > 3 and missing["unexplained"] is not None
    flagged = dataclasses.replace(linear, metrics={"residuals": {"x": missing}})
    _print_residuals(flagged, ("add", "sub", "mul"))
    out = capsys.readouterr().out
    assert "residual of x: RMS" in out and "misses something" in out
    assert hint(("add", "sub", "mul")) in out and "widen --functions" in out
    _print_residuals(flagged, WIDE_FUNCTIONS)  # the wide set already: not proposed again
    out = capsys.readouterr().out
    assert hint(WIDE_FUNCTIONS) in out and "widen" not in out and "--diagnose" in out
    _print_residuals(flagged, ("add", "sub", "mul"),
                     diagnosing=True)  # gpjax fit --diagnose: no hint to add --diagnose
    out = capsys.readouterr().out
    assert "the diagnosis follows" in out and "hint" not in out


def test_the_measured_inputs_noise_rung_through_a_true_model_is_not_flagged():
    """Sampled at 10 Hz, the sensor noise of the measured input (4 %) rings through the true
    Duffing model to well above the response's own noise floor: the gate counts it
    (``ratio_with_input``), so the true model is not flagged; without its cubic spring it
    still is."""
    import dataclasses

    import numpy as np
    import sympy as sp

    from gpjax import Model
    from gpjax._coefficients import Coefficients
    from gpjax._synthetic import generate
    from gpjax._system_diagnose import residual_statistics
    from gpjax.systems import get_system

    system = dataclasses.replace(get_system("duffing"), sample_rate=10.0, duration=150.0)
    record = generate(system, seed=0, noise=0.01, input_noise=0.04).fit
    measurement = record.measurement()
    x, v = sp.symbols("x x_dot")
    c = system.constants
    state = {v: c["c"], x: c["k"], x ** 3: c["k3"]}
    y0 = (float(np.ravel(record.response_true)[0]), float(np.ravel(record.velocity_true)[0]))

    def model(state):
        return Model.from_equations(("x",), "t", ("u",), [Coefficients(
            1.0, state, {sp.Symbol("u"): 1.0}, y0)], substeps=8,
            input_interpolation="bandlimited")

    truth = residual_statistics(model(state), measurement)["x"]
    assert truth["noise"]["ratio"] > 1.5  # the input's noise, not a missing term
    assert truth["noise"]["input_scaling"] > 1.9  # proportional: a linear propagation
    assert truth["noise"]["ratio_with_input"] < 1.25 and truth["unexplained"] is None
    linear = model({f: value for f, value in state.items() if f != x ** 3})
    missing = residual_statistics(linear, measurement)["x"]
    assert missing["noise"]["ratio_with_input"] > 3 and missing["unexplained"] is not None


def test_a_response_the_input_noise_moves_chaotically_is_not_excused_by_it():
    """The driven double-well Duffing (x'' + 0.25·x' − x + x³ = u, Holmes's chaotic
    oscillator): the measured input's noise moves the true model's response by about as
    much at half the noise, so its share is not counted (no ``ratio_with_input``) and the
    line says why."""
    import dataclasses

    import sympy as sp

    from gpjax import Model
    from gpjax._coefficients import Coefficients
    from gpjax._synthetic import generate
    from gpjax._system_diagnose import residual_statistics, summary_line
    from gpjax.systems import Excitation, get_system

    system = dataclasses.replace(
        get_system("duffing"), constants={"m": 1.0, "c": 0.25, "k": -1.0, "k3": 1.0},
        excitation=Excitation(low=0.1, high=0.3, rms=0.3), sample_rate=10.0, duration=300.0)
    record = generate(system, seed=0, noise=0.02, input_noise=0.02).fit
    x, v = sp.symbols("x x_dot")
    y0 = (float(record.response_true[0, 0]), float(record.velocity_true[0, 0]))
    model = Model.from_equations(("x",), "t", ("u",), [Coefficients(
        1.0, {v: 0.25, x: -1.0, x ** 3: 1.0}, {sp.Symbol("u"): 1.0}, y0)], substeps=4)
    statistics = residual_statistics(model, record.measurement())["x"]
    assert statistics["noise"]["input_scaling"] < 1.5 and "ratio_with_input" not in statistics["noise"]
    assert "not a smooth function of its input" in summary_line("x", statistics)


def test_a_model_without_its_input_is_not_read_as_a_chaotic_response():
    """A model whose forcing lacks the input (a search that missed it): the input's noise
    moves its response by 0, which is proportional (scaling 2), so the line counts a share
    of 0 and does not call the response chaotic."""
    import sympy as sp

    from gpjax import Model
    from gpjax._coefficients import Coefficients
    from gpjax._synthetic import generate
    from gpjax._system_diagnose import residual_statistics, summary_line
    from gpjax.systems import get_system

    record = generate(get_system("duffing"), seed=0, noise=0.01, input_noise=0.04).fit
    x, v = sp.symbols("x x_dot")
    model = Model.from_equations(("x",), "t", ("u",), [Coefficients(
        1.0, {v: 2.0, x: 40.0}, {}, (0.0, 0.0))], substeps=2)
    statistics = residual_statistics(model, record.measurement())["x"]
    assert statistics["noise"]["input_sigma"] == 0.0
    assert statistics["noise"]["input_scaling"] == 2.0
    assert statistics["noise"]["ratio_with_input"] == statistics["noise"]["ratio"]
    assert "not a smooth function of its input" not in summary_line("x", statistics)


def test_the_console_script_is_main_without_the_last_collection(monkeypatch):
    """``gpjax`` and ``python -m gpjax`` return :func:`gpjax.cli.main`'s status and skip
    the interpreter's last garbage collection (``gc.freeze``: ~0.5 s of a warm demo);
    ``main`` itself, which tests and notebooks call in a living process, does not."""
    import tomllib

    from gpjax import cli

    frozen = []
    monkeypatch.setenv("JAX_PLATFORMS", "cpu")  # console() sets it where unset: restored after
    monkeypatch.setattr(cli.gc, "freeze", lambda: frozen.append(True))
    monkeypatch.setattr(cli, "main", lambda: 2)
    assert cli.console() == 2 and frozen == [True]
    project = tomllib.loads((Path(__file__).parents[1] / "pyproject.toml").read_text())
    assert project["project"]["scripts"]["gpjax"] == "gpjax.cli:console"
    assert "console()" in (Path(cli.__file__).parent / "__main__.py").read_text()


@pytest.mark.parametrize("chosen", [None, "cuda"])
def test_the_console_script_runs_on_the_cpu_unless_told(monkeypatch, chosen):
    """``gpjax`` on a GPU machine ran on the GPU, where its sequential RK4 scan is slower
    than on the CPU at every default setting (:func:`gpjax.cli.console`): the command line
    now sets ``JAX_PLATFORMS=cpu`` before JAX starts, unless the user named a platform."""
    from gpjax import cli

    if chosen is None:
        monkeypatch.delenv("JAX_PLATFORMS", raising=False)
    else:
        monkeypatch.setenv("JAX_PLATFORMS", chosen)
    seen = []
    monkeypatch.setattr(cli.gc, "freeze", lambda: None)
    monkeypatch.setattr(cli, "main", lambda: seen.append(os.environ.get("JAX_PLATFORMS")) or 0)
    assert cli.console() == 0 and seen == [chosen or "cpu"]


def test_a_closed_stdout_ends_the_command_quietly():
    """``gpjax fit … | head -1``: once the reader has gone, printing the rest raised
    BrokenPipeError and a traceback followed the results."""
    program = ("import sys; from gpjax import cli\n"
               "def handler(args):\n    print('x' * 100_000)\n    return 0\n"
               "cli._demo = handler\n"
               "sys.exit(cli.main(['demo']))\n")
    read, write = os.pipe()
    os.close(read)  # the reader has gone before the command writes
    try:
        done = subprocess.run([sys.executable, "-c", program], stdout=write,
                              stderr=subprocess.PIPE, text=True, timeout=120)
    finally:
        os.close(write)
    assert done.returncode == 1
    assert "Traceback" not in done.stderr and "BrokenPipe" not in done.stderr, done.stderr
