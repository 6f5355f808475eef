"""A system (several --response) through the one-coordinate run machinery: checkpoints,
resume after a kill, and islands on Dask."""

import dataclasses
import json
import os
import subprocess
import sys

import pytest
from _runs import kill_and_resume

from gpjax import GPConfig, Identifier, UserInputError, _trees
from gpjax.systems import generate, get_system, write_csv

SMALL = dict(population=30, generations=3, epsilon=0.0)


def _record(seed=1):
    return generate(dataclasses.replace(get_system("chain2"), duration=4.0), seed=seed).fit


def test_a_system_tree_survives_its_json():
    """A system equation's tree (named variables ``("s", name)``) reads back as itself;
    a checkpoint holds the population as such trees."""
    tree = ("add", ("mul", ("n", 2.5), ("s", "x1_ddot")),
            ("sub", ("s", "d_x1_x2"), ("mul", ("u", 0), ("sign", ("s", "x1_dot")))))
    assert _trees.from_json(json.loads(json.dumps(_trees.to_json(tree)))) == tree
    with pytest.raises(ValueError, match="malformed"):
        _trees.from_json(["s", 3])


@pytest.mark.slow
@pytest.mark.handrun  # 4-5 min on 2 cores (three system runs in subprocesses): the hand-run
# tier (README, Quick start); CI's slow step keeps one coordinate's kill and resume
# (tests/test_run.py) and a system's islands resumed (below)
def test_a_system_resumes_after_sigkill_to_the_same_model(tmp_path):
    """kill -9 after generation 1, then ``--resume``: the model of the uninterrupted run,
    byte for byte (the refined constants travel in the checkpoint)."""
    write_csv(_record(), tmp_path / "chain.csv")
    (tmp_path / "config.toml").write_text(
        "".join(f"{k} = {v}\n" for k, v in SMALL.items()))
    base = [sys.executable, "-m", "gpjax", "fit", str(tmp_path / "chain.csv"), "--time", "t",
            "--response", "x1", "--response", "x2", "--input", "u", "--config",
            str(tmp_path / "config.toml"), "--seed", "5"]
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    subprocess.run(base + ["--out", str(tmp_path / "full")], check=True, env=env,
                   capture_output=True)
    expected = (tmp_path / "full" / "model.json").read_text()
    run = tmp_path / "killed"
    assert kill_and_resume(base, run, 1, env) == expected
    checkpoint = json.loads((run / "checkpoint.json").read_text())["state"]
    assert checkpoint["records"] and all("values" in r for r in checkpoint["records"])


@pytest.mark.slow  # ~2 min: two island runs of a system on a two-worker LocalCluster
def test_system_islands_are_deterministic_and_resume(tmp_path):
    """Two islands of a 2-mass chain: the same seed gives the same model bit for bit, the
    model records its islands, and resuming the finished run's checkpoint reports it
    again; a one-process resume of it is refused."""
    from distributed import LocalCluster

    from gpjax import Migration
    measurement = _record().system_measurement()
    config = GPConfig(**SMALL)
    env = {"GPJAX_COMPILATION_CACHE": "on", "GPJAX_CACHE_DIR": str(tmp_path / "cache"),
           "JAX_PLATFORMS": "cpu"}
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None, env=env) as cluster:
        options = dict(seed=4, islands=2, scheduler=cluster.scheduler_address,
                       migration=Migration(every=1, migrants=1), progress=False)
        first = Identifier(config).fit(measurement, out=tmp_path / "a", **options)
        Identifier(config).fit(measurement, out=tmp_path / "b", **options)
        text = (tmp_path / "a" / "model.json").read_text()
        assert text == (tmp_path / "b" / "model.json").read_text()
        assert json.loads(text)["provenance"]["islands"] == 2
        assert first.model_.n_coordinates == 2 and first.convergence_[-1].converged
        checkpoint = json.loads((tmp_path / "a" / "checkpoint.json").read_text())
        assert len(checkpoint["islands"]) == 2 and checkpoint["epoch"] == 3
        assert all(isinstance(s["population"][0], list) and len(s["population"][0]) == 2
                   for s in checkpoint["islands"])  # one tree per equation
        again = Identifier(config).fit(measurement, out=tmp_path / "a", resume=True,
                                       **options)
        assert again.model_ == first.model_
    with pytest.raises(UserInputError, match="island run; resume with --islands 2"):
        Identifier(config).fit(measurement, out=tmp_path / "a", resume=True)
