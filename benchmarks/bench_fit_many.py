"""``fit-many`` on generated records: gear records that differ in their noise (seed k) and
in the gear itself (K1 from 0.9× to 1.1× the paper's, K2 from 1.1× to 0.9×), one length
bucket, plus one broken file, fitted with the paper's protocol on a LocalCluster of 2
workers; with ``--sequential``, also the same records one after another in one process.
Compilation cache on, in a fresh folder for each (so both start cold). Each record's
summary row gives the seconds it spent compiling or loading programs: after each worker's
first record (cold), a different record of the bucket should compile nothing. Prints a
summary, writes JSON.

    python benchmarks/bench_fit_many.py --records 11 --json benchmarks/fit_many.json
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _provenance import provenance  # noqa: E402

SEQUENTIAL = """
import sys, time
from pathlib import Path
from gpjax import GPConfig, Identifier, load_csv, UserInputError
began = time.perf_counter()
for path in sorted(Path(sys.argv[1]).glob("*.csv")):
    try:
        m = load_csv(path, time="t", response="phi", inputs=["T"])
        Identifier(GPConfig.paper()).fit(m, seed=0, progress=False)
    except UserInputError:
        pass
print(time.perf_counter() - began)
"""


#: Seconds of compiling or loading above which a record counts as having compiled.
COMPILED_S = 1.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--records", type=int, default=20)
    parser.add_argument("--sequential", action="store_true",
                        help="also fit the records one after another in one process")
    parser.add_argument("--json", help="write the results here")
    args = parser.parse_args()
    from gpjax.gear import PAPER_TRUTH, generate_gear_example

    scratch = Path(tempfile.mkdtemp(prefix="gpjax-bench-many-"))
    records = scratch / "records"
    records.mkdir()
    good = args.records - 1
    for seed in range(good):
        shift = 0.1 * (2 * seed / max(1, good - 1) - 1)  # -0.1 ... 0.1
        truth = {"J": PAPER_TRUTH["J"], "K1": PAPER_TRUTH["K1"] * (1 + shift),
                 "K2": PAPER_TRUTH["K2"] * (1 - shift)}
        generate_gear_example(seed=seed, truth=truth).measurement.to_csv(
            records / f"gear{seed:02d}.csv")
    (records / "gear_broken.csv").write_text("t,phi,T\n0,nan,1\n")
    env = dict(os.environ, JAX_PLATFORMS="cpu", GPJAX_COMPILATION_CACHE="on")
    began = time.perf_counter()
    run = subprocess.run([sys.executable, "-m", "gpjax", "fit-many", str(records), "--time",
                          "t", "--response", "phi", "--input", "T", "--config",
                          str(_paper_toml(scratch)), "--out", str(scratch / "out"),
                          "--workers", "2"],
                         env=env | {"GPJAX_CACHE_DIR": str(scratch / "cache-many")},
                         capture_output=True, text=True)
    many_s = time.perf_counter() - began
    summary = (scratch / "out" / "summary.csv").read_text()
    sequential_s = None
    if args.sequential:
        sequential = subprocess.run([sys.executable, "-c", SEQUENTIAL, str(records)],
                                    env=env | {"GPJAX_CACHE_DIR": str(scratch / "cache-seq")},
                                    capture_output=True, text=True, check=True)
        sequential_s = float(sequential.stdout.split()[-1])
    import csv

    rows = list(csv.DictReader(summary.splitlines()))
    ok = [r for r in rows if not r["error"]]
    eq14 = sum("phi**2" in r["equation"] and "phi_ddot" in r["equation"] for r in ok)
    # A record compiles when its shapes and settings are new to the cache folder (the
    # first of each worker, and one whose convergence check settles on a step count no
    # earlier record used); otherwise it only loads executables.
    compiled = [r for r in ok if float(r["compile_s"]) >= COMPILED_S]
    loaded = [r for r in ok if float(r["compile_s"]) < COMPILED_S]
    result = {**provenance(), "cpus": os.cpu_count(),
              "load_average_after": os.getloadavg(),
              "records": len(rows), "ok": len(ok), "failed": len(rows) - len(ok),
              "exit_status": run.returncode, "eq14_structure": eq14,
              "fit_many_wall_s": many_s, "one_process_sequential_s": sequential_s,
              "median_record_s": sorted(float(r["seconds"]) for r in ok)[len(ok) // 2],
              "compiled_records": len(compiled), "loaded_records": len(loaded),
              "loaded_max_s": max((float(r["compile_s"]) for r in loaded), default=None),
              "loaded_max_share": max((float(r["compile_s"]) / float(r["seconds"])
                                       for r in loaded), default=None),
              "summary_csv": summary}
    print(f"{len(rows)} records ({len(ok)} ok, {len(rows) - len(ok)} failed, exit "
          f"{run.returncode}); eq. 14 structure in {eq14}")
    print(f"fit-many on 2 workers: {many_s:.1f} s in all (process, cluster start included)"
          + (f"; one process, one after another: {sequential_s:.1f} s (records only)"
             if sequential_s is not None else ""))
    if loaded:
        print(f"{len(compiled)} record(s) compiled; {len(loaded)} only loaded executables, "
              f"{result['loaded_max_s']:.2f} s ({result['loaded_max_share']:.1%} of the "
              "record) at most")
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")


def _paper_toml(folder: Path) -> Path:
    """The paper's settings (GPConfig.paper()) as a TOML file for the command line."""
    from gpjax import GPConfig

    values = GPConfig.paper().to_dict()
    lines = []
    for key, value in values.items():
        if isinstance(value, dict):
            inner = ", ".join(f"{k} = {json.dumps(v)}" for k, v in value.items())
            lines.append(f"{key} = {{ {inner} }}")
        else:
            lines.append(f"{key} = {json.dumps(value)}")
    path = folder / "paper.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


if __name__ == "__main__":
    main()
