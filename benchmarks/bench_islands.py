"""Islands on a LocalCluster of 2 workers against 1 process, and a measured cost model.

Part ``compare``: the paper's protocol on the bundled gear example (P = 500 in all,
<= 10 generations), one process against K = 2 islands of 250 (ring, 2 migrants every
2 generations) on a LocalCluster of 2 workers started beforehand, over seeds; with
eps = 0.01 (time to reach it) and eps = 0 (all 10 generations: final objective).
``--cache off``: every run compiles, as a first run does; ``--cache warm``: the
compilation cache (a temporary folder) is filled by one discarded run of each mode first.
``--hard``: a harder search, eps = 0.01 only: P = 60 (islands of 30), pure GP
(``local_search = 0``), ``refine_top = 1``; it needs several generations or fails.

Part ``overhead``: K = 2, 4, 8 islands of 60 on the same 2 workers, every = 1 (compilation
cache on, in a temporary folder): per-task scheduling overhead and the client's
migration + checkpoint time against K, fitted as lines for the cost model.

    python benchmarks/bench_islands.py compare --seeds 3 --json benchmarks/islands_compare.json
    python benchmarks/bench_islands.py compare --cache warm --json benchmarks/islands_warm.json
    python benchmarks/bench_islands.py compare --cache warm --hard --seeds 8 \
        --json benchmarks/islands_hard.json
    python benchmarks/bench_islands.py overhead --json benchmarks/islands_overhead.json
    python benchmarks/bench_islands.py model     # reads both JSON files, writes islands_model.json
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from _provenance import provenance

HERE = Path(__file__).resolve().parent


def _cluster(env: dict):
    from distributed import Client, LocalCluster

    began = time.perf_counter()
    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                           dashboard_address=None, env=env)
    client = Client(cluster)
    return cluster, client, time.perf_counter() - began


def compare(seeds: int, cache: str, hard: bool) -> dict:
    from gpjax import GPConfig, Identifier, Migration
    from gpjax.gear import load_bundled_example

    env = ({"GPJAX_COMPILATION_CACHE": "off"} if cache == "off" else
           {"GPJAX_COMPILATION_CACHE": "on",
            "GPJAX_CACHE_DIR": tempfile.mkdtemp(prefix="gpjax-bench-cache-")})
    os.environ.update(env)
    measurement, _ = load_bundled_example()
    cluster, client, startup = _cluster(env)
    rows = []
    settings = dict(population=60, local_search=0, refine_top=1) if hard else {}
    plan = ([(0.01, 1000, True)] if cache == "warm" else []) + [
        (epsilon, seed, False) for epsilon in ((0.01,) if hard else (0.01, 0.0))
        for seed in range(seeds)]
    for epsilon, seed, warm_up in plan:
        for mode in ("1 process", "2 islands"):
            options = ({} if mode == "1 process" else
                       dict(islands=2, scheduler=cluster.scheduler_address,
                            migration=Migration(every=2, migrants=2)))
            began = time.perf_counter()
            identifier = Identifier(GPConfig.paper(epsilon=epsilon, **settings)).fit(
                measurement, seed=seed, progress=False, **options)
            wall = time.perf_counter() - began
            if warm_up:
                continue
            history = identifier.history_
            rows.append({
                "mode": mode, "epsilon": epsilon, "seed": seed, "wall_s": wall,
                "generations": identifier.timings_["generations"],
                "search_best_objective": history[-1]["best_objective"],
                "stopped_by": identifier.stopped_by,
                "convergence_s": identifier.timings_["convergence_s"],
                "reported_objective": identifier.model_.metrics["objective"],
                "equation": str(identifier.model_.equation()),
                "client_compile_s": identifier.timings_["compile_s"],
                "worker_compile_s": identifier.timings_.get("worker_compile_s"),
                "generation_s": [h["seconds"] for h in history],
                "island_tasks": identifier.timings_.get("island_tasks"),
                "epoch_timings": identifier.timings_.get("epoch_timings")})
            print(f"{mode:>10} eps={epsilon:<5} seed={seed} wall {wall:6.1f} s  gens "
                  f"{rows[-1]['generations']:>2}  best f {history[-1]['best_objective']:.4g}"
                  f"  reported f {rows[-1]['reported_objective']:.4g}", flush=True)
    client.close()
    cluster.close()
    return {"cluster_startup_s": startup, "cache": cache, "settings": settings, "runs": rows}


def overhead() -> dict:
    from gpjax import GPConfig, Identifier, Migration
    from gpjax.gear import load_bundled_example

    cache = tempfile.mkdtemp(prefix="gpjax-bench-cache-")
    env = {"GPJAX_COMPILATION_CACHE": "on", "GPJAX_CACHE_DIR": cache}
    os.environ.update(env)
    measurement, _ = load_bundled_example()
    cluster, client, _ = _cluster(env)
    rows = []
    for k in (2, 4, 8):
        for repeat in range(2):  # the first warms the cache for these shapes
            identifier = Identifier(GPConfig.paper(population=60 * k, generations=6,
                                                   epsilon=0.0)).fit(
                measurement, seed=0, progress=False, islands=k,
                scheduler=cluster.scheduler_address, migration=Migration(every=1))
            if repeat == 0:
                continue
            tasks = identifier.timings_["island_tasks"]
            for epoch in identifier.timings_["epoch_timings"]:
                if epoch["epoch"] == 0:
                    continue  # builds the engines
                mine = [t for t in tasks if t["epoch"] == epoch["epoch"]]
                compute = sum(t["seconds"] for t in mine)
                rows.append({"islands": k, "epoch": epoch["epoch"], "wall_s": epoch["wall_s"],
                             "task_s": [t["seconds"] for t in mine],
                             # 2 workers: the ideal wall is the larger worker's share
                             "ideal_s": max(sum(t["seconds"] for t in mine
                                                if t["worker"] == w)
                                            for w in {t["worker"] for t in mine}),
                             "compute_s": compute, "client_s": epoch["client_s"],
                             "checkpoint_bytes": epoch["checkpoint_bytes"]})
            print(f"K={k}: " + ", ".join(f"wall {r['wall_s']:.3f} ideal {r['ideal_s']:.3f} "
                                         f"client {r['client_s']:.3f}"
                                         for r in rows if r["islands"] == k), flush=True)
    client.close()
    cluster.close()
    return {"runs": rows}


def model() -> dict:
    """Cost model: epoch time = every * t_gen(p) + overhead(K) + client(K)."""
    compare_runs = json.loads((HERE / "islands_compare.json").read_text())["runs"]
    over = json.loads((HERE / "islands_overhead.json").read_text())["runs"]
    single = [g for r in compare_runs if r["mode"] == "1 process" and r["epsilon"] == 0.0
              for g in r["generation_s"][1:]]
    island = [t["seconds"] / t["generations"] for r in compare_runs
              if r["mode"] == "2 islands" and r["epsilon"] == 0.0
              for t in r["island_tasks"] if not t["built"]]
    ks = np.array(sorted({r["islands"] for r in over}), float)  # medians per K (a loaded
    scheduling = np.array([np.median([r["wall_s"] - r["ideal_s"] for r in over  # machine)
                                      if r["islands"] == k]) for k in ks])
    client = np.array([np.median([r["client_s"] for r in over if r["islands"] == k])
                       for k in ks])
    sched_fit = np.polyfit(ks, scheduling, 1)
    client_fit = np.polyfit(ks, client, 1)
    t_gen = float(np.median(island))
    every = 2
    projection = []
    for workers in (2, 8, 64, 512):
        epoch = every * t_gen + np.polyval(sched_fit, workers) + np.polyval(client_fit, workers)
        projection.append({"workers": workers, "islands": workers, "population": 250 * workers,
                           "epoch_s": float(epoch),
                           "generation_s": float(epoch / every),
                           "overhead_share": float(1 - every * t_gen / epoch)})
    return {"single_process_generation_s_P500": float(np.median(single)),
            "island_generation_s_P250": t_gen,
            "scheduling_s_per_epoch": {"intercept": float(sched_fit[1]),
                                       "per_island": float(sched_fit[0])},
            "client_migration_checkpoint_s_per_epoch": {"intercept": float(client_fit[1]),
                                                        "per_island": float(client_fit[0])},
            "projection": projection,
            "note": "a projection, not a measurement: one island of 250 per worker, "
                    "every = 2, linear overheads fitted on K = 2, 4, 8 islands on 2 workers"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("part", choices=("compare", "overhead", "model"))
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--cache", choices=("off", "warm"), default="off")
    parser.add_argument("--hard", action="store_true", help="the harder search (see above)")
    parser.add_argument("--json", help="write the results here")
    args = parser.parse_args()
    result = (compare(args.seeds, args.cache, args.hard) if args.part == "compare" else
              overhead() if args.part == "overhead" else model())
    result |= {**provenance(), "load_average_after": os.getloadavg()}
    if args.part == "model":
        for row in result["projection"]:
            print(f"{row['workers']:>4} workers: epoch {row['epoch_s']:.3f} s, "
                  f"{row['generation_s']:.3f} s per generation, overhead "
                  f"{row['overhead_share']:.0%} (projection)")
    path = args.json or (HERE / "islands_model.json" if args.part == "model" else None)
    if path:
        Path(path).write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
