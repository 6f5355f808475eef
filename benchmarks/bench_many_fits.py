"""Memory of a process that fits one record after another (a notebook, a sweep, a worker of
``fit_many``): memory maps and resident memory after each fit, with this tree and with git
revision ``--baseline`` (a temporary worktree), each tree in one fresh child process.

    python benchmarks/bench_many_fits.py --baseline 3605eef --json benchmarks/many_fits.json

Each fit: Duffing (``gpjax.systems``, seed i, 1 % noise), population 30, one generation, the
compilation cache off (each fit traces and compiles its programs, as a new record does);
the ``Identifier`` is dropped and garbage-collected before counting. Memory maps are the
lines of ``/proc/self/maps`` (Linux only): the kernel refuses a process more than
``vm.max_map_count`` of them (65,530 by default), and XLA then aborts while compiling.
The growth per fit is the mean over the last four fits (the first ones fill bounded
caches: the model evaluators of the last 8 records, ``gpjax._model``). Resident memory
includes what the allocator keeps after freeing. Prints a table and writes JSON.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from _baseline import ROOT, baseline_tree, run_child
from _provenance import provenance

CHILD = """
import gc, json, sys
import gpjax
from gpjax.systems import generate
def counts():
    maps = sum(1 for _ in open("/proc/self/maps"))
    rss = next(int(l.split()[1]) for l in open("/proc/self/status") if l.startswith("VmRSS"))
    return maps, rss / 1024
rows = []
for seed in range(int(sys.argv[1])):
    data = generate("duffing", seed=seed, noise=0.01, input_noise=0.01, extrapolation_scale=1.2)
    config = gpjax.GPConfig(population=30, generations=1, max_degree=3)
    identifier = gpjax.Identifier(config).fit(data.fit.measurement(), seed=seed, progress=False)
    del identifier
    gc.collect()
    maps, rss = counts()
    rows.append({"fit": seed + 1, "maps": maps, "rss_mb": rss})
print(json.dumps(rows))
"""


def run(path: Path, fits: int) -> list[dict]:
    """Per fit, maps and resident MB of one child process running the tree at ``path``;
    raises ``subprocess.CalledProcessError`` when it fails."""
    return run_child(path, CHILD, str(fits))


def slope(rows: list[dict], key: str) -> float:
    """Growth of ``key`` per fit over the last four of ``rows``."""
    return (rows[-1][key] - rows[-5][key]) / 4


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--baseline", required=True, help="git revision to compare with")
    parser.add_argument("--fits", type=int, default=12, help="fits per process (≥ 12)")
    parser.add_argument("--json", help="write the table and the command to this file")
    args = parser.parse_args(argv)
    if args.fits < 12:
        parser.error("--fits must be at least 12 (8 fill the bounded caches, 4 measure)")
    if not Path("/proc/self/maps").exists():
        parser.error("memory maps are read from /proc (Linux only)")
    ours = run(ROOT, args.fits)
    with baseline_tree(args.baseline) as tree:
        theirs = run(tree, args.fits)
    limit = int(Path("/proc/sys/vm/max_map_count").read_text())
    summary = {}
    print(f"| fit | maps ({args.baseline}) | maps (this tree) | RSS MB ({args.baseline}) "
          "| RSS MB (this tree) |\n| ---: | ---: | ---: | ---: | ---: |")
    for a, b in zip(theirs, ours):
        print(f"| {a['fit']} | {a['maps']:,} | {b['maps']:,} | {a['rss_mb']:.0f} "
              f"| {b['rss_mb']:.0f} |")
    for name, rows in ((args.baseline, theirs), ("this tree", ours)):
        per_fit = slope(rows, "maps")
        summary[name] = {"maps_per_fit": per_fit, "rss_mb_per_fit": slope(rows, "rss_mb"),
                         "fits_to_map_limit": (limit - rows[-1]["maps"]) / per_fit + len(rows)
                         if per_fit > 0 else None}
        s = summary[name]
        print(f"{name}: {per_fit:.0f} maps and {s['rss_mb_per_fit']:.1f} MB per fit; "
              f"vm.max_map_count {limit:,} reached after "
              f"{'never' if s['fits_to_map_limit'] is None else round(s['fits_to_map_limit'])} fits")
    if args.json:
        Path(args.json).write_text(json.dumps({
            **provenance(), "max_map_count": limit,
            "baseline": theirs, "this_tree": ours, "summary": summary}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
