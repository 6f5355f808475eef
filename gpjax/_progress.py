"""Progress of a run: a tqdm bar on a terminal, lines on the ``gpjax`` logger.

A run logs one INFO line per generation (:func:`generation`) and one per stage
(:func:`stage`: generation 0's compiling, final model selection, convergence checks,
diagnosis steps, writing results) on the ``gpjax`` logger. Python shows none of them
unless logging is configured (e.g. ``logging.basicConfig(level=logging.INFO)``); the
command line writes them to stderr, each flushed, where stderr is not a terminal (a log
file, CI, ``nohup``, a cluster job: where tqdm hides its bar) and nowhere on a terminal,
which shows the bar (:func:`lines_on_stderr`). Nothing goes to stdout.

A :func:`stage_clock` times the stages that start while it is open, so a command can say
where the seconds of a stage-logged part (the diagnosis) went, parts that add up to it.
"""

from __future__ import annotations

import contextlib
import logging
import sys
import time

LOGGER = logging.getLogger("gpjax")
#: The open stage clocks' marks: (time.perf_counter(), message) per stage started.
_CLOCKS: list[list[tuple[float, str]]] = []


def stage(message: str) -> None:
    """Log the start of a stage of a run (and mark it on every open :func:`stage_clock`)."""
    now = time.perf_counter()
    for marks in _CLOCKS:
        marks.append((now, message))
    LOGGER.info(message)


@contextlib.contextmanager
def stage_clock(first: str):
    """While open, the stages started are timed. Yields a list that holds, once closed,
    (message, seconds) of each stage in order: ``first`` for the time before the first
    stage, then each stage until the next one or the close; the seconds add up to the
    time the clock was open."""
    marks = [(time.perf_counter(), first)]
    durations: list[tuple[str, float]] = []
    _CLOCKS.append(marks)
    try:
        yield durations
    finally:
        _CLOCKS.remove(marks)
        ends = [t for t, _ in marks[1:]] + [time.perf_counter()]
        durations.extend((message, end - began) for (began, message), end in zip(marks, ends))


def stage_summary(what: str, durations: list[tuple[str, float]]) -> str:
    """One line: ``what``'s seconds in all and per stage of :func:`stage_clock`, each
    stage's message without the prefix that names ``what`` ("diagnosis: ",
    "diagnosis of the system: "). A stage that does not name ``what`` (a fit's own stage,
    logged once per candidate inside a diagnosis step) counts towards the part it runs in,
    so a step is one part however many fits it makes."""
    parts: list[list] = []
    for k, (message, seconds) in enumerate(durations):
        named = message.lower().startswith(what.lower()) and ": " in message
        if k and parts and not named:
            parts[-1][1] += seconds
        else:
            parts.append([message.split(": ", 1)[1] if named else message, seconds])
    listed = "; ".join(f"{label} {s:.1f} s" for label, s in parts)
    return f"{what}: {sum(s for _, s in durations):.1f} s in all: {listed}."


def generation(number: int, total: int, best: float, seconds: float) -> None:
    """Log a finished generation: its number of ``total``, best objective and seconds."""
    LOGGER.info("generation %d/%d: best objective %.4g, %.1f s", number, total, best, seconds)


def bar(total: int, *, initial: int = 0, progress: bool | None = None):
    """A tqdm bar of generations, shown where stderr is a terminal unless ``progress``
    says otherwise."""
    from tqdm.auto import tqdm

    return tqdm(total=total, initial=initial, unit="gen", leave=False,
                disable=None if progress is None else not progress)


@contextlib.contextmanager
def lines_on_stderr():
    """While open, the ``gpjax`` logger's lines go to stderr (flushed after each), unless
    stderr is a terminal."""
    if sys.stderr.isatty():
        yield
        return
    handler = logging.StreamHandler(sys.stderr)  # flushes after every line
    handler.setFormatter(logging.Formatter("%(asctime)s gpjax: %(message)s", "%H:%M:%S"))
    level = LOGGER.level
    LOGGER.addHandler(handler)
    LOGGER.setLevel(logging.INFO)
    try:
        yield
    finally:
        LOGGER.removeHandler(handler)
        LOGGER.setLevel(level)
