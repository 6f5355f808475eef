"""Bad-input corpus: every user error is refused cleanly, before any GP work.

The command-line contract (see ``gpjax/cli.py``): a user error gives exit status 2, exactly
one line on stderr starting with ``gpjax: error:`` that names the problem and the fix, no
traceback, nothing on stdout, and no file or folder left behind (the ``--out`` folder must
not exist afterwards, no partial or temporary files in the working directory).

Every CLI case runs ``python -m gpjax`` as a real subprocess in its own fresh pytest
temporary directory (``JAX_PLATFORMS=cpu``). Importing gpjax costs a few seconds per
process, so the selected CLI cases are launched together, a few at a time, the first time
one of them is needed; each test then checks its own result. Cases whose data must be
valid use a tiny 50-row uniformly sampled CSV (columns t, x, u) and a small population,
so a case that slipped through validation would still end quickly.

Model-file cases go through the Python API (``gpjax.Model.load``), which must raise
:class:`gpjax.ModelFileError` with a one-line message.

The cases that first failed (keyword column names, a newline in a header cell, infinite
intervals, negative seeds, deep nesting, huge numbers and powers, misplaced features in a
model file, a minimum population refused by the default tournament size) were fixed in
the package; they stay here as regression cases.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import hashlib
import json
import math
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

# --------------------------------------------------------------------------------------
# Data helpers
# --------------------------------------------------------------------------------------

DT = 0.01
N_ROWS = 50
#: Marks a path that the case's setup creates as a directory instead of a file.
DIR = object()


def _times(n: int = N_ROWS) -> list[float]:
    return [i * DT for i in range(n)]


def csv_text(header: str = "t,x,u", *, n: int = N_ROWS, sep: str = ",",
             cells: dict[tuple[int, int], str] | None = None,
             times: list[float] | None = None, response: list[float] | None = None,
             header_row: bool = True) -> str:
    """A small CSV: time ``t`` (uniform, step DT), response ``x`` (a 3 Hz sine), input ``u``.

    ``cells`` overrides single cells by (data row index from 0, column index) with raw text.
    """
    times = _times(n) if times is None else times
    response = ([math.sin(2 * math.pi * 3 * t) + 0.2 * t for t in times]
                if response is None else response)
    rows = [[repr(t), repr(x), repr(math.cos(5 * t))] for t, x in zip(times, response)]
    for (i, j), text in (cells or {}).items():
        rows[i][j] = text
    lines = ([header] if header_row else []) + [sep.join(r) for r in rows]
    return "\n".join(lines) + "\n"


VALID_CSV = csv_text()


def with_extra_column(text: str, name: str, value: str) -> str:
    """``text`` with one more column ``name`` (every data cell ``value``)."""
    lines = text.rstrip("\n").split("\n")
    return "\n".join([f"{lines[0]},{name}", *(f"{line},{value}" for line in lines[1:])]) + "\n"


def truncate_row(text: str, row: int, keep: int) -> str:
    """``text`` with data row ``row`` (from 0) cut to its first ``keep`` cells."""
    lines = text.split("\n")
    lines[row + 1] = ",".join(lines[row + 1].split(",")[:keep])
    return "\n".join(lines)


def ragged_coordinates(length: int) -> str:
    """The valid CSV with a second coordinate ``x2`` (a 2 Hz sine) measured for its first
    ``length`` rows, then empty and NaN cells (a NaN-padded export)."""
    lines = VALID_CSV.rstrip("\n").split("\n")
    cells = [repr(math.sin(4 * math.pi * t)) if i < length else ("nan" if i % 2 else "")
             for i, t in enumerate(_times())]
    return "\n".join([f"{lines[0]},x2", *(f"{a},{b}" for a, b in zip(lines[1:], cells))]) + "\n"


def model_json(**canonical_changes) -> dict:
    """A valid hand-written model: phi'' + 4 phi = T, with optional changes to canonical."""
    canonical = {"mass": 1, "terms": [{"feature": "phi", "coefficient": 4}],
                 "forcing": [{"feature": "T", "coefficient": 1}]}
    canonical.update(canonical_changes)
    return {"variables": {"time": "t", "response": "phi", "inputs": ["T"]},
            "canonical": canonical}


TWO_RESPONSES = ("fit", "data.csv", "--time", "t", "--response", "x", "--response", "x2",
                 "--input", "u")


def toml_config(text: str) -> dict[str, object]:
    """Files for a config case: the valid CSV and ``cfg.toml`` holding ``text``."""
    return {"data.csv": VALID_CSV, "cfg.toml": text}


#: Fit on the valid data with a small, valid run size (population >= the default
#: tournament size of 7, see test_documented_minimum_population_is_usable).
FIT = ("fit", "data.csv", "--time", "t", "--response", "x", "--input", "u")
SMALL = ("--population", "8", "--generations", "1")
CONFIG_FIT = (*FIT, "--config", "cfg.toml", *SMALL, "--out", "run")


@dataclasses.dataclass(frozen=True)
class CliCase:
    """One command line run in a fresh folder holding ``files``.

    ``expect``: regular expressions (case-insensitive) that must all be found in the
    error line: the problem and the fix it names.
    """

    args: tuple[str, ...]
    files: dict = dataclasses.field(default_factory=dict)
    expect: tuple[str, ...] = ()


def case(case_id: str, args, files=None, expect=()):
    return pytest.param(CliCase(tuple(args), dict(files or {}), tuple(expect)), id=case_id)


def data_case(case_id: str, text, expect, *, args=FIT):
    """A case whose data file ``data.csv`` holds ``text`` (str or bytes)."""
    return case(case_id, (*args, *SMALL), {"data.csv": text}, expect)


def config_case(case_id: str, text: str, expect):
    return case(case_id, CONFIG_FIT, toml_config(text), expect)


# --------------------------------------------------------------------------------------
# The CLI corpus
# --------------------------------------------------------------------------------------

_T = _times()

CLI_CASES = [
    # --- the data file itself ---------------------------------------------------------
    case("missing-file", (*FIT, *SMALL), {}, ["data.csv", "does not exist", "check the path"]),
    case("directory-not-file", (*FIT, *SMALL), {"data.csv": DIR},
         ["data.csv", "directory", "give a CSV file"]),
    data_case("empty-file", "", ["empty", "header row"]),
    data_case("header-only", "t,x,u\n", ["0 data rows", "at least 20"]),
    data_case("no-header-row", csv_text(header_row=False), ["not found", "no header row"]),
    data_case("decimal-comma", csv_text("t;x;u", sep=";", cells={(3, 1): "0,25"}),
              ["line 5", "'0,25' is not a number", "decimal comma"]),
    data_case("not-utf8", b"\xff\xfe\x00t,x,u\n" + VALID_CSV.encode()[6:],
              ["cannot read", "data.csv"]),
    # --- columns --------------------------------------------------------------------------
    case("missing-response-column", ("fit", "data.csv", "--time", "t", "--response", "y",
                                     "--input", "u", *SMALL),
         {"data.csv": VALID_CSV}, ["'y' not found", "columns are: 't', 'x', 'u'"]),
    case("missing-time-column", ("fit", "data.csv", "--time", "time", "--response", "x",
                                 *SMALL),
         {"data.csv": VALID_CSV}, ["'time' not found", "columns are"]),
    case("missing-input-column", (*FIT, "--input", "v", *SMALL),
         {"data.csv": VALID_CSV}, ["'v' not found", "columns are"]),
    data_case("duplicate-column-in-header",
              with_extra_column(csv_text(), "x", "0.5"),
              ["'x' appears 2 times", "rename"]),
    case("same-column-twice", ("fit", "data.csv", "--time", "t", "--response", "t", *SMALL),
         {"data.csv": VALID_CSV}, ["named twice", "name each column once"]),
    case("input-is-the-response", ("fit", "data.csv", "--time", "t", "--response", "x",
                                   "--input", "x", *SMALL),
         {"data.csv": VALID_CSV}, ["named twice", "name each column once"]),
    # --- several responses (the coordinates of one system) ------------------------------
    case("response-named-twice", ("fit", "data.csv", "--time", "t", "--response", "x",
                                  "--response", "x", "--input", "u", *SMALL),
         {"data.csv": VALID_CSV}, ["response 'x' is named twice", "name each column once"]),
    case("response-is-also-an-input", ("fit", "data.csv", "--time", "t", "--response", "x",
                                       "--response", "u", "--input", "u", *SMALL),
         {"data.csv": VALID_CSV}, ["'u' is named twice, as a response and as an input"]),
    data_case("coordinates-of-different-lengths", ragged_coordinates(30),
              ["'x2'", "30 samples but 't' has 50", "empty or NaN after line 31",
               "same length"], args=TWO_RESPONSES),
    case("several-responses-resume-without-checkpoint",
         (*TWO_RESPONSES, *SMALL, "--out", "run", "--resume"),
         {"data.csv": ragged_coordinates(N_ROWS), "run": DIR},
         ["no checkpoint", "without --resume"]),
    case("diagnose-one-coordinate-model-takes-one-response",
         ("diagnose", "data.csv", "--model", "model.json", "--time", "t", "--response", "x",
          "--response", "x2", "--out", "d"),
         {"data.csv": VALID_CSV, "model.json": json.dumps(model_json())},
         ["diagnose takes one --response", "give one"]),
    case("system-diagnosis-with-frequency", (*TWO_RESPONSES, "--diagnose", "--frequency", "3"),
         {"data.csv": ragged_coordinates(N_ROWS)}, ["--frequency", "drop it"]),
    data_case("column-name-with-space", csv_text("t,my col,u"),
              ["'my col'", "not usable", "rename"],
              args=("fit", "data.csv", "--time", "t", "--response", "my col", "--input", "u")),
    data_case("column-name-starts-with-digit", csv_text("t,1x,u"),
              ["'1x'", "not usable", "rename"],
              args=("fit", "data.csv", "--time", "t", "--response", "1x", "--input", "u")),
    data_case("column-named-x_dot", csv_text("t,x,x_dot"), ["_dot", "rename"],
              args=("fit", "data.csv", "--time", "t", "--response", "x", "--input", "x_dot")),
    case("column-name-python-keyword",
         ("fit", "data.csv", "--time", "t", "--response", "lambda", "--input", "u", *SMALL,
          "--out", "occupied"),
         {"data.csv": csv_text("t,lambda,u"), "occupied": "keep me\n"},
         ["'lambda'", "rename"]),
    data_case("header-cell-with-newline", 't,"x\nx",u\n' + VALID_CSV.split("\n", 1)[1],
              ["'y' not found", "columns are"],
              args=("fit", "data.csv", "--time", "t", "--response", "y", "--input", "u")),
    # --- cells ----------------------------------------------------------------------------
    data_case("text-in-numeric-cell", csv_text(cells={(12, 1): "abc"}),
              ["line 14", "'abc' is not a number", "fix or remove"]),
    data_case("empty-cell", csv_text(cells={(12, 1): ""}),
              ["line 14", "'' is not a number", "fix or remove"]),
    data_case("short-row", truncate_row(csv_text(), 30, 1), ["line 32", "'' is not a number"]),
    data_case("nan-cell", csv_text(cells={(7, 1): "nan"}), ["line 9", "NaN/inf"]),
    data_case("nan-cell-after-comments", "# rig 3\n# units: s, m, N\n\n"
              + csv_text(cells={(7, 1): "nan"}), ["line 12", "NaN/inf"]),
    data_case("inf-cell", csv_text(cells={(7, 2): "inf"}), ["line 9", "'u'", "NaN/inf"]),
    data_case("minus-infinity-in-time", csv_text(cells={(0, 0): "-Infinity"}),
              ["line 2", "'t'", "NaN/inf"]),
    data_case("absurd-magnitude", csv_text(cells={(5, 1): "1e300"}),
              ["'x'", "1e\\+300", "rescale"]),
    # --- rows and the time axis -----------------------------------------------------------
    data_case("one-row", csv_text(n=1), ["1 data rows", "at least 20"]),
    data_case("ten-rows", csv_text(n=10), ["10 data rows", "at least 20"]),
    data_case("non-monotonic-time", csv_text(cells={(10, 0): repr(_T[11]), (11, 0): repr(_T[10])}),
              ["not strictly increasing", "row 12", "sort the rows"]),
    data_case("duplicate-time", csv_text(cells={(11, 0): repr(_T[10])}),
              ["not strictly increasing", "drop duplicate times"]),
    data_case("non-uniform-sampling", csv_text(times=[i * DT + 0.004 * (i % 2)
                                                      for i in range(N_ROWS)]),
              ["not uniformly sampled", "resample"]),
    data_case("constant-response", csv_text(response=[1.5] * N_ROWS),
              ["'x'", "constant", "no dynamics"]),
    # --- configuration file ---------------------------------------------------------------
    case("config-missing", CONFIG_FIT, {"data.csv": VALID_CSV},
         ["cfg.toml", "does not exist", "check the path"]),
    case("config-is-a-directory", CONFIG_FIT, {"data.csv": VALID_CSV, "cfg.toml": DIR},
         ["config file cfg.toml is a directory", "give a file"]),
    config_case("config-not-toml", "population: 500\n{oops", ["not valid TOML", "fix the syntax"]),
    config_case("config-unknown-key", "popsize = 100\n", ["unknown key 'popsize'", "valid keys"]),
    config_case("config-wrong-type", 'population = "many"\n',
                ["population must be an integer", "'many'"]),
    config_case("config-boolean-for-number", "generations = true\n",
                ["generations must be an integer", "True"]),
    config_case("config-unknown-input-forcing", 'input_forcing = "cubic"\n',
                ["input_forcing must be one of linear, any", "'cubic'"]),
    config_case("config-negative-population", "population = -3\n",
                ["population must be at least 4", "-3"]),
    config_case("config-probabilities-not-summing-to-1",
                "p_crossover = 0.5\np_mutation = 0.2\np_perturbation = 0.1\n"
                "p_reproduction = 0.1\n", ["sum to 1", "0.9", "adjust p_crossover"]),
    config_case("config-reversed-interval-constant",
                "interval_constants = { k1 = [[20.0, 0.1]] }\n", ["k1", "lo < hi"]),
    config_case("config-malformed-interval-constant",
                "interval_constants = { k1 = [[0.1, 20.0], [800.0]] }\n",
                ["interval_constants.k1", "\\[lo, hi\\] pairs"]),
    config_case("config-reversed-real-interval", "real_interval = [10.0, -10.0]\n",
                ["real_interval", "lo < hi"]),
    config_case("config-infinite-real-interval", "real_interval = [-inf, inf]\n",
                ["real_interval", "finite"]),
    config_case("config-nan-epsilon", "epsilon = nan\n", ["epsilon", "finite"]),
    config_case("config-unknown-function", 'functions = ["add", "gamma"]\n',
                ["unknown function 'gamma'", "choose from"]),
    config_case("config-unknown-variable", 'variables = ["x", "x_ddot", "y"]\n',
                ["unknown variable 'y'", "choose from"]),
    config_case("config-variables-without-x_ddot", 'variables = ["x", "x_dot", "u"]\n',
                ["must contain x_ddot"]),
    config_case("config-named-constant-reserved", "named_constants = { x = 2.0 }\n",
                ["named constant 'x'", "identifier other than"]),
    config_case("config-n_bins-zero", "n_bins = 0\n", ["n_bins must be at least 1"]),
    config_case("config-coefficients-magic", 'coefficients = "magic"\n',
                ["coefficients must be one of", "least_squares", "'magic'"]),
    config_case("config-substeps-zero", "substeps = 0\n", ["substeps must be \"auto\" or an integer between 1 and 64"]),
    config_case("config-input-interpolation-unknown", 'input_interpolation = "cubic"\n',
                ["input_interpolation must be one of", "bandlimited", "hold", "'cubic'"]),
    config_case("config-init-depth-beyond-max-depth", "max_depth = 3\ninit_depth = [2, 5]\n",
                ["init_depth", "max_depth"]),
    # --- command-line arguments -----------------------------------------------------------
    case("functions-unknown", (*FIT, *SMALL, "--functions", "add,sub,gamma"),
         {"data.csv": VALID_CSV}, ["unknown function 'gamma'", "choose from"]),
    case("input-forcing-unknown", (*FIT, *SMALL, "--input-forcing", "quadratic"),
         {"data.csv": VALID_CSV}, ["--input-forcing", "invalid choice: 'quadratic'"]),
    case("functions-empty", (*FIT, *SMALL, "--functions", " , "),
         {"data.csv": VALID_CSV}, ["--functions", "comma-separated names"]),
    case("functions-without-add-or-sub", (*FIT, *SMALL, "--functions", "mul,sin"),
         {"data.csv": VALID_CSV}, ["functions must contain add or sub"]),
    case("population-negative", (*FIT, "--population", "-5", "--generations", "1"),
         {"data.csv": VALID_CSV}, ["population must be at least 4", "-5"]),
    case("population-not-an-integer", (*FIT, "--population", "many"),
         {"data.csv": VALID_CSV}, ["--population", "invalid int value", "gpjax fit --help"]),
    case("generations-zero", (*FIT, "--population", "8", "--generations", "0"),
         {"data.csv": VALID_CSV}, ["generations must be at least 1", "got 0"]),
    case("seed-negative", (*FIT, *SMALL, "--seed", "-1", "--out", "run"),
         {"data.csv": VALID_CSV}, ["seed"]),
    case("unknown-flag", (*FIT, *SMALL, "--frobnicate"), {"data.csv": VALID_CSV},
         ["unrecognized arguments: --frobnicate", "--help"]),
    case("input-interpolation-unknown", (*FIT, *SMALL, "--input-interpolation", "sinc"),
         {"data.csv": VALID_CSV}, ["--input-interpolation", "invalid choice", "hold", "'sinc'"]),
    case("missing-time-flag", ("fit", "data.csv", "--response", "x", *SMALL),
         {"data.csv": VALID_CSV}, ["required: --time", "gpjax fit --help"]),
    case("no-subcommand", (), {}, ["required", "gpjax --help"]),
    case("out-is-an-existing-file", (*FIT, *SMALL, "--out", "results"),
         {"data.csv": VALID_CSV, "results": "not a folder\n"}, ["--out results", "is a file",
                                                                "give a folder"]),
    case("resume-without-checkpoint", (*FIT, *SMALL, "--out", "run", "--resume"),
         {"data.csv": VALID_CSV, "run": DIR}, ["no checkpoint", "without --resume"]),
    case("resume-damaged-checkpoint", (*FIT, *SMALL, "--out", "run", "--resume"),
         {"data.csv": VALID_CSV, "run": DIR, "run/checkpoint.json": "{not json"},
         ["checkpoint.json", "damaged", "without --resume"]),
    case("resume-checkpoint-of-other-data", (*FIT, *SMALL, "--out", "run", "--resume"),
         {"data.csv": VALID_CSV, "run": DIR,
          "run/checkpoint.json": json.dumps({"data": "0" * 64, "config": {}, "seed": 0,
                                             "state": {}})},
         ["other data", "same CSV"]),
    case("demo-population-zero", ("demo", "--population", "0", "--out", "demo"), {},
         ["population must be at least 4"]),
    # --- islands and many records ---------------------------------------------------------
    case("islands-zero", (*FIT, *SMALL, "--islands", "0", "--out", "run"),
         {"data.csv": VALID_CSV}, ["islands must be a positive integer", "got 0"]),
    case("islands-too-many-for-population", (*FIT, *SMALL, "--islands", "3", "--out", "run"),
         {"data.csv": VALID_CSV}, ["population 8 is too small for 3 islands", "fewer islands"]),
    case("migrate-every-zero", (*FIT, *SMALL, "--islands", "2", "--migrate-every", "0"),
         {"data.csv": VALID_CSV}, ["every must be at least 1"]),
    case("scheduler-malformed", (*FIT, *SMALL, "--islands", "2", "--scheduler", "localhost"),
         {"data.csv": VALID_CSV}, ["'localhost'", "PROTOCOL://HOST:PORT", "tcp://"]),
    case("scheduler-unreachable", (*FIT, *SMALL, "--islands", "2", "--scheduler",
                                   "tcp://127.0.0.1:9", "--out", "run"),
         {"data.csv": VALID_CSV}, ["cannot reach the Dask scheduler", "dask scheduler",
                                   "leave out --scheduler"]),
    case("scheduler-without-islands", (*FIT, *SMALL, "--scheduler", "tcp://127.0.0.1:9"),
         {"data.csv": VALID_CSV}, ["need islands", "--islands K"]),
    case("resume-island-checkpoint-without-islands", (*FIT, *SMALL, "--out", "run", "--resume"),
         {"data.csv": VALID_CSV, "run": DIR,
          "run/checkpoint.json": json.dumps({"islands": [{}, {}], "data": "0" * 64})},
         ["island run", "--islands 2"]),
    case("resume-one-process-checkpoint-with-islands",
         (*FIT, *SMALL, "--islands", "2", "--out", "run", "--resume"),
         {"data.csv": VALID_CSV, "run": DIR,
          "run/checkpoint.json": json.dumps({"data": "0" * 64, "config": {}, "seed": 0,
                                             "state": {}})},
         ["one-process run", "without --islands"]),
    case("fit-many-empty-folder", ("fit-many", "records", "--time", "t", "--response", "x",
                                   "--out", "many"),
         {"records": DIR}, ["no CSV files in records", "glob"]),
    case("fit-many-glob-matches-nothing", ("fit-many", "records/*.csv", "--time", "t",
                                           "--response", "x", "--out", "many"),
         {"data.csv": VALID_CSV}, ["no CSV files in records/\\*.csv"]),
    case("fit-many-same-record-name-twice", ("fit-many", "*/data.csv", "--time", "t",
                                             "--response", "x", "--out", "many"),
         {"a/data.csv": VALID_CSV, "b/data.csv": VALID_CSV}, ["'data'", "own name"]),
    case("fit-many-out-is-a-file", ("fit-many", ".", "--time", "t", "--response", "x",
                                    "--out", "taken"),
         {"data.csv": VALID_CSV, "taken": "occupied\n"}, ["--out taken", "is a file"]),
    case("fit-many-workers-zero", ("fit-many", ".", "--time", "t", "--response", "x",
                                   "--workers", "0", "--out", "many"),
         {"data.csv": VALID_CSV}, ["workers must be a positive integer", "got 0"]),
    case("demo-out-is-an-existing-file", ("demo", "--population", "8", "--generations", "1",
                                          "--out", "taken"),
         {"taken": "occupied\n"}, ["--out taken", "is a file", "give a folder"]),
]


# --------------------------------------------------------------------------------------
# Running the CLI cases
# --------------------------------------------------------------------------------------

@dataclasses.dataclass
class CliRun:
    cwd: Path
    returncode: int
    stdout: str
    stderr: str
    before: dict[str, str]
    after: dict[str, str]
    seconds: float


def _setup(folder: Path, files: dict) -> None:
    for name, content in files.items():
        path = folder / name
        if content is DIR:
            path.mkdir(parents=True, exist_ok=True)
            continue
        path.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(content, bytes):
            path.write_bytes(content)
        else:
            with open(path, "w", encoding="utf-8", newline="") as handle:
                handle.write(content)


def _snapshot(folder: Path) -> dict[str, str]:
    """Every path under ``folder`` (hidden ones included) -> "dir" or a content hash."""
    out = {}
    for path in sorted(folder.rglob("*")):
        rel = path.relative_to(folder).as_posix()
        if path.is_symlink():
            out[rel] = f"link:{os.readlink(path)}"
        elif path.is_dir():
            out[rel] = "dir"
        else:
            out[rel] = hashlib.sha256(path.read_bytes()).hexdigest()
    return out


#: A case still running after this long has got far past validation.
CLI_TIMEOUT_S = 180


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["JAX_PLATFORMS"] = "cpu"
    # This checkout's gpjax (the installed one may be another worktree's), nothing else.
    env["PYTHONPATH"] = str(Path(__file__).resolve().parents[1])
    return env


def _run_case(folder: Path, cli: CliCase) -> CliRun:
    before = _snapshot(folder)
    began = time.perf_counter()
    try:
        proc = subprocess.run([sys.executable, "-m", "gpjax", *cli.args], cwd=folder,
                              env=_env(), capture_output=True, text=True, timeout=CLI_TIMEOUT_S)
        returncode, stdout, stderr = proc.returncode, proc.stdout, proc.stderr
    except subprocess.TimeoutExpired as err:  # still running GP long after validation
        returncode = -1
        stdout = err.stdout.decode(errors="replace") if isinstance(err.stdout, bytes) else (
            err.stdout or "")
        stderr = f"<killed after {CLI_TIMEOUT_S} s> " + (
            err.stderr.decode(errors="replace") if isinstance(err.stderr, bytes) else (
                err.stderr or ""))
    seconds = time.perf_counter() - began
    return CliRun(folder, returncode, stdout, stderr, before, _snapshot(folder), seconds)


class _CliBatch:
    """Runs the selected CLI cases concurrently on first use (import time dominates)."""

    def __init__(self, tmp_path_factory, selected: dict[str, CliCase]):
        self._factory = tmp_path_factory
        self._selected = selected
        self._results: dict[str, CliRun] = {}

    def _folder(self, case_id: str, cli: CliCase) -> Path:
        folder = self._factory.mktemp(re.sub(r"\W", "_", case_id)[:40], numbered=True)
        _setup(folder, cli.files)
        return folder

    def get(self, case_id: str, cli: CliCase) -> CliRun:
        if not self._results and self._selected:
            pending = {cid: (self._folder(cid, c), c) for cid, c in self._selected.items()}
            workers = max(2, min(8, os.cpu_count() or 2))
            with concurrent.futures.ThreadPoolExecutor(max_workers=workers) as pool:
                futures = {cid: pool.submit(_run_case, folder, c)
                           for cid, (folder, c) in pending.items()}
                self._results = {cid: f.result() for cid, f in futures.items()}
        if case_id not in self._results:  # not part of the batch: run it alone
            self._results[case_id] = _run_case(self._folder(case_id, cli), cli)
        return self._results[case_id]


@pytest.fixture(scope="module")
def cli_batch(request, tmp_path_factory) -> _CliBatch:
    selected = {}
    for item in request.session.items:
        callspec = getattr(item, "callspec", None)
        if (callspec is not None and "cli" in callspec.params
                and getattr(item, "module", None) is request.module):
            selected[callspec.id] = callspec.params["cli"]
    return _CliBatch(tmp_path_factory, selected)


def test_corpus_is_large_enough():
    assert len(CLI_CASES) + len(MODEL_CASES) >= 35
    ids = [p.id for p in CLI_CASES] + [p.id for p in MODEL_CASES]
    assert len(ids) == len(set(ids))


# Each case is a fresh ``python -m gpjax`` (~1 s of imports): every other case runs in the
# fast tier, the whole corpus in the slow step, so the fast tier stays within 5 minutes.
@pytest.mark.parametrize("cli", [
    pytest.param(*p.values, id=p.id, marks=(*p.marks, pytest.mark.slow) if i % 2 else p.marks)
    for i, p in enumerate(CLI_CASES)])
def test_cli_user_error(cli: CliCase, cli_batch: _CliBatch, request):
    run = cli_batch.get(request.node.callspec.id, cli)
    report = (f"gpjax {' '.join(cli.args)}\nexit {run.returncode}\n"
              f"stdout: {run.stdout!r}\nstderr: {run.stderr!r}")
    assert "Traceback" not in run.stderr, report
    assert run.returncode == 2, report
    assert run.stdout == "", report
    assert run.stderr.endswith("\n") and run.stderr.count("\n") == 1, \
        "stderr must be exactly one line\n" + report
    line = run.stderr.rstrip("\n")
    assert "\r" not in line, report
    assert line.startswith("gpjax: error: "), report
    message = line[len("gpjax: error: "):]
    for pattern in cli.expect:
        assert re.search(pattern, message, flags=re.IGNORECASE), \
            f"error message does not match {pattern!r}\n{report}"
    # Nothing written, nothing removed, nothing changed; in particular no --out folder.
    assert run.after == run.before, report
    args = list(cli.args)
    out = args[args.index("--out") + 1] if "--out" in args else (
        "gpjax-run" if args[:1] == ["fit"] else "gpjax-demo")
    if out not in run.before:
        assert not (run.cwd / out).exists(), report


#: Runs the command line in-process, then names the heavy libraries it loaded.
_LOADED_PROBE = ("import sys\nfrom gpjax.cli import main\nstatus = main(sys.argv[1:])\n"
                 "print(sorted(m for m in ('jax', 'sympy', 'diffrax', 'scipy', 'distributed')"
                 " if m in sys.modules))\nsys.exit(status)\n")


@pytest.mark.parametrize("case_id", [
    "demo-population-zero", "demo-out-is-an-existing-file", "out-is-an-existing-file",
    "response-named-twice", "coordinates-of-different-lengths", "islands-zero",
    "migrate-every-zero", "scheduler-malformed", "scheduler-without-islands",
    "fit-many-empty-folder", "fit-many-workers-zero", "config-unknown-function",
    "functions-unknown", "input-forcing-unknown"])
def test_a_user_error_is_reported_before_jax_loads(case_id, tmp_path):
    # One line at once (JAX, sympy, diffrax and Dask take seconds to import): every
    # command checks its settings, --out and data before it loads the engine.
    cli = next(p.values[0] for p in CLI_CASES if p.id == case_id)
    _setup(tmp_path, cli.files)
    done = subprocess.run([sys.executable, "-c", _LOADED_PROBE, *cli.args], cwd=tmp_path,
                          env=_env(), capture_output=True, text=True, timeout=CLI_TIMEOUT_S)
    assert done.returncode == 2, done.stderr
    assert done.stdout == "[]\n", f"loaded {done.stdout.strip()} before the error {done.stderr}"


# --------------------------------------------------------------------------------------
# Model files through the Python API
# --------------------------------------------------------------------------------------

def with_feature(text: str) -> dict:
    return model_json(terms=[{"feature": "phi", "coefficient": 4},
                             {"feature": text, "coefficient": 1}])


def mcase(case_id: str, content, expect=()):
    """``content``: JSON-able data, or raw text (str) written as is."""
    raw = content if isinstance(content, str) else json.dumps(content)
    return pytest.param(raw, tuple(expect), id=case_id)


MODEL_CASES = [
    mcase("malformed-json", '{"variables": {"time": "t", ', ["not valid JSON", "fix the syntax"]),
    mcase("empty-json-file", "", ["not valid JSON"]),
    mcase("top-level-list", [model_json()], ["top level must be a JSON object"]),
    mcase("top-level-string", '"phi_ddot + 4*phi = T"', ["top level must be a JSON object"]),
    mcase("missing-variables", {"canonical": model_json()["canonical"]}, ['"variables"']),
    mcase("variables-not-names", dict(model_json(), variables={"time": "t", "response": 3}),
          ['"response"']),
    mcase("missing-canonical", {"variables": model_json()["variables"]}, ['"canonical"']),
    mcase("unknown-function-system", with_feature("system(1)"),
          ["function 'system' is not allowed"]),
    mcase("attribute-access", with_feature("phi.__class__"), ["Attribute is not allowed"]),
    mcase("lambda", with_feature("lambda: phi"), ["Lambda is not allowed"]),
    mcase("subscript", with_feature("phi[0]"), ["Subscript is not allowed"]),
    mcase("string-constant", with_feature("'abc'"), ["not allowed"]),
    mcase("unknown-name", with_feature("theta"), ["unknown name 'theta'"]),
    mcase("eq-inside-feature", with_feature("Eq(phi, 1)"), ["function 'Eq' is not allowed"]),
    mcase("symbolic-exponent", with_feature("phi**phi"), ["exponent must be a number"]),
    mcase("syntax-error", with_feature("phi +"), ["cannot parse expression"]),
    mcase("null-byte", with_feature("phi\x00"), ["cannot parse expression"]),
    mcase("cross-term-phi-times-phi_dot", with_feature("phi*phi_dot"),
          ["must depend on phi alone or on phi_dot alone"]),
    mcase("no-inertia-term", model_json(mass=0), ["breaks the structure rules", "phi_ddot"]),
    mcase("coefficient-not-a-number",
          model_json(terms=[{"feature": "phi", "coefficient": "4"}]), ["must be a finite number"]),
    mcase("coefficient-nan", json.dumps(model_json()).replace('"coefficient": 4',
                                                             '"coefficient": NaN'),
          ["must be a finite number"]),
    mcase("mass-infinity", json.dumps(model_json()).replace('"mass": 1', '"mass": Infinity'),
          ["canonical.mass must be a finite number"]),
    mcase("duplicate-feature", model_json(terms=[{"feature": "phi", "coefficient": 4},
                                                 {"feature": "phi", "coefficient": 2}]),
          ["feature 'phi' twice"]),
    mcase("terms-not-a-list", model_json(terms={"phi": 4}), ["must be a list"]),
    mcase("expression-too-long", with_feature("+".join(["phi"] * 4000)), ["longer than"]),
    mcase("expression-nested-too-deeply", with_feature("-" * 300 + "phi"),
          ["nested too deeply"]),
    mcase("expression-nested-5000-deep", with_feature("-" * 5000 + "phi"),
          ["nested too deeply"]),
    mcase("integer-with-5000-digits",
          json.dumps(model_json()).replace('"coefficient": 4', '"coefficient": ' + "9" * 5000),
          ["number"]),
    mcase("state-variable-in-forcing", model_json(forcing=[{"feature": "phi",
                                                            "coefficient": 1}]),
          ["forcing"]),
    mcase("constant-in-state-terms", with_feature("1"), ["terms"]),
    mcase("acceleration-in-state-terms", with_feature("phi_ddot"), ["terms"]),
    mcase("simulation-interpolation-unknown", dict(model_json(), simulation={
        "input_interpolation": "spline"}), ['"simulation"', "bandlimited", "hold", "spline"]),
    mcase("simulation-not-an-object", dict(model_json(), simulation="bandlimited"),
          ['"simulation" must be']),
    mcase("input-named-like-a-derivative",
          dict(model_json(forcing=[]), variables={"time": "t", "response": "phi",
                                                   "inputs": ["phi_dot"]}),
          ["phi_dot"]),
]


def _load(tmp_path: Path, raw: str):
    import gpjax

    path = tmp_path / "model.json"
    path.write_text(raw, encoding="utf-8")
    return gpjax.Model.load(path)


@pytest.mark.parametrize("raw, expect", MODEL_CASES)
def test_model_file_error(raw, expect, tmp_path, monkeypatch):
    import gpjax

    monkeypatch.chdir(tmp_path)
    with pytest.raises(gpjax.ModelFileError) as info:
        _load(tmp_path, raw)
    message = str(info.value)
    assert message and "\n" not in message and "\r" not in message, repr(message)
    for pattern in expect:
        assert re.search(pattern, message, flags=re.IGNORECASE), (pattern, message)


def test_model_file_missing(tmp_path):
    import gpjax

    with pytest.raises(gpjax.ModelFileError) as info:
        gpjax.Model.load(tmp_path / "absent.json")
    assert "does not exist" in str(info.value) and "\n" not in str(info.value)


def test_model_file_injection_is_not_run(tmp_path, monkeypatch):
    import gpjax

    monkeypatch.chdir(tmp_path)
    data = with_feature("__import__('os').system('touch pwned')")
    with pytest.raises(gpjax.ModelFileError) as info:
        _load(tmp_path, json.dumps(data))
    assert "\n" not in str(info.value)
    assert not (tmp_path / "pwned").exists()
    assert not Path("pwned").exists()


def test_handwritten_model_loads(tmp_path):
    model = _load(tmp_path, json.dumps(model_json()))
    equation = str(model.equation())
    assert "phi_ddot" in equation
    assert model.mass == 1.0 and model.state == {"phi": 4.0} and model.forcing == {"T": 1.0}


def test_documented_minimum_population_is_usable():
    """``population must be at least 4`` — so 4 should be accepted with the defaults."""
    from gpjax import GPConfig

    GPConfig(population=4)


@pytest.mark.skipif(sys.platform == "win32", reason="signal.setitimer is POSIX-only")
def test_model_file_huge_power_is_refused_quickly(tmp_path):
    """A 17-character feature must not keep the loader busy: refuse it within seconds."""
    import gpjax

    class _TooSlow(Exception):
        pass

    def _alarm(signum, frame):
        raise _TooSlow

    previous = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, 5.0)
    try:
        with pytest.raises(gpjax.ModelFileError):
            _load(tmp_path, json.dumps(with_feature("(phi + 1)**100000")))
    except _TooSlow:
        pytest.fail("Model.load still busy after 5 s on feature '(phi + 1)**100000'")
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


# --------------------------------------------------------------------------------------
# Memory guard, in process (the available memory is patched to a small number)
# --------------------------------------------------------------------------------------

def test_fit_beyond_available_memory_exits_2_and_writes_nothing(tmp_path, monkeypatch, capsys):
    import gpjax
    from gpjax import _memory, cli

    data = Path(gpjax.__file__).parent / "data" / "gear_example.csv"
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(_memory, "available_bytes", lambda: 10 * 2 ** 20)
    before = _snapshot(tmp_path)
    status = cli.main(["fit", str(data), "--time", "t", "--response", "phi", "--input", "T",
                       "--population", "8", "--generations", "1", "--out", "run"])
    out, err = capsys.readouterr()
    assert status == 2 and out == ""
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert re.match(r"gpjax: error: this run needs about [\d.]+ GB of memory but 0\.0 GB are "
                    r"available .*; shorten the record, or lower population or substeps$",
                    err.rstrip("\n")), err
    assert _snapshot(tmp_path) == before and not (tmp_path / "run").exists()


def test_the_diagnosis_checks_its_own_memory_before_its_fits(monkeypatch):
    """A diagnosis's fits at their substeps are checked against the memory then available,
    for the estimate less what the running process holds already."""
    import gpjax
    from gpjax import _memory
    from gpjax._canonical import Symbols
    from gpjax._diagnose_fits import FitProblem
    from gpjax._errors import UserInputError

    measurement = gpjax.load_csv(Path(gpjax.__file__).parent / "data" / "gear_example.csv",
                                 time="t", response="phi", inputs=["T"])
    need = _memory.fit_bytes(n_samples=measurement.n_samples, substeps=4,
                             population=4, together=True) - _memory.BASE_BYTES
    monkeypatch.setattr(_memory, "available_bytes", lambda: need - 1)
    with pytest.raises(UserInputError, match=r"^not enough memory for the diagnosis's fits: "
                       r"about [\d.]+ GB more needed, .*at 4 RK4 steps each\); shorten the "
                       r"record$"):
        FitProblem(measurement, Symbols("phi", "t", ("T",)), holdout=0.25, iterations=5,
                   substeps=4, batch=4)
    monkeypatch.setattr(_memory, "available_bytes", lambda: need)
    FitProblem(measurement, Symbols("phi", "t", ("T",)), holdout=0.25, iterations=5,
               substeps=4, batch=4)
