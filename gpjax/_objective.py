"""The objective of eqs. 7–9 and the amplitude spectra it compares.

f_time (eq. 8) is the Euclidean norm of the residual; f_freq (eq. 9) the sum of absolute
differences of the single-sided amplitude spectra over the first m DFT bins, where m holds
99 % of the measured response's AC spectral energy (:func:`default_n_bins`). The
population evaluator takes the bins of a record padded to its length bucket by a chirp-z
transform (:func:`chirp_z`), whose arrays depend on the record only as data.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

#: Fraction of the measured response's AC spectral energy the default m bins hold.
SPECTRAL_ENERGY_FRACTION = 0.99


def objective_parts(measured: jax.Array, calculated: jax.Array, n_bins: int):
    """f_time (eq. 8), f_freq (eq. 9) and the RMS error along axis 0.

    f_freq compares single-sided amplitude spectra |X_j|·2/N (DC, and the Nyquist bin of
    an even N: |X_j|/N) of the first ``n_bins`` DFT bins, j = 0 … m−1, from an rfft (the
    reference; the population evaluator computes the same bins of a padded record by
    :func:`chirp_z`).
    """
    n = measured.shape[0]
    weight = jnp.asarray(_bin_weights(n, n_bins)).reshape((-1,) + (1,) * (measured.ndim - 1))

    def amplitude(signal):
        return weight * jnp.abs(jnp.fft.rfft(signal, axis=0)[:n_bins])

    residual = measured - calculated
    f_time = jnp.sqrt(jnp.sum(residual ** 2, axis=0))
    f_freq = jnp.sum(jnp.abs(amplitude(measured) - amplitude(calculated)), axis=0)
    return f_time, f_freq, f_time / np.sqrt(n)


def _bin_weights(n: int, n_bins: int) -> np.ndarray:
    """(n_bins,) weights of eq. 9's amplitudes for N samples: 2/N, DC and Nyquist 1/N."""
    weight = np.full(n_bins, 2.0 / n)
    weight[0] = 1.0 / n
    if n % 2 == 0 and n_bins > n // 2:
        weight[n // 2] = 1.0 / n
    return weight


def chirp_z(n: int, n_padded: int, n_bins: int) -> dict[str, np.ndarray]:
    """The arrays by which :func:`chirp_z_amplitude` gives eq. 9's amplitudes of the first
    N of ``n_padded`` samples at the DFT bins j/N, j < n_padded // 2 + 1 (zero weight
    from ``n_bins`` on), with FFTs whose length depends on ``n_padded`` alone.

    Bluestein's algorithm: with jk = (j² + k² − (j − k)²)/2,
    X_j = c_j · Σ_k (x_k c_k) · conj(c_(j−k)), c_k = exp(−iπk²/N), a convolution done by FFTs
    of length L ≥ N' + m' − 1 (the next 5-smooth number). O(N log N) time and memory per
    signal; no (m × N) DFT matrix. The phases are reduced modulo 2π exactly (k² mod 2N in
    integers), so the bins agree with an rfft to rounding (tested).

    Returns:
        ``chirp`` (N',) c_k for k < N, 0 past N (the padding drops out); ``kernel`` (L,)
        the FFT of conj(c) laid out for the circular convolution; ``post`` (m',) c_j times
        the bin weights (:func:`_bin_weights`, zero from ``n_bins`` on).
    """
    bins = n_padded // 2 + 1
    length = _five_smooth(n_padded + bins - 1)

    def phase(k):
        return np.exp(-1j * np.pi * ((k.astype(np.int64) ** 2) % (2 * n)) / n)

    k = np.arange(n_padded)
    lags = np.arange(-(n_padded - 1), bins)
    kernel = np.zeros(length, dtype=complex)
    kernel[lags % length] = np.conj(phase(lags))
    weight = np.zeros(bins)
    weight[:n_bins] = _bin_weights(n, n_bins)
    return {"chirp": np.where(k < n, phase(k), 0.0), "kernel": np.fft.fft(kernel),
            "post": phase(np.arange(bins)) * weight}


def chirp_z_amplitude(spectrum, signal):
    """(m', …) weighted amplitudes of ``signal`` (N', …; samples first, any trailing axes)
    from the arrays of :func:`chirp_z` (``spectrum``: ``chirp``, ``kernel``, ``post``)."""
    extra = (1,) * (signal.ndim - 1)
    length, bins = spectrum["kernel"].shape[0], spectrum["post"].shape[0]
    product = jnp.fft.fft(signal * spectrum["chirp"].reshape((-1,) + extra), n=length, axis=0)
    convolved = jnp.fft.ifft(product * spectrum["kernel"].reshape((-1,) + extra), axis=0)
    return jnp.abs(convolved[:bins] * spectrum["post"].reshape((-1,) + extra))


def _objective_parts(measured, calculated, spectrum, amplitude_measured, *, count):
    """f_time, f_freq and the RMS of a padded record (:mod:`gpjax._record`): ``measured``
    and ``calculated`` (N', …) with a zero residual past the record's ``count`` samples,
    ``amplitude_measured`` the measured amplitudes (m', …), ``spectrum`` from
    :func:`chirp_z`."""
    residual = measured - calculated
    f_time = jnp.sqrt(jnp.sum(residual ** 2, axis=0))
    f_freq = jnp.sum(jnp.abs(amplitude_measured - chirp_z_amplitude(spectrum, calculated)),
                     axis=0)
    return f_time, f_freq, f_time / jnp.sqrt(count)


def _five_smooth(n: int) -> int:
    """The smallest number ≥ ``n`` with no prime factor above 5 (a fast FFT length)."""
    while True:
        rest = n
        for prime in (2, 3, 5):
            while rest % prime == 0:
                rest //= prime
        if rest == 1:
            return n
        n += 1


def amplitude_spectrum(signal: np.ndarray) -> np.ndarray:
    """Single-sided amplitude spectrum |X_j|·2/N (DC and Nyquist |X|/N) via numpy's rfft."""
    n = signal.size
    return np.abs(np.fft.rfft(signal)) * _bin_weights(n, n // 2 + 1)


def default_n_bins(response: np.ndarray) -> int:
    """Smallest m whose bins (DC included) hold 99 % of the response's AC spectral energy.

    Bins above that carry less than 1 % of the oscillation energy, mostly noise, which would
    add a model-independent floor to f_freq; DC is always included (bin 0).
    """
    energy = amplitude_spectrum(response)[1:] ** 2
    total = energy.sum()
    if total == 0:
        return 1
    count = int(np.searchsorted(np.cumsum(energy) / total, SPECTRAL_ENERGY_FRACTION)) + 1
    return 1 + count


