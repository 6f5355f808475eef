"""Weak-form equation error: derivatives, window integrals and the least-squares solve.

Given x, x' and x'' estimated from the smoothed measurement (Savitzky–Golay, scipy), the
canonical form ``m·x'' + Σ c·φ(x, x') − Σ g·ψ(t, u) = 0`` is linear in (m, c, g).
Integrated against compact test functions ψ_k = (1 − s²)^4 it needs no second derivative
of the noisy response (``∫ψ_k·x'' = ∫ψ_k''·x``, ``∫ψ_k·x' = −∫ψ_k'·x``). Fixing the first
input's forcing coefficient to 1 (or m = 1 without it) leaves an ordinary linear
least-squares problem: GP's coefficient setter (``coefficients="least_squares"``), the
start of every output-error refinement and the diagnosis's evidence.

Memory and time are O(N): window k covers samples ``c_k ± h``, centres every h//2 samples,
so each sample lies in about four windows, and each integral is a dot product of a
strided view of the samples (no copy of the N-sample record per window) with the kernel.
"""

from __future__ import annotations

import dataclasses
from functools import lru_cache

import numpy as np
import sympy as sp
from numpy.lib.stride_tricks import sliding_window_view
from scipy.signal import savgol_filter

from ._canonical import Symbols
from ._data import Measurement
from ._objective import default_n_bins

POLYORDER = 4


@dataclasses.dataclass(frozen=True)
class Derivatives:
    """Smoothed response and its first two derivatives at the sample times."""

    x: np.ndarray
    x_dot: np.ndarray
    x_ddot: np.ndarray
    window: int

    @property
    def initial_state(self) -> tuple[float, float]:
        """(x, x') at the first sample: eq. 13's robust estimate of the initial state."""
        return float(self.x[0]), float(self.x_dot[0])


