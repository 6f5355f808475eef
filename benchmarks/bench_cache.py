"""Cold and warm whole-process ``gpjax demo`` with the persistent compilation cache.

Each run is a fresh process timed by ``/usr/bin/time`` (wall seconds, peak memory): with
an empty cache folder (cold), again on the filled folder (warm), and with the cache
switched off, ``--repeats`` times each. Prints a table and writes JSON.

    python benchmarks/bench_cache.py --repeats 3 --json benchmarks/cache_demo.json
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from _provenance import provenance


def timed_demo(env: dict, out: Path) -> dict:
    """One ``gpjax demo`` process: wall seconds, peak RSS (MB), the seconds it printed
    for compiling or loading its programs, and the 1-minute load average after it."""
    command = ["/usr/bin/time", "-f", "TIME %e %M", sys.executable, "-m", "gpjax", "demo",
               "--out", str(out)]
    run = subprocess.run(command, env=dict(os.environ, JAX_PLATFORMS="cpu", **env),
                         capture_output=True, text=True, check=True)
    wall, peak = run.stderr.strip().splitlines()[-1].split()[1:]
    compile_s = float(re.search(r"([\d.]+) s (?:of it )?compiling or loading", run.stdout)[1])
    return {"wall_s": float(wall), "peak_mb": int(peak) / 1024, "compile_s": compile_s,
            "load_average_1min": os.getloadavg()[0]}  # the machine's load as it ended


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", help="write the results here")
    args = parser.parse_args()
    scratch = Path(tempfile.mkdtemp(prefix="gpjax-bench-cache-"))
    rows = []
    for repeat in range(args.repeats):
        cache = scratch / f"cache{repeat}"
        on = {"GPJAX_COMPILATION_CACHE": "on", "GPJAX_CACHE_DIR": str(cache)}
        for label, env in (("off", {"GPJAX_COMPILATION_CACHE": "off"}), ("cold", on),
                           ("warm", on)):
            row = {"cache": label, "repeat": repeat} | timed_demo(env, scratch / "run")
            if label == "warm":
                row["cache_mb"] = sum(p.stat().st_size for p in cache.rglob("*")
                                      if p.is_file()) / 2**20
            rows.append(row)
            print(f"{label:>5} #{repeat}: {row['wall_s']:5.2f} s wall, {row['compile_s']:5.2f} "
                  f"s compiling, peak {row['peak_mb']:.0f} MB", flush=True)
    shutil.rmtree(scratch)
    summary = {label: {"median_wall_s": float(np.median([r["wall_s"] for r in rows
                                                         if r["cache"] == label])),
                       "median_compile_s": float(np.median([r["compile_s"] for r in rows
                                                            if r["cache"] == label]))}
               for label in ("off", "cold", "warm")}
    print("\n| cache | wall s (median) | compiling s (median) |\n| --- | --- | --- |")
    for label, s in summary.items():
        print(f"| {label} | {s['median_wall_s']:.2f} | {s['median_compile_s']:.2f} |")
    if args.json:
        Path(args.json).write_text(json.dumps(
            {**provenance(), "load_average_after": os.getloadavg(),
             "runs_of": "gpjax demo (paper protocol, P = 500, eps = 0.01), one process each",
             "summary": summary, "runs": rows}, indent=1) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
