"""Diagnosis: the noise, estimated from the data — the response's noise floor, the
measured inputs' lines and the band of a drifting response's rate.

**Noise floor.** Measurement noise on the response is broadband; a model's response is
not: the response holds 99 % of its AC energy below the band edge
(:func:`gpjax._weak_form.smoothing_cutoff_hz`). Above it, the residual's periodogram is
the noise's, so its median over those bins / ln 2 (the median of an exponential variable is
ln 2 × its mean; the median ignores a stray line) is the noise's density, and
σ̂ = √(density · bins / N) its standard deviation. Inside the band, under the hypothesis
"the residual is that noise", the summed periodogram over K bins / density is Gamma(K)
distributed: :func:`noise_floor` gives the p-value of the in-band excess. A band of fewer
than :data:`MIN_BINS` bins (a slowly drifting response on a short record) is widened to the
lowest :data:`MIN_BINS`: under the hypothesis every bin is the noise's, so the test stays
exact on any fixed set of bins; it only becomes less sensitive.

**Input lines.** A measured input (a torque) carries sensor noise, which a simulation of the
model feeds through its dynamics: at a lightly damped resonance that noise rings and a
damping term "improves" the held-out prediction of a correct model (an errors-in-variables
false discovery). Where the input is a sum of lines (a periodic or multisine drive) the
noise is removed: lines are fitted (frequency, amplitude, phase, by least squares — no
leakage, unlike zeroing DFT bins of a record that is not a whole number of periods) while
the strongest remaining periodogram peak exceeds the noise floor (median periodogram / ln 2)
at level α with a Bonferroni bound over the padded bins searched (zero-padded at least 8×, to
a length the FFT is fast at), P > density · ln(padded bins/α). The
median is the noise's only while the lines hold a minority of the bins, so an input that needs lines
in more than a quarter of them (a broadband input) is left as measured.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import special
from scipy.fft import next_fast_len
from scipy.optimize import minimize_scalar

from ._data import Measurement
from ._objective import SPECTRAL_ENERGY_FRACTION

#: Most lines fitted to an input; one that needs more is broadband, left as measured.
MAX_LINES = 48
#: Fewest periodogram bins in the band tested and above it (the noise's median density).
MIN_BINS = 16
#: Noise draws whose mean square response gives the input noise's share: one draw's RMS
#: ranged 0.0074–0.020 over six draws on a 20 Hz Duffing record (a lightly damped response
#: to white noise is narrowband, so a record holds few independent cycles of it); the mean
#: of eight spreads √8 times less.
INPUT_NOISE_DRAWS = 8
#: Draws whose response is compared with the same draws halved: the input noise's share is
#: counted only where that response is proportional to the noise
#: (:mod:`gpjax._system_diagnose`).
SCALING_DRAWS = 2
#: Below this scaling (between 1, a response the noise moves as much at half the noise,
#: and 2, one it moves in proportion: the midpoint) the response is not a smooth function
#: of its input here, and the share is not counted.
PROPORTIONAL_FROM = 1.5


def _periodogram(values: np.ndarray) -> np.ndarray:
    """|FFT|² of the mean-removed values over bins 1 … N/2 − 1 (no DC, no Nyquist)."""
    spectrum = np.fft.rfft(values - np.mean(values))
    return np.abs(spectrum[1: (values.size - 1) // 2 + 1]) ** 2


def noise_floor(residual: np.ndarray, dt: float, band_hz: float) -> dict | None:
    """The residual's noise floor (module docstring): ``sigma`` (residual units),
    ``rms`` of the residual, ``ratio`` = rms/σ̂, ``band_hz``, ``p_excess`` (p-value of the
    in-band power under white noise at σ̂; a band of fewer than :data:`MIN_BINS` bins is
    widened to them), or ``None`` with fewer than :data:`MIN_BINS` bins above the band (a
    record too short) or a non-finite residual."""
    power = _periodogram(residual)
    if not np.all(np.isfinite(residual)) or power.size < 2 * MIN_BINS:
        return None
    frequency = np.arange(1, power.size + 1) / (residual.size * dt)
    band_hz = max(band_hz, frequency[MIN_BINS - 1])
    inside, outside = power[frequency <= band_hz], power[frequency > band_hz]
    if outside.size < MIN_BINS:
        return None
    density = float(np.median(outside)) / math.log(2.0)
    sigma = math.sqrt(density / residual.size)
    rms = float(np.sqrt(np.mean((residual - np.mean(residual)) ** 2)))
    p = float(special.gammaincc(inside.size, np.sum(inside) / density)) if density > 0 else 0.0
    return {"sigma": sigma, "rms": rms, "ratio": rms / sigma if sigma > 0 else math.inf,
            "band_hz": float(band_hz), "p_excess": p}


def input_noise_sigma(values: np.ndarray, dt: float, *, alpha: float = 0.05) -> float | None:
    """A measured input's white-noise σ (input units): the median of its Hann-windowed
    periodogram above its own band (:func:`signal_band_hz`) / ln 2, over the window's Σw²;
    ``None`` with fewer than :data:`MIN_BINS` bins above the band (a broadband drive). The
    window keeps the leakage of the drive's strong in-band lines out of those bins: unwindowed,
    the median overestimated σ by 20–33 % on multisine records at 20 and 100 Hz, windowed it
    was within 4 % (records outside the repository)."""
    band = signal_band_hz(values, dt, alpha=alpha)
    window = np.hanning(values.size)
    power = np.abs(np.fft.rfft((values - np.mean(values)) * window)) ** 2
    frequency = np.fft.rfftfreq(values.size, dt)
    above = power[(frequency > band) & (frequency < 0.5 / dt)]
    if above.size < MIN_BINS:
        return None
    return math.sqrt(float(np.median(above)) / math.log(2.0) / float(np.sum(window ** 2)))


def models_input_noise(evaluator, population) -> tuple[np.ndarray, np.ndarray]:
    """Per model and coordinate (P, D): the RMS of the simulated response's move when white
    noise at each measured input's floor (:func:`input_noise_sigma`) is added to the inputs,
    over :data:`INPUT_NOISE_DRAWS` seeded draws (the same record gives the same figures),
    each model simulated by ``evaluator`` (a :class:`gpjax._evaluator.PopulationEvaluator`:
    RK4 at its step count, from the population's initial states) with and without them; and
    the scaling of that move with the noise: its RMS over the first :data:`SCALING_DRAWS`
    draws against the same draws halved (2 where it is proportional, and where the noise
    does not move it at all). Both empty where no input has a floor or a response to a
    noisy input diverges."""
    measurement = evaluator.measurement
    sigmas = {name: input_noise_sigma(values, measurement.dt) or 0.0
              for name, values in measurement.inputs.items()}
    if not any(sigmas.values()):
        return np.zeros(0), np.zeros(0)
    clean = np.asarray(evaluator.simulate(population)[0])
    clean = clean.reshape(clean.shape[0], -1, clean.shape[-1])  # (P, D, N)

    def square(noise: dict, scale: float) -> np.ndarray:
        noisy = {name: values + scale * noise[name] for name, values in measurement.inputs.items()}
        basis = evaluator.forcing_basis_as(inputs=noisy)
        moved = np.asarray(evaluator.simulate(population, forcing_basis=basis)[0])
        return np.mean((moved.reshape(clean.shape) - clean) ** 2, axis=-1)

    rng = np.random.default_rng(0)
    draws = [{name: sigmas[name] * rng.standard_normal(values.size)
              for name, values in measurement.inputs.items()} for _ in range(INPUT_NOISE_DRAWS)]
    squares = np.array([square(noise, 1.0) for noise in draws])
    halved = np.array([square(noise, 0.5) for noise in draws[:SCALING_DRAWS]])
    if not (np.all(np.isfinite(squares)) and np.all(np.isfinite(halved))):
        return np.zeros(0), np.zeros(0)
    moved, moved_half = np.sum(squares[:SCALING_DRAWS], axis=0), np.sum(halved, axis=0)
    # a response the noise does not move at all (a model without its inputs) is proportional
    # to it, 0 = 2·0: its share is counted, as 0, not read as a chaotic response
    scaling = np.where((moved == 0) & (moved_half == 0), 2.0,
                       np.sqrt(moved / np.fmax(moved_half, 1e-300)))
    return np.sqrt(np.mean(squares, axis=0)), scaling


def signal_band_hz(values: np.ndarray, dt: float, *, alpha: float = 0.05) -> float:
    """The frequency (Hz) below which :data:`SPECTRAL_ENERGY_FRACTION` of the signal's AC
    energy lies, the signal being the bins significantly above the noise floor (median of
    the upper half of the bins / ln 2; level ``alpha``, Bonferroni over the bins): the band
    of a rate (a differenced drifting position) whose white noise would otherwise spread
    the band to the Nyquist frequency."""
    power = _periodogram(values)
    density = float(np.median(power[power.size // 2:])) / math.log(2.0)
    significant = power > density * math.log(power.size / alpha)
    excess = np.cumsum(np.where(significant, power, 0.0))
    if excess[-1] <= 0:
        return 0.5 / dt
    count = int(np.searchsorted(excess / excess[-1], SPECTRAL_ENERGY_FRACTION)) + 1
    return (count + 1) / (values.size * dt)


def input_lines_only(measurement: Measurement, *, alpha: float
                     ) -> tuple[Measurement, dict[str, dict]]:
    """``measurement`` with each input replaced by its significant spectral lines (module
    docstring), and per input what was done: the line frequencies (Hz), the noise ``sigma``
    removed (input units), ``denoised`` (false for a broadband input, left as measured)."""
    inputs, report = {}, {}
    for name, values in measurement.inputs.items():
        fitted, frequencies = lines(values, measurement.dt, alpha=alpha)
        denoised = fitted is not None
        inputs[name] = fitted if denoised else values
        report[name] = {"denoised": denoised, "lines_hz": frequencies,
                        "sigma": float(np.std(values - inputs[name]))}
    return measurement.with_inputs(inputs), report


def lines(values: np.ndarray, dt: float, *, alpha: float
           ) -> tuple[np.ndarray | None, list[float]]:
    """(mean + significant sinusoids fitted by least squares, their frequencies in Hz),
    found one at a time at the strongest peak of the remaining periodogram (zero-padded at
    least 8×, to a length the FFT is fast at: a record of 2 × a prime samples padded 8×
    took 100 ms an FFT, 5 ms padded to the next fast length) while that peak exceeds the
    noise floor at level ``alpha`` (Bonferroni over the padded bins, as the peak is sought
    on them);
    each new frequency, and at the end each in turn, refined within a bin by least squares.
    ``None`` where no line is significant, more than a quarter of the bins are, or more than
    :data:`MAX_LINES` lines (or a quarter of the bins) would be needed (a broadband input)."""
    n = values.size
    bins = (n - 1) // 2
    time, step = np.arange(n) * dt, 1.0 / (n * dt)  # step: one DFT bin, Hz

    def pair(frequency):
        angle = 2 * np.pi * frequency * time
        return np.column_stack([np.cos(angle), np.sin(angle)])

    def basis(frequencies):
        """An orthonormal basis (n, 1 + 2·lines) of the mean and ``frequencies``' lines."""
        return np.linalg.qr(np.column_stack([np.ones(n), *map(pair, frequencies)]))[0]

    def extended(q, frequency):
        """``q`` with the line at ``frequency`` added (Gram–Schmidt, twice for accuracy)."""
        new = pair(frequency)
        for _ in range(2):
            new = new - q @ (q.T @ new)
        return np.column_stack([q, np.linalg.qr(new)[0]])

    def refine(q, frequency):
        """The frequency of a line near ``frequency`` by least squares, the lines of ``q``
        (an orthonormal basis of the others) projected out."""
        rest = values - q @ (q.T @ values)

        def error(f):
            # |rest|² less what the line's columns, q projected out, explain: rest ⊥ q, so
            # their product with rest is the columns' own; their Gram matrix is
            # CᵀC − (qᵀC)ᵀ(qᵀC) (one pass over the samples, not three)
            columns = pair(f)
            inner = q.T @ columns
            gram = columns.T @ columns - inner.T @ inner
            product = columns.T @ rest
            return float(rest @ rest - product @ np.linalg.lstsq(gram, product, rcond=None)[0])
        low = max(frequency - step, step / 8)
        return float(minimize_scalar(error, method="bounded", bounds=(low, frequency + step),
                                     options={"xatol": 1e-3 * step}).x)

    power = _periodogram(values)
    threshold = math.log(bins / alpha) / math.log(2.0)  # × the median periodogram
    if np.count_nonzero(power > threshold * np.median(power)) > bins // 4:
        return None, []  # broadband: more significant bins than lines may hold
    padding = next_fast_len(8 * n, real=True)
    searched = bins * padding // n  # padded bins up to the last DFT bin tested
    frequencies: list[float] = []
    q = basis([])  # the mean and the lines found so far
    fitted = np.full(n, np.mean(values))
    while True:
        remaining = values - fitted
        if np.std(remaining) <= 1e-9 * np.std(values):  # exact lines: nothing left to find
            break
        density = float(np.median(_periodogram(remaining))) / math.log(2.0)
        padded = np.abs(np.fft.rfft(remaining, n=padding)) ** 2
        padded[:-(-padding // n)] = 0.0  # DC and its leakage (one DFT bin)
        peak = int(np.argmax(padded[:searched]))
        if density <= 0 or padded[peak] <= density * math.log(searched / alpha):
            break
        if len(frequencies) >= min(bins // 8, MAX_LINES):  # 2 columns per line
            return None, []
        frequencies.append(refine(q, peak / (padding * dt)))
        q = extended(q, frequencies[-1])
        fitted = q @ (q.T @ values)
    if not frequencies:
        return None, []  # no line: not a sum of lines
    for k in range(len(frequencies)):
        frequencies[k] = refine(basis(frequencies[:k] + frequencies[k + 1:]), frequencies[k])
    q = basis(frequencies)
    return q @ (q.T @ values), frequencies
