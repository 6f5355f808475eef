"""The objective of eqs. 7–9 and the amplitude spectra it compares.

f_time (eq. 8) is the Euclidean norm of the residual; f_freq (eq. 9) the sum of absolute
differences of the single-sided amplitude spectra over the first m DFT bins, where m holds
99 % of the measured response's AC spectral energy (:func:`default_n_bins`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

#: Fraction of the measured response's AC spectral energy the default m bins hold.
SPECTRAL_ENERGY_FRACTION = 0.99


def objective_parts(measured: jax.Array, calculated: jax.Array, n_bins: int):
    """f_time (eq. 8), f_freq (eq. 9) and the RMS error along axis 0.

    f_freq compares single-sided amplitude spectra |X_j|·2/N (DC: |X_0|/N) of the first
    ``n_bins`` DFT bins, j = 0 … m−1, computed as a DFT-matrix product.
    """
    dft = jnp.asarray(_dft_matrix(measured.shape[0], n_bins))
    return _objective_parts(measured, calculated, dft, _amplitude(dft, measured, n_bins), n_bins)


def _objective_parts(measured, calculated, dft, amplitude_measured, n_bins, *, count=None):
    """:func:`objective_parts` from a DFT matrix and the measured amplitudes; ``count``:
    the samples the RMS is taken over (default all; a padded record's residual is zero
    past them)."""
    residual = measured - calculated
    f_time = jnp.sqrt(jnp.sum(residual ** 2, axis=0))
    rms = f_time / (np.sqrt(measured.shape[0]) if count is None else jnp.sqrt(count))
    f_freq = jnp.sum(jnp.abs(amplitude_measured - _amplitude(dft, calculated, n_bins)), axis=0)
    return f_time, f_freq, rms


#: Largest DFT matrix (elements, 2m·N) used; above it the amplitudes come from an FFT.
DFT_MATRIX_LIMIT = 4_000_000


def _amplitude(dft, signal, n_bins: int, xp=jnp):
    """(m, …) amplitudes of the first m bins of ``signal`` (N, …): samples first, any
    trailing axes (models; coordinates and models); ``xp`` the array module (numpy for a
    record's own spectrum outside a program: an eager JAX product compiles itself in every
    process, 0.4 s of a warm ``gpjax demo``).

    With a DFT matrix: one (2m, N) @ (N, P) product, weighted cos rows over weighted sin
    rows (4mN flops per model; faster than an FFT on CPU for m = 58, N = 1,334). With
    ``dft`` of shape (1, m) — the weights only, see :func:`_dft_matrix` — an rfft, whose
    cost and memory do not grow with m.
    """
    if dft.shape[0] == 1:
        weight = dft[0, :n_bins].reshape((-1,) + (1,) * (signal.ndim - 1))
        return weight * xp.abs(xp.fft.rfft(signal, axis=0)[:n_bins])
    parts = xp.tensordot(dft, signal, axes=1)
    return xp.hypot(parts[:n_bins], parts[n_bins:])


def _dft_matrix(n: int, n_bins: int) -> np.ndarray:
    """(2m, N) rows w_j·cos(2πjk/N) then w_j·sin(2πjk/N), w = 2/N (DC, Nyquist: 1/N);
    above :data:`DFT_MATRIX_LIMIT` elements only the weights, shape (1, m)."""
    if 2 * n_bins * n > DFT_MATRIX_LIMIT:
        weight = np.full(n_bins, 2.0 / n)
        weight[0] = 1.0 / n
        if n % 2 == 0 and n_bins > n // 2:
            weight[n // 2] = 1.0 / n
        return weight[None, :]
    j = np.arange(n_bins)[:, None]
    k = np.arange(n)[None, :]
    angle = 2 * np.pi * ((j * k) % n) / n
    weight = np.full((n_bins, 1), 2.0 / n)
    weight[0] = 1.0 / n
    if n % 2 == 0 and n_bins > n // 2:
        weight[n // 2] = 1.0 / n
    return np.concatenate([weight * np.cos(angle), weight * np.sin(angle)])


def amplitude_spectrum(signal: np.ndarray) -> np.ndarray:
    """Single-sided amplitude spectrum |X_j|·2/N (DC and Nyquist |X|/N) via numpy's rfft."""
    n = signal.size
    amplitude = np.abs(np.fft.rfft(signal)) * 2.0 / n
    amplitude[0] /= 2.0
    if n % 2 == 0:
        amplitude[-1] /= 2.0
    return amplitude


def stop_objective(measurement, config) -> float:
    """The objective below which a run stops (stop rule 2, eq. 12): ``config.epsilon`` ×
    f_0, where f_0 is eq. 7 for the constant model at each response's mean — its f_time
    the response's deviation from the mean, its f_freq the AC amplitudes of the first m
    bins — with the coordinates weighted as in the objective (s_1/s_d). The paper's
    ε = 0.01 is absolute, in its record's units; relative to f_0 the rule means the same on
    a record in rad, m, mm or V (absolute, a record in metres of 1 µm stopped at
    generation 0 with a model 29 % off)."""
    responses = measurement.responses
    deviation = responses - responses.mean(axis=0)
    n_bins = config.n_bins or max(map(default_n_bins, responses.T))
    n_bins = min(n_bins, measurement.n_samples // 2 + 1)
    weights = np.std(responses[:, 0]) / np.where(responses.std(axis=0) > 0,
                                                 responses.std(axis=0), 1.0)
    parts = [config.w_time * np.linalg.norm(d)
             + config.w_freq * float(np.sum(amplitude_spectrum(d)[1:n_bins]))
             for d in deviation.T]
    return config.epsilon * float(np.dot(weights, parts))


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


