"""Island-model GP on Dask, fit-many, and the persistent compilation cache.

The cluster tests share one LocalCluster of two workers (compilation cache in a temporary
folder, so a worker compiles an evaluator's shapes once for the whole module).
"""

import json
import os
import signal
import subprocess
import sys
import threading
import time

import pytest

from gpjax import GPConfig, Identifier, Migration, UserInputError, fit_many
from gpjax._island_settings import island_configs, island_seeds
from gpjax._islands import merged_state, migrate
from gpjax.gear import generate_gear_example

SMALL = dict(population=24, generations=4, epsilon=0.0, refine_top=2)
RING = Migration(every=2, migrants=2)


def _measurement(seed=1):
    return generate_gear_example(revolutions=0.35, seed=seed).measurement


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    from distributed import Client, LocalCluster

    cache = tmp_path_factory.mktemp("jax-cache")
    env = {"GPJAX_COMPILATION_CACHE": "on", "GPJAX_CACHE_DIR": str(cache),
           "JAX_PLATFORMS": "cpu"}
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None, env=env) as local, Client(local) as client:
        yield local, client


@pytest.fixture(scope="module")
def reference(cluster, tmp_path_factory):
    """One island run (K = 2, two epochs): (identifier, run folder)."""
    out = tmp_path_factory.mktemp("islands-reference")
    identifier = Identifier(GPConfig.paper(**SMALL)).fit(
        _measurement(), seed=3, out=out, islands=2, scheduler=cluster[0].scheduler_address,
        migration=RING, progress=False)
    return identifier, out


# --- pure parts ---------------------------------------------------------------------------
def test_islands_share_the_population_and_get_independent_seeds():
    configs = island_configs(GPConfig(population=30), 4)
    assert [c.population for c in configs] == [8, 8, 7, 7]
    assert island_seeds(5, 3) == island_seeds(5, 3)
    assert len(set(island_seeds(5, 3))) == 3
    with pytest.raises(UserInputError, match="too small for 8 islands"):
        island_configs(GPConfig(population=30), 8)
    with pytest.raises(UserInputError, match="positive integer"):
        island_configs(GPConfig(), 0)


def test_migration_settings_validate_themselves():
    with pytest.raises(UserInputError, match="every"):
        Migration(every=0)
    with pytest.raises(UserInputError, match="topology"):
        Migration(topology="star")
    with pytest.raises(UserInputError, match="would replace a whole island of 12"):
        Identifier(GPConfig(population=24)).fit(_measurement(), islands=2,
                                                migration=Migration(migrants=12))
    with pytest.raises(UserInputError, match="need islands"):
        Identifier(GPConfig(population=24)).fit(_measurement(), scheduler="tcp://h:1")


def _island(name, objectives):
    records = [{"key": f"{name}{i}", "objective": f} for i, f in enumerate(objectives)]
    state = {"population": [f"{name}-tree{i}" for i in range(len(objectives))],
             "records": records}
    emigrants = [{"tree": f"{name}-tree{i}", "record": records[i]} for i in range(2)]
    return {"state": state, "emigrants": emigrants}


def test_ring_migration_replaces_the_worst_with_the_previous_islands_best():
    results = [_island(n, [1.0, 2.0, 3.0, 4.0]) for n in "abc"]
    results[1]["state"]["records"].append({"key": "a0", "objective": 0.5})  # better own copy
    states = migrate(results, RING, seed=0, epoch=1)
    assert states[0]["population"] == ["a-tree0", "a-tree1", "c-tree0", "c-tree1"]
    assert states[1]["population"][2:] == ["a-tree0", "a-tree1"]
    kept = {r["key"]: r["objective"] for r in states[1]["records"]}
    assert kept["a0"] == 0.5 and kept["a1"] == 2.0
    shuffled = migrate(results, Migration(topology="random"), seed=0, epoch=1)
    assert shuffled == migrate(results, Migration(topology="random"), seed=0, epoch=1)
    assert sorted(s["population"][-1][0] for s in shuffled) == ["a", "b", "c"]


def test_merged_history_takes_the_best_island_per_generation():
    row = dict(generation=0, median_objective=2.0, valid_fraction=0.5, unique_structures=3,
               seconds=1.0)
    states = [{"generation": 0, "population": [], "rng_state": {}, "forcing_features": ["T"],
               "records": [{"key": "k", "objective": f}],
               "history": [row | {"best_objective": f, "best_key": name}]}
              for name, f in (("a", 2.0), ("b", 1.0))]
    merged = merged_state(states)
    assert merged["history"][0]["best_key"] == "b"
    assert merged["history"][0]["unique_structures"] == 6
    assert merged["records"] == [{"key": "k", "objective": 1.0}]
    states[0]["history"].append(row | {"generation": 1, "best_objective": 3.0,
                                       "best_key": "a"})  # b stopped after generation 0
    assert merged_state(states)["history"][1]["best_key"] == "b"


