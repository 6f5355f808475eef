"""The record as arguments of the compiled programs, padded to a few lengths.

A compiled program that closed over the record's samples (the measured response, its
spectrum, the step, the divergence bounds) was a new program for every record, so a new
record compiled everything again, also where its cache folder held the programs of another
record of the same length. The population evaluator and the refiner therefore take the
record as an argument (:class:`RecordArrays`), and their program keys hold only shapes and
settings: every record of a *length bucket* shares them.

Buckets (:func:`padded_length`): the record's N samples are padded to the next of
:data:`BUCKETS_PER_OCTAVE` lengths per octave (…, 1024, 1280, 1536, 1792, 2048, …), so a
program serves every length from one bucket to the next and a record integrates at most
25 % (on average ~12 %) more samples than it has. The padded samples hold the last input
value; they are masked out of every sum (:attr:`RecordArrays.valid`), so the objective, the
fitted initial states and the refined constants are those of the unpadded record exactly
(tested). The spectral part of the objective is a DFT-matrix product whose columns past N
are zero and whose rows are the record's own bins j/N, padded with zero rows to the next
power of two (:func:`padded_bins`). The bins a record needs follow its band, not its length
(eq. 9's 99 % energy rule), so records of one length differ in them: on issue 43's four
records, 7,601–7,991 samples, they ranged over 136–203 bins, three buckets at four per
octave (160, 192, 224), and two of the three records after the first compiled their
population programs again (~16 s each); at one bucket per octave all four hold 256. An
octave still splits records whose bins straddle a power of two: 2,001-sample records of
one system and band held 26–40 bins, 32 or 64, and half of them compiled again. So the
programs hold at least the bins below f_s/32 (:func:`band_floor`; at 2,048 samples 64):
every record sampled 32 times faster than the band of its energy shares one program per
length bucket. The price is rows of the product: at 8,192 samples, 256 bins take 75 ms per
500 models on 2 cores (the cost is proportional to the rows), against 4.4–4.8 s a
generation of a wide-set fit; at the paper's 1,334 samples 58 bins hold 64 either way. The
floor stops where the DFT matrix would pass :data:`gpjax._objective.DFT_MATRIX_LIMIT`. (A
chirp-z transform, whose cost does not grow with the bins, ran 2–3× slower than the
product at both sizes on XLA's CPU FFT.) Records too long for a DFT matrix (the rfft path of
:mod:`gpjax._objective`) are not padded: their programs serve records of the same length.
"""

from __future__ import annotations

import contextlib
import dataclasses

import jax
import numpy as np

from ._objective import DFT_MATRIX_LIMIT

#: Lengths per octave that records are padded to (see the module docstring).
BUCKETS_PER_OCTAVE = 4
#: Shortest padded length.
SMALLEST_BUCKET = 16
#: The programs hold at least the bins below f_s / BAND_FRACTION (see the module docstring).
BAND_FRACTION = 32


def padded_length(n: int) -> int:
    """The smallest bucket length ≥ ``n``: m·2^k with m in 4…7 (BUCKETS_PER_OCTAVE = 4),
    at least :data:`SMALLEST_BUCKET`."""
    n = max(int(n), SMALLEST_BUCKET)
    octave = 1 << max(0, (n - 1).bit_length() - 1)  # largest power of two below n (or n)
    step = max(1, octave // BUCKETS_PER_OCTAVE)
    return -(-n // step) * step


def padded_bins(n_bins: int, n_padded: int = 0) -> int:
    """The bins the programs hold for a record's ``n_bins`` at ``n_padded`` samples: the
    next power of two of at least ``n_bins``, :data:`SMALLEST_BUCKET` and
    :func:`band_floor` (the module docstring says why)."""
    wanted = max(int(n_bins), SMALLEST_BUCKET, band_floor(n_padded))
    return 1 << (wanted - 1).bit_length()


def band_floor(n_padded: int) -> int:
    """The fewest bins the programs hold at ``n_padded`` samples: those up to
    f_s/:data:`BAND_FRACTION`, while the DFT matrix stays within
    :data:`gpjax._objective.DFT_MATRIX_LIMIT` elements."""
    return min(int(n_padded) // BAND_FRACTION, DFT_MATRIX_LIMIT // max(1, 2 * int(n_padded)))


def padded_rows(array: np.ndarray, rows: int) -> np.ndarray:
    """``array`` extended along axis 0 to ``rows`` by repeating its last row."""
    array = np.asarray(array)
    if array.shape[0] >= rows:
        return array
    return np.concatenate([array, np.repeat(array[-1:], rows - array.shape[0], axis=0)])


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class RecordArrays:
    """What a compiled program needs of a record, as arrays (N' the padded length, m' the
    padded bins, D the coordinates).

    Attributes:
        responses: (N', D) measured responses, zero past N.
        valid: (N',) 1.0 for the record's samples, 0.0 for the padding.
        count: () N, the record's samples.
        dft: (2m', N') weighted cos and sin rows of the record's bins (zero past N and m),
            or (1, m') the rfft weights (:func:`gpjax._objective._dft_matrix`).
        amplitude: (m', D) the measured amplitude spectra (zero past m).
        weights: (D,) each coordinate's weight in the objective.
        bounds: (D, 2) largest |x| and |x'| a simulation is clipped to.
        step: () the RK4 step h (s).
        start: () the time of the first sample (s).
        noise_scale: (D,) the responses' standard deviations (residual scales of the
            refiner).
        sign_scales: (2D²,) θ of a system's smoothed signs tanh(θ·z), one per equation
            variable (:mod:`gpjax._system_bank`; unused for D = 1).
        extra_numbers: (K,) the numbers of the evaluator's extra state features, in
            order (:func:`gpjax._evaluator.lifted_numbers`; empty without them).
    """

    responses: np.ndarray
    valid: np.ndarray
    count: np.ndarray
    dft: np.ndarray
    amplitude: np.ndarray
    weights: np.ndarray
    bounds: np.ndarray
    step: np.ndarray
    start: np.ndarray
    noise_scale: np.ndarray
    sign_scales: np.ndarray
    extra_numbers: np.ndarray


class RecordContext:
    """Mixin: :meth:`record` gives the record arrays being traced inside
    :meth:`tracing`, else the evaluator's own (:attr:`record_arrays`)."""

    _traced_record: RecordArrays | None = None

    @property
    def record(self) -> RecordArrays:
        return self._traced_record if self._traced_record is not None else self.record_arrays

    @contextlib.contextmanager
    def tracing(self, record: RecordArrays):
        """While JAX traces a program body: :attr:`record` is ``record`` (its arguments)."""
        outer, self._traced_record = self._traced_record, record
        try:
            yield
        finally:
            self._traced_record = outer
