"""End-to-end runs: determinism, resume after a kill, other column names."""

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from gpjax import GPConfig, Identifier, load_csv
from gpjax.gear import Torque, generate_gear_example

SMALL = dict(population=60, generations=3, epsilon=0.0, refine_top=3)


def _short_example(**kw):
    return generate_gear_example(revolutions=0.35, **kw)


def test_same_seed_same_model_bit_for_bit(tmp_path):
    measurement = _short_example(seed=1).measurement
    config = GPConfig.paper(**SMALL)
    Identifier(config).fit(measurement, seed=3, out=tmp_path / "a")
    Identifier(config).fit(measurement, seed=3, out=tmp_path / "b")
    a = (tmp_path / "a" / "model.json").read_text()
    assert a == (tmp_path / "b" / "model.json").read_text()
    for name in ("history.csv", "equations.csv", "fit.png", "config.json", "checkpoint.json"):
        assert (tmp_path / "a" / name).is_file()


@pytest.mark.slow
def test_resume_after_sigkill_gives_the_same_model(tmp_path):
    example = _short_example(seed=2)
    csv = tmp_path / "data.csv"
    example.measurement.to_csv(csv)
    config = tmp_path / "config.toml"
    config.write_text("population = 60\ngenerations = 4\nepsilon = 0.0\nrefine_top = 3\n")
    base = [sys.executable, "-m", "gpjax", "fit", str(csv), "--time", "t", "--response", "phi",
            "--input", "T", "--config", str(config), "--seed", "5"]
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    subprocess.run(base + ["--out", str(tmp_path / "full")], check=True, env=env,
                   capture_output=True)
    run = tmp_path / "killed"
    process = subprocess.Popen(base + ["--out", str(run)], env=env,
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 300
    while time.time() < deadline:  # kill once generation 1 or later is checkpointed
        checkpoint = run / "checkpoint.json"
        if checkpoint.is_file() and json.loads(checkpoint.read_text())["state"]["generation"] >= 1:
            break
        time.sleep(0.05)
    process.send_signal(signal.SIGKILL)
    process.wait()
    assert not (run / "model.json").exists()
    subprocess.run(base + ["--out", str(run), "--resume"], check=True, env=env,
                   capture_output=True)
    assert (run / "model.json").read_text() == (tmp_path / "full" / "model.json").read_text()


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="issue 2 open: with default settings GP often stops at "
                   "the linear-plus-offset model (k1*x + g1 = T) and misses x**2")
def test_fit_with_other_names_and_torque_recovers_eq14_structure(tmp_path):
    torque = Torque(mean=9.0, shaft_amplitudes=(0.4, 0.2), shaft_phases=(1.0, 2.0),
                    mesh_amplitudes=(0.9, 0.4, 0.1), mesh_phases=(0.5, 1.5, 3.0))
    example = generate_gear_example(seed=4, torque=torque, time_name="time_s",
                                    response_name="twist", input_name="drive_torque",
                                    revolutions=0.5)
    identifier = Identifier(GPConfig(population=200, generations=6)).fit(
        example.measurement, seed=0)
    model = identifier.model_
    assert sorted(model.state) == ["twist", "twist**2"]
    assert list(model.forcing) == ["drive_torque"]
    truth = example.truth
    constants = model.constants()
    assert constants["m"] == pytest.approx(truth["J"], rel=0.02)
    assert constants["k1"] == pytest.approx(truth["K1"], rel=0.05)
    assert constants["k2"] == pytest.approx(truth["K2"], rel=0.02)


def test_loader_and_reload_of_a_run(tmp_path):
    example = _short_example(seed=0)
    example.measurement.to_csv(tmp_path / "d.csv")
    measurement = load_csv(tmp_path / "d.csv", time="t", response="phi", inputs=["T"])
    identifier = Identifier(GPConfig.paper(**SMALL)).fit(measurement, seed=0, out=tmp_path / "r")
    again = Identifier.load(tmp_path / "r")
    assert again.model_ == identifier.model_
    assert str(again).splitlines()[0] == str(identifier).splitlines()[0]
    assert identifier.score() > 0.9