# --- on the cluster -----------------------------------------------------------------------
@pytest.mark.slow  # on the cluster: CI's slow step (fast tier <= 5 min on 2 cores)
def test_same_seed_and_islands_give_the_same_model_bit_for_bit(cluster, reference, tmp_path):
    identifier, out = reference
    again = Identifier(GPConfig.paper(**SMALL)).fit(
        _measurement(), seed=3, out=tmp_path, islands=2,
        scheduler=cluster[0].scheduler_address, migration=RING, progress=False)
    assert (tmp_path / "model.json").read_text() == (out / "model.json").read_text()
    model = json.loads((out / "model.json").read_text())
    assert model["provenance"]["islands"] == 2
    assert again.timings_["epochs"] == 2
    checkpoint = json.loads((out / "checkpoint.json").read_text())
    assert len(checkpoint["islands"]) == 2 and checkpoint["epoch"] == 2


@pytest.mark.slow  # a long run: CI's slow step (fast tier <= 5 min)
def test_the_command_line_runs_islands_and_resumes_them(cluster, tmp_path, capsys):
    from gpjax.cli import main

    _measurement(2).to_csv(tmp_path / "d.csv")
    (tmp_path / "c.toml").write_text("population = 24\ngenerations = 2\nrefine_top = 2\n")
    command = ["fit", str(tmp_path / "d.csv"), "--time", "t", "--response", "phi", "--input",
               "T", "--config", str(tmp_path / "c.toml"), "--out", str(tmp_path / "run"),
               "--islands", "2", "--migrate-every", "1", "--migrants", "1", "--topology",
               "random", "--scheduler", cluster[0].scheduler_address]
    assert main(command) == 0
    text = (tmp_path / "run" / "model.json").read_text()
    provenance = json.loads(text)["provenance"]
    assert provenance["islands"] == 2
    assert provenance["migration"] == {"every": 1, "migrants": 1, "topology": "random"}
    assert main(command + ["--resume"]) == 0  # a finished run: selection and write-out again
    assert (tmp_path / "run" / "model.json").read_text() == text
    assert "phi_ddot" in capsys.readouterr().out


@pytest.mark.slow  # on the cluster: CI's slow step (fast tier <= 5 min on 2 cores)
def test_each_worker_builds_its_island_once(reference):
    tasks = reference[0].timings_["island_tasks"]
    assert sum(t["built"] for t in tasks) == 2
    first = {t["island"]: t["worker"] for t in tasks if t["epoch"] == 0}
    assert len(set(first.values())) == 2
    assert all(t["worker"] == first[t["island"]] for t in tasks)


@pytest.mark.slow
@pytest.mark.handrun  # minutes on 2 cores: the hand-run tier (README, Quick start)
def test_resume_of_an_interrupted_island_run_gives_the_same_model(cluster, tmp_path):
    config = GPConfig.paper(**SMALL | {"generations": 6})
    options = dict(seed=3, islands=2, scheduler=cluster[0].scheduler_address,
                   migration=RING, progress=False)
    Identifier(config).fit(_measurement(), out=tmp_path / "full", **options)
    run = tmp_path / "interrupted"

    def interrupt():
        while not (run / "checkpoint.json").exists():
            time.sleep(0.01)
        os.kill(os.getpid(), signal.SIGINT)  # stops after the current epoch

    threading.Thread(target=interrupt, daemon=True).start()
    stopped = Identifier(config).fit(_measurement(), out=run, **options)
    assert stopped.stopped_by == "interrupted"
    assert json.loads((run / "checkpoint.json").read_text())["epoch"] < 3
    Identifier(config).fit(_measurement(), out=run, resume=True, **options)
    assert (run / "model.json").read_text() == (tmp_path / "full" / "model.json").read_text()
    with pytest.raises(UserInputError, match="island run; resume with --islands 2"):
        Identifier(config).fit(_measurement(), out=run, resume=True)
    with pytest.raises(UserInputError, match="resume with --islands 2"):
        Identifier(config).fit(_measurement(), out=run, resume=True,
                               **options | {"islands": 3})


@pytest.mark.slow
def test_losing_a_worker_mid_run_does_not_lose_the_run(reference, tmp_path):
    """A worker killed while its island compiles: the scheduler reruns the task on
    another worker from the same state; the model is the uninterrupted run's."""
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as local, Client(local) as client:
        pids = client.run(os.getpid)
        killed = {}

        def kill():
            busy = []
            while not busy:
                busy = [worker for worker, keys in client.processing().items()
                        if any("gpjax-island" in str(key) for key in keys)]
                time.sleep(0.05)
            time.sleep(1.0)  # epoch 0 builds the engines: seconds of compiling, no cache here
            killed["before_first_checkpoint"] = not (tmp_path / "checkpoint.json").exists()
            os.kill(pids[busy[0]], signal.SIGKILL)

        threading.Thread(target=kill, daemon=True).start()
        Identifier(GPConfig.paper(**SMALL)).fit(
            _measurement(), seed=3, out=tmp_path, islands=2,
            scheduler=local.scheduler_address, migration=RING, progress=False)
    assert killed == {"before_first_checkpoint": True}
    assert (tmp_path / "model.json").read_text() == (reference[1] / "model.json").read_text()


