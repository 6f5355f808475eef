"""Measurements: validated, uniformly sampled responses (one or several coordinates) with
zero or more inputs.

Sampling must be uniform: gpjax integrates with a fixed step between samples and computes
spectra with the DFT, so a non-uniform time axis is refused (resample it first, e.g. with
``numpy.interp``) rather than silently resampled.
"""

from __future__ import annotations

import csv
import hashlib
import keyword
import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ._errors import DataError

if TYPE_CHECKING:
    from scipy.interpolate import CubicSpline

MIN_SAMPLES = 20
#: Largest allowed deviation of any sample interval from the mean one, as a fraction of it.
SAMPLING_TOLERANCE = 1e-3
#: Largest magnitude accepted in any column; beyond it squares overflow float64.
MAX_MAGNITUDE = 1e100
#: How inputs are reconstructed between samples (see :func:`between_samples`).
INPUT_INTERPOLATIONS = ("linear", "bandlimited", "hold")
#: Points per sample interval of the band-limited reconstruction (:func:`bandlimited_spline`).
BANDLIMITED_FACTOR = 16
#: Samples on either side that one band-limited value between samples draws on.
BANDLIMITED_REACH = 32


class Measurement:
    """Measured responses x_1(t) … x_D(t) and their inputs u_k(t) on one uniform time grid.

    One response (D = 1) is the usual case: ``Measurement(time=t, response=x,
    inputs={"u": u})``; several coordinates of one system are given as
    ``responses`` (N, D) with ``response_names``.

    Attributes:
        time: sample times in seconds, shape (N,), strictly increasing and uniform.
        responses: measured responses, shape (N, D), in the user's units.
        inputs: input name -> samples, shape (N,) each, in the user's units.
        time_name, response_names: the column names (used in equations and model files).
        response, response_name: the one response (N,) and its name (D = 1 only).

    Raises:
        DataError: bad arrays or names (see :func:`load_csv`); a response that is also an
            input or named twice; coordinates of different lengths.
    """

    def __init__(self, time, response=None, inputs=None, time_name: str = "t",
                 response_name: str = "x", *, responses=None,
                 response_names: tuple[str, ...] | list[str] | None = None):
        if (response is None) == (responses is None):
            raise ValueError("give either response (N,) or responses (N, D)")
        if response is not None:
            columns, names = [response], (response_name,)
        else:
            names = tuple(response_names or ())
            array = np.asarray(responses, dtype=np.float64) if not isinstance(
                responses, (list, tuple)) else None
            columns = (list(responses) if array is None else
                       [array] if array.ndim == 1 else list(array.T))
            if len(names) != len(columns):
                raise DataError(f"{len(columns)} response columns but {len(names)} names; "
                                "name every response once")
        time = _as_vector(time, "time")
        columns = [_as_vector(c, name) for c, name in zip(columns, names)]
        inputs = {name: _as_vector(v, name) for name, v in (inputs or {}).items()}
        n = time.size
        for name, values in [*zip(names, columns), *inputs.items()]:
            if values.size != n:
                raise DataError(f"column {name!r} has {values.size} samples but time has {n}; "
                                "give every column the same length")
        _check_names(time_name, names, tuple(inputs))
        check_time(time)
        if n < MIN_SAMPLES:
            raise DataError(f"only {n} samples; gpjax needs at least {MIN_SAMPLES}")
        for name, values in zip(names, columns):
            if np.ptp(values) == 0:
                raise DataError(f"response {name!r} is constant; there is no dynamics "
                                "to identify")
        self.time = time
        self.responses = np.stack(columns, axis=1)
        self.inputs = inputs
        self.time_name = time_name
        self.response_names = names

    @property
    def n_coordinates(self) -> int:
        """D, the number of measured coordinates."""
        return len(self.response_names)

    @property
    def response(self) -> np.ndarray:
        """The one response (N,).

        Raises:
            DataError: the measurement has several responses.
        """
        return self.responses[:, self._single()]

    @property
    def response_name(self) -> str:
        """The one response's name (raises :class:`DataError` for several)."""
        return self.response_names[self._single()]

    def _single(self) -> int:
        if self.n_coordinates != 1:
            raise DataError(f"this step supports one response, got {self.n_coordinates} "
                            f"({', '.join(self.response_names)}); give one --response")
        return 0

    @property
    def n_samples(self) -> int:
        return self.time.size

    @property
    def dt(self) -> float:
        """Sample interval in seconds."""
        return float((self.time[-1] - self.time[0]) / (self.time.size - 1))

    @property
    def input_names(self) -> tuple[str, ...]:
        return tuple(self.inputs)

    def fingerprint(self) -> str:
        """SHA-256 of the arrays and names (to tell one data set from another)."""
        digest = hashlib.sha256()
        for array in (self.time, *self.responses.T, *self.inputs.values()):
            digest.update(np.ascontiguousarray(array, dtype=np.float64).tobytes())
        names = self.response_names[0] if self.n_coordinates == 1 else self.response_names
        digest.update(repr((self.time_name, names, self.input_names)).encode())
        return digest.hexdigest()

    def coordinate(self, d: int) -> "Measurement":
        """Coordinate ``d``'s response alone, with the same time and inputs."""
        return Measurement(time=self.time, response=self.responses[:, d], inputs=self.inputs,
                           time_name=self.time_name, response_name=self.response_names[d])

    def segment(self, start: int, stop: int) -> "Measurement":
        """Samples ``start:stop`` (Python slice semantics) as a new measurement."""
        return Measurement(
            time=self.time[start:stop], responses=self.responses[start:stop],
            inputs={k: v[start:stop] for k, v in self.inputs.items()},
            time_name=self.time_name, response_names=self.response_names)

    def with_inputs(self, inputs: dict[str, np.ndarray]) -> "Measurement":
        """This measurement with other input samples (name -> (N,)), validated as any.

        Raises:
            DataError: as the constructor does.
        """
        return Measurement(time=self.time, responses=self.responses, inputs=inputs,
                           time_name=self.time_name, response_names=self.response_names)

    def to_csv(self, path: str | Path) -> None:
        """Write the columns as CSV with a header (time, responses, inputs)."""
        columns = [self.time, *self.responses.T, *self.inputs.values()]
        header = [self.time_name, *self.response_names, *self.inputs]
        with open(path, "w", newline="", encoding="utf-8") as handle:
            writer = csv.writer(handle)
            writer.writerow(header)
            writer.writerows(zip(*(map(repr, map(float, c)) for c in columns)))


