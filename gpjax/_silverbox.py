"""Loader for the Silverbox benchmark (Wigren & Schoukens, ECC 2013) from a user's folder.

Reads ``SNLS80mV.csv`` (columns V1 = input voltage, V2 = output voltage, a trailing comma
on every row) and returns it as a :class:`~gpjax._data.Measurement` with columns
``t`` (s, fs = 10^7/2^14 Hz), ``y`` (V2, V) and ``u`` (V1, V), plus the standard segments
(0-based Python slices, as in the ``nonlinear-benchmarks`` package). The data are never
copied into this repository.

At fs = 610 Hz with excitation up to ~200 Hz, linear interpolation of the input between
samples (at the RK4 stage times) is a poor reconstruction — half-way between samples a
200 Hz component keeps only cos(π·200/610) ≈ 51 % of its amplitude — and it distorts the
force the model sees: simulate Silverbox models with ``input_interpolation="bandlimited"``
(:func:`gpjax._data.between_samples`). At ω·h ≈ 2 one RK4 step per sample is far from
converged; ``substeps="auto"`` (the default) takes about ten.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ._data import Measurement
from ._errors import DataError

SAMPLE_RATE = 1e7 / 2 ** 14
FILE = "SNLS80mV.csv"
#: Standard split: estimation (multisines) and the three test segments.
SEGMENTS = {"estimation": (40650, 105712), "multisine": (105712, 127400),
            "arrow_full": (100, 40575), "arrow_no_extrapolation": (100, 32100)}
#: Samples at the start of a test segment that may be used to initialise the state.
WARMUP = 50


def load_silverbox(directory: str | Path) -> Measurement:
    """The whole SNLS80mV record as a Measurement (t in s, y = V2 and u = V1 in volts).

    Raises:
        DataError: the folder or file is missing, or the file is not the expected table.
    """
    path = Path(directory) / FILE
    if not path.is_file():
        raise DataError(f"{path} does not exist; give the folder that holds {FILE}")
    try:
        values = np.loadtxt(path, delimiter=",", skiprows=1, usecols=(0, 1), dtype=np.float64)
    except (OSError, ValueError) as err:
        raise DataError(f"cannot read {path} as two numeric columns V1, V2: {err}") from None
    if values.ndim != 2 or values.shape[0] < SEGMENTS["estimation"][1]:
        raise DataError(f"{path} holds {values.shape[0] if values.ndim == 2 else 0} rows; the "
                        f"Silverbox record has 131,072")
    time = np.arange(values.shape[0]) / SAMPLE_RATE
    return Measurement(time=time, response=values[:, 1], inputs={"u": values[:, 0]},
                       time_name="t", response_name="y")


def silverbox_segments(directory: str | Path) -> dict[str, Measurement]:
    """The estimation segment and the test segments ``multisine``, ``arrow_full`` and
    ``arrow_no_extrapolation``, each a Measurement on its own slice of the record."""
    record = load_silverbox(directory)
    return {name: record.segment(start, stop) for name, (start, stop) in SEGMENTS.items()}


def segment_rms(models: list, segment: Measurement, *, warmup: int = WARMUP) -> np.ndarray:
    """RMS simulation error in the response's units of each model on a test segment.

    The initial state is estimated from the first ``warmup`` samples (Savitzky–Golay, as
    the benchmark allows); the error is taken over the samples after them. Each model is
    simulated by the reference solve (adaptive diffrax Dopri8, :mod:`gpjax._reference`)
    with its own input interpolation; a model whose solve fails scores inf.

    Args:
        models: :class:`~gpjax._model.Model` objects with the segment's variable names.
        segment: the test data (from :func:`silverbox_segments`).
        warmup: samples used for the initial state and left out of the RMS.
    """
    from ._weak_form import estimate_initial_conditions

    y0 = estimate_initial_conditions(segment.segment(0, max(warmup + 1, 21)))
    rms = []
    for model in models:
        error = segment.response[warmup:] - model.simulate(segment, initial_conditions=y0)[warmup:]
        rms.append(float(np.sqrt(np.mean(error ** 2))))
    return np.where(np.isfinite(rms), rms, np.inf)