def savgol_window(measurement: Measurement, cutoff_hz: float) -> int:
    """Odd Savitzky–Golay window whose −3 dB frequency is ~2× ``cutoff_hz``.

    Uses Schafer's (2011) approximation f_3dB/fs ≈ (p+1)/(3.2·w − 4.6) for order p = 4.
    """
    fs = 1.0 / measurement.dt
    window = ((POLYORDER + 1) * fs / (2.0 * max(cutoff_hz, 1e-12)) + 4.6) / 3.2
    window = int(np.clip(window, POLYORDER + 3, max(POLYORDER + 3, measurement.n_samples // 4)))
    return window if window % 2 else window + 1


def smoothing_cutoff_hz(measurement: Measurement, n_bins: int | None = None) -> float:
    """Frequency (Hz) of DFT bin ``n_bins`` (default: the bins holding 99 % of the
    response's AC energy, :func:`gpjax._objective.default_n_bins`): the band the
    derivative estimates keep."""
    if n_bins is None:
        n_bins = default_n_bins(measurement.response)
    return n_bins / (measurement.n_samples * measurement.dt)


def estimate_initial_conditions(measurement: Measurement) -> tuple[float, float]:
    """(x, x') at the first sample from the smoothed response (eq. 13's robust estimate)."""
    return smoothed_derivatives(measurement).initial_state


def smoothed_derivatives(measurement: Measurement, cutoff_hz: float | None = None
                         ) -> Derivatives:
    """x, x', x'' from a Savitzky–Golay filter that keeps frequencies up to ~``cutoff_hz``
    (default :func:`smoothing_cutoff_hz`)."""
    if cutoff_hz is None:
        cutoff_hz = smoothing_cutoff_hz(measurement)
    largest_odd = measurement.n_samples - 1 if measurement.n_samples % 2 == 0 else (
        measurement.n_samples - 2)
    window = min(savgol_window(measurement, cutoff_hz), largest_odd)
    dt = measurement.dt
    y = measurement.response
    return Derivatives(
        x=savgol_filter(y, window, POLYORDER, deriv=0, delta=dt, mode="interp"),
        x_dot=savgol_filter(y, window, POLYORDER, deriv=1, delta=dt, mode="interp"),
        x_ddot=savgol_filter(y, window, POLYORDER, deriv=2, delta=dt, mode="interp"),
        window=window)


class WeakForm:
    """Weak-form integrals ∫ψ_k·f dt for test functions ψ_k = (1 − s²)^4 of half width h.

    Windows span ±h samples around centres h, h + h//2, … < N − h; ψ and ψ' vanish at the
    window ends, so integration by parts has no boundary terms.

    Args:
        measurement: the data.
        symbols: names of response, time and inputs.
        x_dot: smoothed x' at the samples (for features nonlinear in x').
        half_width: h in samples (clipped to 2 … (N − 1)/2).
        excluded: samples (N,) bool whose windows are left out (e.g. a stage at rest,
            where dry friction is set-valued); default none.
    """

    def __init__(self, measurement: Measurement, symbols: Symbols, x_dot: np.ndarray,
                 half_width: int, *, excluded: np.ndarray | None = None):
        self.measurement, self.symbols, self.x_dot = measurement, symbols, x_dot
        self.u0 = symbols.u[0] if symbols.u else None
        h = max(2, min(half_width, (measurement.n_samples - 1) // 2))
        self.half_width, self.step = h, max(1, h // 2)
        s = np.arange(-h, h + 1) / h
        scale, dt = h * measurement.dt, measurement.dt
        self._kernels = ((1 - s ** 2) ** 4 * dt, -8 * s * (1 - s ** 2) ** 3 / scale * dt,
                         (-8 * (1 - s ** 2) ** 3 + 48 * s ** 2 * (1 - s ** 2) ** 2)
                         / scale ** 2 * dt)
        self.centres = np.arange(h, measurement.n_samples - h, self.step)
        self._kept = (None if excluded is None else
                      ~self._windows(np.asarray(excluded, dtype=bool)).any(axis=1))
        if self._kept is not None:
            self.centres = self.centres[self._kept]
        self.kernel_area = float(np.sum(self._kernels[0]))
        self._cache: dict[sp.Expr, np.ndarray] = {}

    def _windows(self, values: np.ndarray) -> np.ndarray:
        """(K, 2h + 1) strided windows of ``values`` (a view), all centres."""
        count = np.arange(self.half_width, self.measurement.n_samples - self.half_width,
                          self.step).size
        return sliding_window_view(values, 2 * self.half_width + 1)[:: self.step][:count]

    def _integrate(self, values: np.ndarray, kernel: int) -> np.ndarray:
        """(K,) window integrals of the kept windows: strided windows times the kernel."""
        with np.errstate(invalid="ignore", over="ignore"):  # a candidate's overflow: data
            integrals = self._windows(values) @ self._kernels[kernel]
        return integrals if self._kept is None else integrals[self._kept]

    def acceleration(self) -> np.ndarray:
        """∫ψ_k''·x: the inertia column (no derivative of the data needed; cached, as every
        column is: every least-squares problem of the run has it)."""
        return self.column(self.symbols.x_ddot)

    def column(self, feature: sp.Expr) -> np.ndarray:
        """∫ψ_k·feature(x, x', x'', t, u) for every window (cached); x' and x'' are
        integrated by parts against the measured x."""
        if feature not in self._cache:
            if feature == self.symbols.x_ddot:
                self._cache[feature] = self._integrate(self.measurement.response, 2)
            elif feature == self.symbols.x_dot:
                self._cache[feature] = -self._integrate(self.measurement.response, 1)
            else:
                self._cache[feature] = self._integrate(
                    evaluate(feature, self.symbols, self.measurement, self.measurement.response,
                             self.x_dot), 0)
        return self._cache[feature]


def evaluate(feature: sp.Expr, symbols: Symbols, measurement: Measurement, x: np.ndarray,
             x_dot: np.ndarray) -> np.ndarray:
    """A feature's values at the samples, given x and x' (numpy)."""
    fn = _lambdified(feature, symbols)
    # A candidate's feature may overflow (exp(150·x')); the non-finite values make its
    # least squares NaN (:func:`scaled_lstsq`), so the candidate scores as diverged.
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        values = fn(x, x_dot, measurement.time,
                    *(measurement.inputs[name] for name in symbols.inputs))
    return np.broadcast_to(np.asarray(values, dtype=np.float64), x.shape).copy()


@lru_cache(maxsize=4096)
def _lambdified(feature: sp.Expr, symbols: Symbols):
    return sp.lambdify((symbols.x, symbols.x_dot, symbols.t, *symbols.u), feature,
                       modules="numpy")


def design(weak: WeakForm, lhs: tuple[sp.Expr, ...], forcing: tuple[sp.Expr, ...]
           ) -> tuple[np.ndarray, np.ndarray, bool]:
    """(matrix (K, p), target (K,), normalise) of the least-squares problem for left-hand
    side features ``lhs`` (state and parametric) and ``forcing`` features. ``normalise``:
    the first input is in ``forcing`` (its coefficient is 1; the first unknown is the
    mass); otherwise the mass is 1."""
    u0 = weak.u0
    acceleration = weak.acceleration()
    normalise = u0 is not None and u0 in forcing
    columns = [acceleration] if normalise else []
    columns += [weak.column(f) for f in lhs]
    columns += [-weak.column(g) for g in forcing if not (normalise and g == u0)]
    target = weak.column(u0) if normalise else -acceleration
    matrix = np.stack(columns, axis=1) if columns else np.zeros((target.size, 0))
    return matrix, target, normalise


def least_squares(weak: WeakForm, lhs: tuple[sp.Expr, ...], forcing: tuple[sp.Expr, ...]
                  ) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """Weak-form least-squares constants: (mass, ``lhs`` coefficients, ``forcing``
    coefficients, solution vector of :func:`design`'s problem), columns scaled to unit norm
    for the solve. The first input's coefficient is 1 if present, else the mass is 1."""
    matrix, target, normalise = design(weak, lhs, forcing)
    solution = scaled_lstsq(matrix, target)
    k = 1 if normalise else 0
    mass = float(solution[0]) if normalise else 1.0
    coefficients = solution[k:k + len(lhs)]
    rest = iter(solution[k + len(lhs):])
    forcing_coefficients = np.array([1.0 if normalise and g == weak.u0 else float(next(rest))
                                     for g in forcing])
    return mass, coefficients, forcing_coefficients, solution


def least_squares_residual(weak: WeakForm, lhs: tuple[sp.Expr, ...],
                           forcing: tuple[sp.Expr, ...]) -> float:
    """Norm of the weak-form least-squares residual of a structure (how much of the data
    its features leave unexplained), in the weak form's units."""
    matrix, target, _ = design(weak, lhs, forcing)
    return float(np.linalg.norm(target - matrix @ scaled_lstsq(matrix, target)))


def scaled_lstsq(matrix: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Least-squares solution with columns scaled to unit norm for the solve; NaN where a
    column or the target is not finite (the structure then scores as diverged)."""
    if not matrix.shape[1]:
        return np.zeros(0)
    if not (np.all(np.isfinite(matrix)) and np.all(np.isfinite(target))):
        return np.full(matrix.shape[1], np.nan)
    with np.errstate(over="ignore"):  # a column beyond 1e154: its norm is inf, its share 0
        scale = np.linalg.norm(matrix, axis=0)
    scale[scale == 0] = 1.0
    return np.linalg.lstsq(matrix / scale, target, rcond=None)[0] / scale