def _check_names(time_name: str, responses: tuple[str, ...], inputs: tuple[str, ...]) -> None:
    """Refuse column names that equations cannot use, or a name given twice (DataError)."""
    names = [time_name, *responses, *inputs]
    for name in names:
        if not name.isidentifier() or name.startswith("_") or keyword.iskeyword(name):
            raise DataError(f"column name {name!r} is not usable in equations; rename it to "
                            "letters, digits and underscores, starting with a letter")
    for name in responses:
        if responses.count(name) > 1:
            raise DataError(f"response {name!r} is named twice; name each column once")
        if name in inputs:
            raise DataError(f"{name!r} is named twice, as a response and as an input; name "
                            "each column once")
    for name in names:
        if names.count(name) > 1:
            raise DataError(f"column {name!r} is named twice (columns {names}); name each "
                            "column once")
    if any(name.endswith("_dot") or name.endswith("_ddot") for name in names):
        raise DataError("column names must not end in _dot or _ddot (reserved for derivatives); "
                        "rename the column")


def between_samples(values: np.ndarray, factor: int, method: str = "linear") -> np.ndarray:
    """``values`` (N,) at ``factor`` times the sample rate: (N − 1)·factor + 1 points that
    pass through the samples, which stay at indices 0, factor, 2·factor, …

    ``"linear"`` joins the samples by straight lines: for smooth inputs sampled well above
    their bandwidth. ``"bandlimited"`` reconstructs the signal between them as band-limited
    (:func:`bandlimited_spline`): for inputs with content near the Nyquist frequency that
    were anti-alias filtered (e.g. Silverbox), where half-way between samples linear
    interpolation keeps only cos(π·f/fs) of a component at f. It is non-causal — a value
    between two samples uses :data:`BANDLIMITED_REACH` samples on either side. ``"hold"``
    holds each sample for one period, u(t) = u_k on [t_k, t_(k+1)) (zero-order hold): for
    inputs applied by a DAC, where the measured input is the commanded value held for a
    period.

    Raises:
        ValueError: ``factor`` < 1 or an unknown ``method``.
    """
    if factor < 1:
        raise ValueError(f"factor must be >= 1, got {factor}")
    if method not in INPUT_INTERPOLATIONS:
        raise ValueError(f"input interpolation must be one of {INPUT_INTERPOLATIONS}, "
                         f"got {method!r}")
    if factor == 1:
        return np.array(values, dtype=np.float64)
    n = (values.size - 1) * factor + 1
    if method == "linear":
        return np.interp(np.arange(n) / factor, np.arange(values.size), values)
    if method == "hold":
        return np.repeat(np.asarray(values, dtype=np.float64), factor)[:n]
    if BANDLIMITED_FACTOR % factor == 0:
        return _bandlimited_grid(values)[:: BANDLIMITED_FACTOR // factor]
    out = bandlimited_spline(values)(np.arange(n) / factor)
    out[::factor] = values
    return out


def _bandlimited_grid(values: np.ndarray) -> np.ndarray:
    """``values`` at :data:`BANDLIMITED_FACTOR` times the sample rate, band-limited:
    polyphase FIR (:func:`scipy.signal.resample_poly`, the ends extended by a fitted line)
    with a Kaiser-windowed sinc (β = 10) spanning ±32 samples, which reproduces a tone
    up to 0.9 × Nyquist within 1e-5 of its amplitude (scipy's default ±10-sample, β = 5
    filter: 3e-3, whose images a fine integrator would see), passing through the samples."""
    # scipy is imported here, not at the top: the CLI imports this module to validate a
    # user's files, and scipy.signal would triple the time it takes to refuse a bad one.
    from scipy.signal import firwin, resample_poly

    n = (values.size - 1) * BANDLIMITED_FACTOR + 1
    taps = firwin(2 * BANDLIMITED_FACTOR * BANDLIMITED_REACH + 1, 1.0 / BANDLIMITED_FACTOR,
                  window=("kaiser", 10.0))
    out = resample_poly(values, BANDLIMITED_FACTOR, 1, window=taps, padtype="line")[:n]
    out[::BANDLIMITED_FACTOR] = values
    return out


def bandlimited_spline(values: np.ndarray) -> CubicSpline:
    """The band-limited reconstruction of ``values`` as a function of the sample index
    (0 … N − 1, fractional between samples): :func:`_bandlimited_grid` joined by a cubic
    spline. This one function is the ``"bandlimited"`` input: the RK4 stage values
    (:func:`between_samples`) and the reference solve (:mod:`gpjax._reference`) both
    evaluate it; the spline's own error is ~(π/16)⁴/384 ≈ 4e-6 of a component at the
    Nyquist frequency."""
    from scipy.interpolate import CubicSpline  # see _bandlimited_grid

    fine = _bandlimited_grid(np.asarray(values, dtype=np.float64))
    return CubicSpline(np.arange(fine.size) / BANDLIMITED_FACTOR, fine)


def _as_vector(values, name: str) -> np.ndarray:
    try:
        array = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise DataError(f"column {name!r} is not numeric; remove text from it") from None
    if array.ndim != 1:
        raise DataError(f"column {name!r} must be one-dimensional, got shape {array.shape}")
    bad = ~np.isfinite(array)
    if bad.any():
        i = int(np.argmax(bad))
        raise DataError(f"column {name!r} holds {array[i]} at row {i + 1}; remove or fill "
                        "NaN/inf values")
    if array.size and np.max(np.abs(array)) > MAX_MAGNITUDE:
        raise DataError(f"column {name!r} holds {np.max(np.abs(array)):.3g}, beyond "
                        f"{MAX_MAGNITUDE:.0e}; rescale it to sensible units")
    return array


def check_time(time: np.ndarray) -> None:
    """Refuse a time axis that is not strictly increasing and uniform (DataError)."""
    steps = np.diff(time)
    if steps.size and np.any(steps <= 0):
        i = int(np.argmax(steps <= 0))
        raise DataError(f"time is not strictly increasing at row {i + 2} "
                        f"({time[i]} then {time[i + 1]}); sort the rows and drop duplicate times")
    if steps.size:
        mean = (time[-1] - time[0]) / steps.size
        worst = float(np.max(np.abs(steps - mean)) / mean)
        if worst > SAMPLING_TOLERANCE:
            raise DataError(f"time is not uniformly sampled (an interval differs by {worst:.1%} "
                            "from the mean); resample to a uniform grid first")


def load_csv(path: str | Path, *, time: str, response: str | None = None,
             responses: tuple[str, ...] | list[str] | None = None,
             inputs: tuple[str, ...] | list[str] = ()) -> Measurement:
    """Read a measurement from a CSV file with a header row.

    Args:
        path: the CSV file with a header row, separated by commas (a trailing comma on every
            row is accepted), tabs, semicolons or whitespace, as its header is; lines
            starting with ``#`` are skipped.
        time: name of the time column, in seconds.
        response: name of the measured response column (one coordinate), or
        responses: names of several measured coordinates of one system, in order.
        inputs: names of the input (excitation) columns, in order; the first one is the
            input whose coefficient is normalised to 1 in the model.

    Raises:
        DataError: missing file or column, non-numeric cell, NaN/inf, fewer than 20 rows,
            time not strictly increasing or not uniform, a response named twice or also
            an input, columns of different lengths (empty or NaN cells at the end of one).
        ValueError: both or neither of ``response`` and ``responses``.
        TypeError: ``response`` not one name, or ``responses`` or ``inputs`` one name
            instead of a list.
    """
    if (response is None) == (responses is None):
        raise ValueError("give either response= (one name) or responses= (a list of names)")
    if response is not None and not isinstance(response, str):
        raise TypeError(f"response= takes one column name; for several coordinates give "
                        f"responses={list(response)!r}")
    for label, given in (("responses", responses), ("inputs", inputs)):
        if isinstance(given, str):
            raise TypeError(f"{label}= takes a list of column names: {label}={[given]!r}")
    names = (response,) if response is not None else tuple(responses)
    if not names:
        raise DataError("no response named; give at least one --response")
    _check_names(time, names, tuple(inputs))
    data = read_columns(path, [time, *names, *inputs])
    return Measurement(
        time=data[time], responses=[data[name] for name in names],
        inputs={name: data[name] for name in inputs}, time_name=time, response_names=names)


def read_columns(path: str | Path, wanted: list[str], *,
                 optional: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """Columns of a CSV file with a header row, by name (``optional`` ones only if present);
    separators and comment lines as :func:`load_csv` reads them.

    Raises:
        DataError: missing file or wanted column, a column named twice, non-numeric cell,
            NaN/inf, fewer than 20 rows.
    """
    path = Path(path)
    try:
        with open(path, newline="", encoding="utf-8-sig") as handle:
            rows = _numbered_rows(handle)
    except FileNotFoundError:
        raise DataError(f"data file {path} does not exist; check the path") from None
    except IsADirectoryError:
        raise DataError(f"data file {path} is a directory; give a CSV file") from None
    except (OSError, UnicodeDecodeError, csv.Error) as err:
        raise DataError(f"cannot read {path} as CSV text: {err}") from None
    rows = [(n, r) for n, r in rows if any(cell.strip() for cell in r)]
    if not rows:
        raise DataError(f"data file {path} is empty; it needs a header row and data rows")
    header = [cell.strip() for cell in rows[0][1]]
    while header and header[-1] == "":
        header.pop()
    if len(set(wanted)) != len(wanted):
        raise DataError(f"the same column is named twice in {wanted}; name each column once")
    wanted = wanted + [name for name in optional if name in header and name not in wanted]
    for name in wanted:
        if header.count(name) > 1:
            raise DataError(f"column {name!r} appears {header.count(name)} times in the header of "
                            f"{path}; rename the duplicates")
        if name not in header:
            hint = ("the file seems to have no header row; add one" if _is_number(header[0])
                    else f"columns are: {', '.join(map(repr, header))}")
            raise DataError(f"column {name!r} not found in {path}; {hint}")
    index = {name: header.index(name) for name in wanted}
    _check_lengths(rows, index, path)
    data = {name: [] for name in wanted}
    for line, row in rows[1:]:
        for name in wanted:
            j = index[name]
            cell = row[j].strip() if j < len(row) else ""
            try:
                value = float(cell)
            except ValueError:
                comma = (" (a decimal comma? write decimal points)"
                         if _is_number(cell.replace(",", ".", 1)) else "")
                raise DataError(f"{path} line {line}, column {name!r}: {cell!r} is not a "
                                f"number{comma}; fix or remove that row") from None
            if not math.isfinite(value):
                raise DataError(f"{path} line {line}, column {name!r} is {cell}; remove or fill "
                                "NaN/inf values")
            data[name].append(value)
    if len(rows) - 1 < MIN_SAMPLES:
        raise DataError(f"{path} has {len(rows) - 1} data rows; gpjax needs at least {MIN_SAMPLES}")
    return {name: np.array(values) for name, values in data.items()}


def _numbered_rows(lines) -> list[tuple[int, list[str]]]:
    """(line number in the file, cells) of each line that is neither blank nor a comment
    (``#``), split at the header's separator: a comma, else a tab, else a semicolon, else
    runs of whitespace."""
    kept = [(n, line) for n, line in enumerate(lines, start=1)
            if line.strip() and not line.lstrip().startswith("#")]
    if not kept:
        return []
    separator = next((sep for sep in ",\t;" if sep in kept[0][1]), None)
    if separator is None:
        return [(n, line.split()) for n, line in kept]
    reader = csv.reader((line for _, line in kept), delimiter=separator)
    return [(kept[reader.line_num - 1][0], row) for row in reader]


def _check_lengths(rows: list[tuple[int, list[str]]], index: dict[str, int],
                   path: Path) -> None:
    """Refuse columns of different lengths: one whose cells are all empty or NaN from some
    row to the end while another goes on (DataError). ``rows``: the header's and the data
    rows' (line number, cells)."""
    def length(j: int) -> int:
        for i in range(len(rows) - 1, 0, -1):
            cells = rows[i][1]
            cell = cells[j].strip().lower() if j < len(cells) else ""
            if cell not in ("", "nan"):
                return i
        return 0

    lengths = {name: length(j) for name, j in index.items()}
    longest = max(lengths, key=lengths.get)
    for name, n in lengths.items():
        if n < lengths[longest]:
            raise DataError(f"column {name!r} of {path} has {n} samples but {longest!r} has "
                            f"{lengths[longest]} (empty or NaN after line {rows[n][0]}); give "
                            "every column the same length (trim the rows to the shortest)")


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True
