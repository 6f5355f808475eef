"""Run-folder output: atomic file writes, ``history.csv`` and the ``fit.png`` figure.

Figures are ``matplotlib.figure.Figure`` objects drawn by the Agg canvas, without pyplot:
no display is needed and a notebook's backend is left as it is (:func:`png_bytes`).
"""

from __future__ import annotations

import csv
import io
import os
import tempfile
from pathlib import Path

import numpy as np

from ._errors import UserInputError


def check_out_folder(out: Path) -> None:
    """Refuse a run folder that is an existing file (UserInputError), before any work."""
    if out.exists() and not out.is_dir():
        raise UserInputError(f"--out {out} is a file; give a folder")


def write_bytes_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to a temporary file beside ``path``, then rename it into place."""
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(handle, "wb") as stream:
            stream.write(data)
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(temporary, path)
    except BaseException:
        if os.path.exists(temporary):
            os.unlink(temporary)
        raise


def write_text_atomic(path: Path, text: str) -> None:
    write_bytes_atomic(path, text.encode("utf-8"))


def history_csv(rows: list[dict]) -> str:
    """CSV text of per-generation statistics (one dict per generation)."""
    if not rows:
        return ""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(rows[0]), lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    return buffer.getvalue()


def fit_figure(time: np.ndarray, measured: np.ndarray, calculated: np.ndarray, *,
               response_name: str, n_bins: int, title: str) -> bytes:
    """PNG bytes: measured vs calculated response (paper Fig. 10) and their spectra."""
    from matplotlib.figure import Figure

    from ._objective import amplitude_spectrum  # JAX: only where a figure is drawn

    figure = Figure(figsize=(9, 7), constrained_layout=True)
    top, bottom = figure.subplots(2, 1)
    top.plot(time, measured, color="0.55", lw=1.2, label="measured")
    top.plot(time, calculated, color="C3", lw=1.0, ls="--", label="calculated")
    top.set_xlabel("t [s]")
    top.set_ylabel(response_name)
    top.set_title(title, fontsize=9)
    top.legend(loc="upper right")
    frequency = np.fft.rfftfreq(time.size, d=(time[-1] - time[0]) / (time.size - 1))
    bottom.semilogy(frequency, amplitude_spectrum(measured) + 1e-300, color="0.55", lw=1.2,
                    label="measured")
    bottom.semilogy(frequency, amplitude_spectrum(calculated) + 1e-300, color="C3", lw=1.0,
                    ls="--", label="calculated")
    bottom.axvline(frequency[min(n_bins, frequency.size) - 1], color="k", lw=0.8, ls=":",
                   label=f"m = {n_bins} bins (eq. 9)")
    bottom.set_xlabel("frequency [Hz]")
    bottom.set_ylabel(f"amplitude of {response_name}")
    bottom.legend(loc="upper right")
    return png_bytes(figure, dpi=110)


def png_bytes(figure, *, dpi: int) -> bytes:
    """A ``matplotlib.figure.Figure`` rendered to PNG by the Agg canvas (no pyplot, so no
    backend is switched)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(figure)
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=dpi)
    return buffer.getvalue()
