"""Island-model GP on Dask: ``Identifier(config).fit(measurement, islands=K)``.

The population is split into K islands (sizes differ by at most one), each the ordinary
GP engine (:func:`~gpjax._evolve.evolution_for`: one coordinate's
:class:`~gpjax._evolve.Evolution` or a system's
:class:`~gpjax._system_search.SystemEvolution`) with its own seed from
``numpy.random.SeedSequence(seed).spawn(K)``. An *epoch* runs ``Migration.every``
generations of every island as one Dask task, ``(data, config, island state) -> island
state``, the state being the engine's JSON-ready checkpoint (``state_json``).
Between epochs, on the client, each island's best ``migrants`` distinct structures (the
head of its ranked population, with their records) replace the worst of the next island:
ring ``i -> i + 1``, or a ring in a random order drawn from (seed, epoch). All islands are
checkpointed after every epoch (``checkpoint.json``, atomic); resume reads it.

Tasks are pure functions of their inputs, so a task whose worker dies is run again by the
scheduler on another worker from the same state, with the same result. A worker keeps
each island's compiled evaluator (:func:`_engine`) and is given the same islands again,
so it compiles once per island it hosts (K = workers: once). The run stops when an island
reaches epsilon or all have run ``generations``; the reported model is then selected from
the records of all islands by the same code as a one-process run
(:meth:`Identifier._finish`).
"""

from __future__ import annotations

import collections
import dataclasses
import json
import os
import time
import uuid
from pathlib import Path

import numpy as np

from . import _progress
from ._aot import compile_ledger
from ._cluster import dask_client, worker_address
from ._config import GPConfig
from ._data import Measurement
from ._errors import UserInputError
from ._evolve import GenerationStats, evolution_for
from ._island_settings import Migration, island_plan, island_seeds
from ._objective import stop_objective
from ._report import write_text_atomic

#: Island engines (compiled evaluators) a worker keeps.
ENGINES_PER_WORKER = 8


# --- worker side ----------------------------------------------------------------------
_ENGINES: collections.OrderedDict = collections.OrderedDict()


def _engine(measurement: Measurement, config: GPConfig, island: int, state: dict | None):
    """This worker's GP engine (:func:`gpjax._evolve.evolution_for`) for ``island`` and
    whether it was built now.

    A kept engine is reused only when its forcing columns are those ``state`` recorded
    (a fresh engine's, for a new island), so reuse gives bit for bit what a fresh engine
    loaded from ``state`` gives; its records are replaced by the state's.
    """
    key = (measurement.fingerprint(), json.dumps(config.to_dict(), sort_keys=True), island)
    evolution = _ENGINES.pop(key, None)
    if evolution is not None:
        expected = state["forcing_features"] if state else evolution.fresh_columns
        if evolution.forcing_columns() != expected:
            evolution = None
    built = evolution is None
    if built:
        evolution = evolution_for(measurement, config)
    evolution.reset()
    _ENGINES[key] = evolution
    while len(_ENGINES) > ENGINES_PER_WORKER:
        _ENGINES.popitem(last=False)
    return evolution, built


def run_epoch(measurement: Measurement, config: GPConfig, island: int, seed: int,
              state: dict | None, until: int, migrants: int) -> dict:
    """Dask task: island ``island`` from ``state`` (``None``: generation 0 from ``seed``)
    to generation ``until`` or its stop rule.

    Returns:
        ``state`` (the new island state), ``emigrants`` (its best ``migrants`` distinct
        valid structures: tree and record), ``worker`` (address), ``built`` (whether the
        engine was compiled here), ``generations`` (run here, generation 0 included),
        ``seconds`` and ``compile_s``.
    """
    began = time.perf_counter()
    evolution, built = _engine(measurement, config, island, state)
    compiled = compile_ledger()[0]  # this worker process's programs
    run = evolution.start(seed) if state is None else evolution.load_state(state)
    first = run.generation if state is not None else -1
    while run.generation < until and not run.done:
        run = evolution.step(run)
    return {"state": evolution.state_json(run), "emigrants": evolution.emigrants(run, migrants),
            "worker": worker_address(), "built": built,
            "generations": run.generation - first, "seconds": time.perf_counter() - began,
            "compile_s": compile_ledger()[0] - compiled}


