"""Cold and warm whole-process ``gpjax demo`` with the persistent compilation cache.

Each run is a fresh process timed by ``/usr/bin/time`` (wall seconds, peak memory): with
an empty cache folder (cold), again on the filled folder (warm), and with the cache
switched off, ``--repeats`` times each. Prints a table and writes JSON.

    python benchmarks/bench_cache.py --repeats 3 [--baseline REV] --json benchmarks/cache_demo.json

``--baseline REV`` times the same processes with the code of git revision ``REV`` (a
temporary worktree on ``PYTHONPATH``, its own cache folders), each right after this tree's,
so both see the same machine; the JSON then holds the baseline's medians and the ratios.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from _baseline import baseline_tree, in_tree
from _provenance import provenance


def timed_demo(env: dict, out: Path, tree: Path | None = None) -> dict:
    """One ``gpjax demo`` process (of the code at ``tree``; default this one): wall
    seconds, peak RSS (MB), the seconds it printed for compiling or loading its programs,
    and the 1-minute load average after it."""
    command = ["/usr/bin/time", "-f", "TIME %e %M", sys.executable, "-m", "gpjax", "demo",
               "--out", str(out)]
    run = subprocess.run(command, **in_tree(tree, JAX_PLATFORMS="cpu", **env),
                         capture_output=True, text=True, check=True)
    wall, peak = run.stderr.strip().splitlines()[-1].split()[1:]
    compile_s = float(re.search(r"([\d.]+) s (?:of it )?compiling or loading", run.stdout)[1])
    return {"wall_s": float(wall), "peak_mb": int(peak) / 1024, "compile_s": compile_s,
            "load_average_1min": os.getloadavg()[0]}  # the machine's load as it ended


def summarise(rows: list[dict]) -> dict:
    """Median wall and compiling seconds per cache mode."""
    return {label: {"median_wall_s": float(np.median([r["wall_s"] for r in rows
                                                      if r["cache"] == label])),
                    "median_compile_s": float(np.median([r["compile_s"] for r in rows
                                                         if r["cache"] == label]))}
            for label in ("off", "cold", "warm")}


def timed_modes(scratch: Path, repeats: int, trees: dict) -> dict:
    """Rows per tree (name -> path, ``None`` for this one): every mode and repeat, the
    trees one after the other for each (module docstring)."""
    rows = {name: [] for name in trees}
    for repeat in range(repeats):
        for label in ("off", "cold", "warm"):
            for name, tree in trees.items():
                cache = scratch / f"cache-{name}-{repeat}"
                env = ({"GPJAX_COMPILATION_CACHE": "off"} if label == "off" else
                       {"GPJAX_COMPILATION_CACHE": "on", "GPJAX_CACHE_DIR": str(cache)})
                row = {"cache": label, "repeat": repeat} | timed_demo(env, scratch / "run", tree)
                if label == "warm":
                    row["cache_mb"] = sum(p.stat().st_size for p in cache.rglob("*")
                                          if p.is_file()) / 2**20
                rows[name].append(row)
                print(f"{name:>8} {label:>5} #{repeat}: {row['wall_s']:5.2f} s wall, "
                      f"{row['compile_s']:5.2f} s compiling, peak {row['peak_mb']:.0f} MB",
                      flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--baseline", help="git revision timed in the same run")
    parser.add_argument("--json", help="write the results here")
    args = parser.parse_args()
    scratch = Path(tempfile.mkdtemp(prefix="gpjax-bench-cache-"))
    try:
        with (baseline_tree(args.baseline) if args.baseline else contextlib.nullcontext()) as tree:
            trees = {"this": None} | ({"baseline": tree} if tree else {})
            rows = timed_modes(scratch, args.repeats, trees)
    finally:
        shutil.rmtree(scratch)
    summary = summarise(rows["this"])
    out = {"summary": summary, "runs": rows["this"]}
    print("\n| cache | wall s (median) | compiling s (median) |\n| --- | --- | --- |")
    for label, s in summary.items():
        print(f"| {label} | {s['median_wall_s']:.2f} | {s['median_compile_s']:.2f} |")
    if args.baseline:
        base = summarise(rows["baseline"])
        out["baseline"] = {"revision": args.baseline, "summary": base, "runs": rows["baseline"],
                           "ratio": {k: summary[k]["median_wall_s"] / base[k]["median_wall_s"]
                                     for k in summary}}
        print("ratio of medians to " + args.baseline + ": " + ", ".join(
            f"{k} {v:.2f}" for k, v in out["baseline"]["ratio"].items()))
    if args.json:
        Path(args.json).write_text(json.dumps(
            {**provenance(), "load_average_after": os.getloadavg(),
             "runs_of": "gpjax demo (paper protocol, P = 500, eps = 0.01), one process each",
             **out}, indent=1) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
