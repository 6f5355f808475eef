"""Loader for the Silverbox benchmark (Wigren & Schoukens, ECC 2013) from a user's folder.

Reads ``SNLS80mV.csv`` (columns V1 = input voltage, V2 = output voltage, a trailing comma
on every row) and returns it as a :class:`~gpjax._data.Measurement` with columns
``t`` (s, fs = 10^7/2^14 Hz), ``y`` (V2, V) and ``u`` (V1, V), plus the standard segments
(0-based Python slices, as in the ``nonlinear-benchmarks`` package). The data are never
copied into this repository.

The simulation interpolates inputs linearly between samples (at the RK4 stage times). At
fs = 610 Hz with excitation up to ~200 Hz that is a poor reconstruction — half-way between
samples a 200 Hz component keeps only cos(π·200/610) ≈ 51 % of its amplitude — and it
distorts the force the model sees. :func:`upsample` reconstructs the record between samples
by band-limited interpolation first; :func:`segment_rms` scores such a record on the
original samples only.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.signal import resample_poly

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


def upsample(measurement: Measurement, factor: int) -> Measurement:
    """The record at ``factor`` times its sample rate: response and inputs reconstructed
    between samples by band-limited interpolation (polyphase FIR, Kaiser-windowed sinc,
    :func:`scipy.signal.resample_poly`), passing through the original samples, which stay
    at indices 0, factor, 2·factor, … The interpolation is non-causal: a value between two
    samples uses about ten samples on either side (linear interpolation uses one ahead).

    Raises:
        ValueError: ``factor`` < 1.
    """
    if factor < 1:
        raise ValueError(f"factor must be >= 1, got {factor}")
    if factor == 1:
        return measurement
    n = (measurement.n_samples - 1) * factor + 1

    def reconstructed(values: np.ndarray) -> np.ndarray:
        out = resample_poly(values, factor, 1)[:n]
        out[::factor] = values
        return out

    return Measurement(time=measurement.time[0] + np.arange(n) * (measurement.dt / factor),
                       response=reconstructed(measurement.response),
                       inputs={k: reconstructed(v) for k, v in measurement.inputs.items()},
                       time_name=measurement.time_name, response_name=measurement.response_name)


def silverbox_segments(directory: str | Path, *, factor: int = 1) -> dict[str, Measurement]:
    """The estimation segment and the test segments ``multisine``, ``arrow_full`` and
    ``arrow_no_extrapolation`` (each a Measurement on its own slice of the record), the
    whole record first reconstructed at ``factor`` times the sample rate (:func:`upsample`;
    a segment then spans its original samples and the points between them)."""
    record = upsample(load_silverbox(directory), factor)
    return {name: record.segment(start * factor, (stop - 1) * factor + 1)
            for name, (start, stop) in SEGMENTS.items()}


def segment_rms(models: list, segment: Measurement, *, warmup: int = WARMUP,
                substeps: int = 1, factor: int = 1) -> np.ndarray:
    """RMS simulation error in the response's units of each model on a test segment.

    The initial state is estimated from the first ``warmup`` original samples
    (Savitzky–Golay, as the benchmark allows); the error is taken over the original
    samples after them. All models are simulated in one compiled solve.

    Args:
        models: :class:`~gpjax._model.Model` objects with the segment's variable names.
        segment: the test data (from :func:`silverbox_segments` with the same ``factor``).
        warmup: original samples used for the initial state and left out of the RMS.
        substeps: RK4 steps per sample interval of ``segment``.
        factor: ``segment`` holds the original samples at every ``factor``-th index.
    """
    from ._evaluator import PopulationEvaluator, polynomial_state_features
    from ._model import estimate_initial_conditions

    y0 = estimate_initial_conditions(segment.segment(0, max(warmup * factor + 1, 21)))
    lhs, forcing, degree = [], [], 3
    for model in models:
        for text in (*model.state, *model.parametric):
            feature = model._feature(text)
            if feature not in lhs:
                lhs.append(feature)
        forcing += [model._feature(t) for t in model.forcing if model._feature(t) not in forcing]
    symbols = models[0].symbols
    polynomial = set(polynomial_state_features(symbols, degree))
    evaluator = PopulationEvaluator(
        segment, symbols, max_degree=degree, substeps=substeps, n_bins=1, batch=len(models),
        extra_state_features=tuple(f for f in lhs if f not in polynomial))
    for feature in forcing:
        evaluator.forcing_index(feature)
    population = evaluator.empty(len(models))
    for i, model in enumerate(models):
        population.mass[i] = model.mass
        for text, value in (*model.state.items(), *model.parametric.items()):
            population.state[i, evaluator.state_index(model._feature(text))] = value
        for text, value in model.forcing.items():
            population.forcing[i, evaluator.forcing_index(model._feature(text))] = value
        population.y0[i] = y0
    responses, scores = evaluator.simulate(population)
    error = (segment.response[None, warmup * factor::factor]
             - responses[:, warmup * factor::factor])
    rms = np.sqrt(np.mean(error ** 2, axis=1))
    return np.where(scores.status == 0, rms, np.inf)