@pytest.mark.slow  # a long run: CI's slow step (fast tier <= 5 min)
def test_fit_many_writes_every_good_record_and_a_row_per_bad_one(cluster, tmp_path, capsys):
    import csv

    from gpjax.cli import main

    data = tmp_path / "records"
    data.mkdir()
    for seed in (0, 1):
        _measurement(seed).to_csv(data / f"gear{seed}.csv")
    (data / "broken.csv").write_text("t,phi,T\n0,1,2\n")
    (tmp_path / "small.toml").write_text("population = 24\ngenerations = 1\nrefine_top = 2\n")
    status = main(["fit-many", str(data), "--time", "t", "--response", "phi", "--input", "T",
                   "--config", str(tmp_path / "small.toml"), "--out", str(tmp_path / "out"),
                   "--scheduler", cluster[0].scheduler_address])
    err = capsys.readouterr().err
    assert status == 2 and err.splitlines()[-1].startswith("gpjax: error: 1 of 3 records failed")
    assert "gpjax: record gear1 fitted" in err  # the progress lines before it
    rows = list(csv.DictReader((tmp_path / "out" / "summary.csv").open()))
    assert [r["record"] for r in rows] == ["broken", "gear0", "gear1"]
    assert "1 data rows" in rows[0]["error"] and not rows[0]["equation"]
    assert all(r["error"] == "" and "phi_ddot" in r["equation"] and float(r["rms"]) > 0
               and 0 <= float(r["compile_s"]) < float(r["seconds"]) for r in rows[1:])
    assert (tmp_path / "out" / "gear1" / "model.json").is_file()
    assert not (tmp_path / "out" / "broken").exists()
    assert fit_many(data / "gear0.csv", time="t", response="phi", inputs=("T",),
                    config=GPConfig(population=24, generations=1), out=tmp_path / "one",
                    scheduler=cluster[0].scheduler_address)[0]["error"] == ""


# --- compilation cache --------------------------------------------------------------------
_TINY_FIT = """
import json, jax, sys
import gpjax
assert jax.config.jax_compilation_cache_dir is None  # importing changes nothing
from gpjax import GPConfig, Identifier
from gpjax.gear import generate_gear_example
m = generate_gear_example(revolutions=0.35, seed=1).measurement
i = Identifier(GPConfig.paper(population=12, generations=1, refine_top=1)).fit(m, seed=0)
print(json.dumps([jax.config.jax_compilation_cache_dir, i.timings_["compile_s"]]))
"""


def _tiny_fit(env):
    env = dict(os.environ, JAX_PLATFORMS="cpu", **env)
    run = subprocess.run([sys.executable, "-c", _TINY_FIT], env=env, capture_output=True,
                         text=True, timeout=240, check=True)
    return json.loads(run.stdout.splitlines()[-1])


@pytest.mark.slow  # a long run: CI's slow step (fast tier <= 5 min)
def test_a_second_process_loads_its_compiled_programs_from_the_cache(tmp_path):
    cache = tmp_path / "cache"
    folder, cold = _tiny_fit({"GPJAX_CACHE_DIR": str(cache), "GPJAX_COMPILATION_CACHE": "on"})
    assert folder == str(cache) and any(cache.iterdir())
    _, warm = _tiny_fit({"GPJAX_CACHE_DIR": str(cache), "GPJAX_COMPILATION_CACHE": "on"})
    assert warm < 0.6 * cold
    folder, _ = _tiny_fit({"GPJAX_CACHE_DIR": str(tmp_path / "unused"),
                           "GPJAX_COMPILATION_CACHE": "off"})
    assert folder is None and not (tmp_path / "unused").exists()


def test_cache_folder_follows_the_environment(monkeypatch, tmp_path):
    from gpjax._jaxcache import cache_folder

    monkeypatch.setenv("GPJAX_COMPILATION_CACHE", "on")
    monkeypatch.setenv("GPJAX_CACHE_DIR", str(tmp_path))
    assert cache_folder() == tmp_path
    monkeypatch.delenv("GPJAX_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    if sys.platform.startswith("linux"):
        assert cache_folder() == tmp_path / "xdg" / "gpjax" / "jax"
    monkeypatch.setenv("GPJAX_COMPILATION_CACHE", "OFF")
    assert cache_folder() is None