# --- client side ----------------------------------------------------------------------
def migrate(results: list[dict], migration: Migration, *, seed: int, epoch: int) -> list[dict]:
    """Island states after migration: each receiver's worst individuals replaced by its
    sender's emigrants (their records kept where better than the receiver's own)."""
    k = len(results)
    if k == 1 or migration.migrants == 0:
        return [r["state"] for r in results]
    order = (np.arange(k) if migration.topology == "ring"
             else np.random.default_rng([seed, epoch]).permutation(k))
    sender = {int(order[j]): int(order[j - 1]) for j in range(k)}
    states = []
    for i in range(k):
        state = dict(results[i]["state"])
        arriving = results[sender[i]]["emigrants"]
        if arriving:
            state["population"] = (state["population"][: -len(arriving)]
                                   + [m["tree"] for m in arriving])
            records = {r["key"]: r for r in state["records"]}
            for m in arriving:
                own = records.get(m["record"]["key"])
                if own is None or m["record"]["objective"] < own["objective"]:
                    records[m["record"]["key"]] = m["record"]
            state["records"] = list(records.values())
        states.append(state)
    return states


def _finished(states: list[dict | None], config: GPConfig, threshold: float) -> bool:
    """Whether every island has run, and one reached ``threshold`` (the record's
    :func:`gpjax._objective.stop_objective`) or all ran their generations."""
    if any(s is None for s in states):
        return False
    reached = any(s["history"][-1]["best_objective"] <= threshold for s in states)
    return reached or all(s["generation"] >= config.generations for s in states)


def merged_history(states: list[dict]) -> list[dict]:
    """One history row per generation across islands (best objective and its key over
    islands, median of the island medians, mean valid fraction, distinct structures
    summed over islands, the slowest island's seconds); an island that stopped early (it
    reached epsilon) counts with its last row."""
    history = []
    for generation in range(max(len(s["history"]) for s in states)):
        rows = [s["history"][min(generation, len(s["history"]) - 1)] for s in states]
        best = min(rows, key=lambda r: r["best_objective"])
        medians = [r["median_objective"] for r in rows if r["median_objective"] is not None]
        history.append(dataclasses.asdict(GenerationStats(
            generation=generation, best_objective=best["best_objective"],
            median_objective=float(np.median(medians)) if medians else None,
            valid_fraction=float(np.mean([r["valid_fraction"] for r in rows])),
            unique_structures=sum(r["unique_structures"] for r in rows),
            seconds=max(r["seconds"] for r in rows), best_key=best["best_key"])))
    return history


def merged_state(states: list[dict]) -> dict:
    """One state JSON holding every island's records (the best of a key's copies) and
    their :func:`merged_history`, for the final selection."""
    records: dict[str, dict] = {}
    for state in states:
        for record in state["records"]:
            own = records.get(record["key"])
            if own is None or record["objective"] < own["objective"]:
                records[record["key"]] = record
    features = list(dict.fromkeys(f for s in states for f in s["forcing_features"]))
    return {"generation": max(s["generation"] for s in states),
            "population": [t for s in states for t in s["population"]],
            "rng_state": states[0]["rng_state"], "history": merged_history(states),
            "done": True,
            "records": list(records.values()), "forcing_features": features}


