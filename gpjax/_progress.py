"""Progress of a run: a tqdm bar on a terminal, lines on the ``gpjax`` logger.

A run logs one INFO line per generation (:func:`generation`) and one per stage
(:func:`stage`: generation 0's compiling, final model selection, convergence checks,
diagnosis steps, writing results) on the ``gpjax`` logger. Python shows none of them
unless logging is configured (e.g. ``logging.basicConfig(level=logging.INFO)``); the
command line writes them to stderr, each flushed, where stderr is not a terminal (a log
file, CI, ``nohup``, a cluster job: where tqdm hides its bar) and nowhere on a terminal,
which shows the bar (:func:`lines_on_stderr`). Nothing goes to stdout.
"""

from __future__ import annotations

import contextlib
import logging
import sys

LOGGER = logging.getLogger("gpjax")


def stage(message: str) -> None:
    """Log the start of a stage of a run."""
    LOGGER.info(message)


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
