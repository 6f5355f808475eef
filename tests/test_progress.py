"""Progress where stderr is not a terminal: one line per generation and per stage on
stderr, stdout unchanged; on a terminal nothing but the bar."""

import io
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from gpjax import Identifier, _progress
from gpjax.gear import generate_gear_example

LINE = re.compile(r"^\d\d:\d\d:\d\d gpjax: (.*)$")


@pytest.mark.slow  # 20-30 s: CI's slow step; the fast tier stays within 5 min on 2 cores
def test_a_piped_fit_logs_each_generation_and_stage_on_stderr(tmp_path):
    generate_gear_example(revolutions=0.35, seed=2).measurement.to_csv(tmp_path / "data.csv")
    (tmp_path / "c.toml").write_text("population = 24\ngenerations = 2\nepsilon = 0.0\n"
                                     "refine_top = 2\n")
    env = dict(os.environ, JAX_PLATFORMS="cpu",
               PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    done = subprocess.run([sys.executable, "-m", "gpjax", "fit", "data.csv", "--time", "t",
                           "--response", "phi", "--input", "T", "--config", "c.toml",
                           "--out", "run"], cwd=tmp_path, env=env, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    lines = [m.group(1) for m in map(LINE.match, done.stderr.splitlines()) if m]
    generations = [re.fullmatch(r"generation (\d+)/2: best objective \S+, [\d.]+ s", line)
                   for line in lines]
    assert [int(g.group(1)) for g in generations if g] == [0, 1, 2], done.stderr
    stages = [line for line, g in zip(lines, generations) if not g]
    for stage in ("generation 0: compiling", "final model selection", "convergence check at",
                  "writing results to run/"):
        assert any(line.startswith(stage) for line in stages), (stage, done.stderr)
    summary, timings = done.stdout.split("\n\nStopped by ")  # the results, nothing else
    expected = str(Identifier.load(tmp_path / "run")).splitlines()
    printed = summary.splitlines()
    assert printed[0] == expected[0] and "gpjax:" not in done.stdout
    residuals = printed[len(expected):]  # then the residual against its noise floor
    assert residuals[0] == "Residuals per coordinate (reference solve):"
    assert residuals[1].startswith("  residual of phi: RMS") and len(residuals) in (2, 3)
    assert timings.endswith("Results in run/\n") and "\n" not in timings[:-1]


def test_lines_only_where_stderr_is_not_a_terminal(monkeypatch):
    class Terminal(io.StringIO):
        def isatty(self):
            return True

    terminal, piped = Terminal(), io.StringIO()
    for stream in (terminal, piped):
        monkeypatch.setattr(sys, "stderr", stream)
        with _progress.lines_on_stderr():
            _progress.stage("writing")
        _progress.stage("after")  # the handler is gone
    assert terminal.getvalue() == ""
    assert LINE.match(piped.getvalue()).group(1) == "writing"
    assert piped.getvalue().count("\n") == 1


def test_a_stage_clock_splits_its_time_into_the_stages_started_while_open(monkeypatch):
    clock = iter([10.0, 10.5, 12.0, 12.5, 13.0, 13.5, 14.5, 99.0])  # readings in turn
    monkeypatch.setattr(_progress.time, "perf_counter", lambda: next(clock))
    fit = "fitting the system's constants at 2 substeps"
    with _progress.stage_clock("setting up") as durations:
        _progress.stage("diagnosis: step 1: ranking the effects")
        _progress.stage("diagnosis of the system: step 1: fitting 2 candidate effect(s)")
        _progress.stage(fit)  # a fit's own stage, once per candidate
        _progress.stage(fit)
        _progress.stage("diagnosis: writing the report")
    _progress.stage("after")  # the clock is closed: not timed
    assert durations == [("setting up", 0.5), ("diagnosis: step 1: ranking the effects", 1.5),
                         ("diagnosis of the system: step 1: fitting 2 candidate effect(s)",
                          0.5), (fit, 0.5), (fit, 0.5), ("diagnosis: writing the report", 1.0)]
    assert _progress.stage_summary("Diagnosis", durations) == (
        "Diagnosis: 4.5 s in all: setting up 0.5 s; step 1: ranking the effects 1.5 s; "
        "step 1: fitting 2 candidate effect(s) 1.5 s; writing the report 1.0 s.")