def fit_islands(identifier, measurement: Measurement, *, seed: int, out, resume: bool,
                islands: int | None, scheduler: str | None, migration: Migration | None,
                progress: bool | None = None):
    """:meth:`Identifier.fit` with ``islands`` (see the module docstring); returns the
    fitted ``identifier``, whose ``timings_`` also hold ``epochs``, ``island_tasks`` (per
    task: worker, built, generations, seconds, compile_s), ``epoch_timings`` (wall,
    client seconds, checkpoint bytes) and ``worker_compile_s``.

    Raises:
        UserInputError: no ``islands`` given, bad island settings, a bad checkpoint to
            resume, or an unreachable scheduler.
    """
    from ._estimator import _StopOnInterrupt

    config = identifier.config
    configs, migration = island_plan(config, islands, scheduler=scheduler, migration=migration)
    out = Path(out) if out is not None else None
    fingerprint = measurement.fingerprint()
    threshold = stop_objective(measurement, config)
    began, compiled = time.perf_counter(), compile_ledger()
    settings = {"migration": dataclasses.asdict(migration)}
    if resume:
        epoch, seed, states = _load(out, config, fingerprint, islands, settings)
    else:
        epoch, states = 0, [None] * islands
    seeds = island_seeds(seed, islands)
    tasks: list[dict] = []
    epochs: list[dict] = []
    logged = 0 if states[0] is None else len(merged_history(states))  # generations
    with dask_client(scheduler, workers=min(islands, os.cpu_count() or 1)) as client, \
            _StopOnInterrupt() as stop, \
            _progress.bar(config.generations, progress=progress) as bar:
        _progress.stage(f"{islands} islands on Dask, migrating every {migration.every} "
                        "generations; each island's first task compiles (or loads) its "
                        "evaluator")
        placement: list[str | None] = [None] * islands
        run_id = uuid.uuid4().hex[:8]
        while not _finished(states, config, threshold) and not stop.requested:
            until = min((epoch + 1) * migration.every, config.generations)
            submitted = time.perf_counter()
            futures = [client.submit(
                run_epoch, measurement, configs[i], i, seeds[i], states[i], until,
                migration.migrants, key=f"gpjax-island-{run_id}-{epoch}-{i}", pure=False,
                **({"workers": placement[i], "allow_other_workers": True} if placement[i]
                   else {})) for i in range(islands)]
            results = client.gather(futures)
            gathered = time.perf_counter()
            placement = [r["worker"] for r in results]
            tasks += [{k: r[k] for k in ("worker", "built", "generations", "seconds",
                                         "compile_s")}
                      | {"epoch": epoch, "island": i} for i, r in enumerate(results)]
            epoch += 1
            states = [r["state"] for r in results]
            if not _finished(states, config, threshold):
                states = migrate(results, migration, seed=seed, epoch=epoch)
            text = json.dumps({"config": config.to_dict(), "seed": seed, "data": fingerprint,
                               "epoch": epoch, "islands": states} | settings)
            states = json.loads(text)["islands"]  # as a resumed run reads them
            if out is not None:
                write_text_atomic(out / "checkpoint.json", text)
            epochs.append({"epoch": epoch - 1, "wall_s": gathered - submitted,
                           "client_s": time.perf_counter() - gathered,
                           "checkpoint_bytes": len(text)})
            bar.update(min(until, config.generations) - bar.n)
            history = merged_history(states)
            for row in history[logged:]:
                _progress.generation(row["generation"], config.generations,
                                     row["best_objective"], row["seconds"])
            logged = len(history)
    evolution = evolution_for(measurement, configs[0])
    state = evolution.load_state(merged_state(states))
    identifier.measurement_ = measurement
    identifier._provenance = {"islands": islands} | settings
    identifier._conclude(evolution, seed, state, began=began, compiled=compiled, out=out,
                         interrupted=stop.requested)
    identifier.timings_ |= {"epochs": epoch, "island_tasks": tasks, "epoch_timings": epochs,
                            "worker_compile_s": sum(t["compile_s"] for t in tasks)}
    return identifier


def _load(out: Path | None, config: GPConfig, fingerprint: str, islands: int,
          settings: dict) -> tuple[int, int, list[dict]]:
    """(epoch, seed, island states) of the island checkpoint in ``out``; raises
    UserInputError for a missing, damaged or foreign one."""
    path = None if out is None else out / "checkpoint.json"
    if path is None or not path.is_file():
        raise UserInputError(f"no checkpoint to resume in {out}; run without --resume first")
    try:
        payload = json.loads(path.read_text(encoding="utf-8"))
        found = len(payload.get("islands", []))
        problem = ("a one-process run's; resume without --islands" if "islands" not in payload
                   else f"for {found} islands; resume with --islands {found}"
                   if found != islands
                   else "for other data; resume with the same CSV and columns"
                   if payload["data"] != fingerprint
                   else "with other settings; resume with the same configuration"
                   if (payload["config"] != config.to_dict()
                       or payload["migration"] != settings["migration"]) else "")
        if problem:
            raise UserInputError(f"{path} was written {problem}")
        return int(payload["epoch"]), int(payload["seed"]), list(payload["islands"])
    except (KeyError, TypeError, ValueError) as err:
        if isinstance(err, UserInputError):
            raise
        raise UserInputError(f"{path} is damaged ({err}); start the run afresh without "
                             "--resume") from None
