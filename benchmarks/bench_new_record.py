"""What a new record costs: whole-process ``gpjax fit`` on several different 1-DOF records of
one length bucket, one after another with one cache folder (fresh at the start), at this
tree and at a baseline revision in the same run.

The first record compiles (cold); every later one is a *different* record, so before the
record became a program argument (gpjax._record) it compiled again. Each row gives the
whole process's seconds and the seconds its summary counts as compiling or loading.

    python benchmarks/bench_new_record.py --baseline 2596765 --timeout 1200 \
        --json benchmarks/new_record.json

``--host-devices K`` compares this tree at one host device with this tree split over K
(``XLA_FLAGS=--xla_force_host_platform_device_count=K``) instead.

A row of a fit stopped by ``--timeout`` shows the timeout with a "+".
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _provenance import provenance  # noqa: E402
from _baseline import ROOT, baseline_tree, in_tree  # noqa: E402

from gpjax._config import WIDE_FUNCTIONS  # noqa: E402

WIDE = ",".join(WIDE_FUNCTIONS)
#: (system, duration in s): issue 43's four records, 100 Hz, 7,601–7,991 samples, one
#: length bucket (7,169–8,192); Coulomb + viscous exercises the sign-width loop.
RECORDS = (("duffing", 79.9), ("pendulum", 78.0), ("quadratic_drag", 77.0),
           ("coulomb_viscous", 76.0))
#: The run summary's whole seconds and compile seconds, in the older and the newer wording.
SUMMARIES = (re.compile(r"([\d.]+) s in all, ([\d.]+) s of it compiling or loading (\d+)"),
             re.compile(r"([\d.]+) s in all: .*Of these, ([\d.]+) s compiling or loading (\d+)"))
#: The summary's stages (seconds), where it names them.
STAGES = {"search_s": re.compile(r"search \([^)]*\) ([\d.]+) s"),
          "selection_s": re.compile(r"final model selection ([\d.]+) s"),
          "convergence_s": re.compile(r"convergence check ([\d.]+) s"),
          "intervals_s": re.compile(r"standard errors and residuals ([\d.]+) s")}
#: The reported row of the printed Pareto table (marked ``*``): its equation.
REPORTED = re.compile(r"^\*\s+\d+\s+\S+\s+(Eq\(.*\))\s*$", re.MULTILINE)
NUMBER = re.compile(r"(?<![\w.])-?\d+\.\d+(e-?\d+)?")


def _structure(stdout: str) -> str | None:
    """The reported equation with its numbers replaced by ``c``: the structure, whatever the
    names the constants get (``k1``, ``k2`` follow the terms' order in the record)."""
    found = REPORTED.search(stdout)
    return NUMBER.sub("c", found[1]) if found else None


def _write_records(folder: Path, count: int) -> list[Path]:
    from gpjax.systems import generate, get_system, write_csv

    paths = []
    for name, duration in RECORDS[:count]:
        system = dataclasses.replace(get_system(name), duration=duration)
        path = folder / f"{name}.csv"
        write_csv(generate(system, seed=0).fit, path)
        paths.append(path)
    return paths


def _fit_all(tree: Path, records: list[Path], cache: Path, args,
             devices: int | None = None) -> list[dict]:
    """Fit ``records`` one after another in child processes on the code at ``tree``, with
    ``devices`` host devices (``None``: the tree's default)."""
    rows = []
    flags = ({} if devices is None else
             {"XLA_FLAGS": f"--xla_force_host_platform_device_count={devices}"})
    child = in_tree(tree, JAX_PLATFORMS="cpu", GPJAX_COMPILATION_CACHE="on",
                    GPJAX_CACHE_DIR=str(cache), **flags)
    for path in records:
        began = time.perf_counter()
        try:
            run = subprocess.run(
                [sys.executable, "-m", "gpjax", "fit", str(path), "--time", "t", "--response",
                 "x", "--input", "u", "--functions", WIDE, "--population",
                 str(args.population), "--generations", str(args.generations), "--out",
                 str(cache.parent / f"{cache.name}-{path.stem}")],
                capture_output=True, text=True, timeout=args.timeout, **child)
        except subprocess.TimeoutExpired:
            rows.append({"record": path.stem, "exit": "timeout", "whole_s": args.timeout,
                         "fit_s": None, "compile_s": None, "programs": None,
                         "equation": f"did not finish in {args.timeout:.0f} s"})
            continue
        whole = time.perf_counter() - began
        found = next((m for m in (p.search(run.stdout) for p in SUMMARIES) if m), None)
        equation = run.stdout.splitlines()[0] if run.stdout else run.stderr[-300:]
        stages = {name: (float(m[1]) if (m := pattern.search(run.stdout)) else None)
                  for name, pattern in STAGES.items()}
        rows.append({"record": path.stem, "exit": run.returncode, "whole_s": whole,
                     "fit_s": float(found[1]) if found else None,
                     "compile_s": float(found[2]) if found else None,
                     "programs": int(found[3]) if found else None, "equation": equation,
                     "structure": _structure(run.stdout)}
                    | stages)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--records", type=int, default=len(RECORDS))
    parser.add_argument("--population", type=int, default=500)
    parser.add_argument("--generations", type=int, default=10)
    parser.add_argument("--baseline", help="git revision to compare against in the same run")
    parser.add_argument("--host-devices", type=int, metavar="K",
                        help="instead of a baseline revision: this tree at one host device "
                             "against this tree split over K (XLA_FLAGS)")
    parser.add_argument("--json", help="write the results here")
    parser.add_argument("--timeout", type=float, default=None,
                        help="seconds after which a fit is stopped and its row marked")
    args = parser.parse_args()
    scratch = Path(tempfile.mkdtemp(prefix="gpjax-bench-record-"))
    records = _write_records(scratch, args.records)
    if args.baseline and args.host_devices:
        parser.error("--baseline and --host-devices are two kinds of comparison: give one")
    runs = ({"1 host device": (ROOT, 1), f"{args.host_devices} host devices":
             (ROOT, args.host_devices)} if args.host_devices else {"this tree": (ROOT, None)})
    results = {}
    with (baseline_tree(args.baseline) if args.baseline else contextlib.nullcontext()) as base:
        if base is not None:
            runs = {args.baseline: (base, None), **runs}
        for label, (tree, devices) in runs.items():
            results[label] = _fit_all(tree, records, scratch / f"cache-{len(results)}", args,
                                      devices)
    print(f"{'record':24s}" + "".join(f"{label:>32s}" for label in results)
          + ("   ratio" if len(results) == 2 else ""))
    for i, path in enumerate(records):
        cells = "".join(f"{r[i]['whole_s']:>10.1f} s{'+' if r[i]['exit'] == 'timeout' else ' '}"
                        f"({r[i]['compile_s'] or 0:5.1f} s compiling)" for r in results.values())
        if len(results) == 2:
            before, after = (r[i]["whole_s"] for r in results.values())
            cells += f"   {after / before:5.2f}"
        print(f"{path.stem:24s}{cells}")
    if args.json:
        Path(args.json).write_text(json.dumps({
            **provenance(), "population": args.population,
            "generations": args.generations, "functions": WIDE, "results": results},
            indent=1) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
