"""Equation-error least squares: coefficients of a structure straight from the data.

Given x, x', x'' estimated from the smoothed measurement (Savitzky–Golay, scipy), the
canonical form ``m·x'' + Σ c·φ(x, x') − Σ g·ψ(t, u) = 0`` is linear in (m, c, g). Fixing
the first input's forcing coefficient to 1 (or m = 1 without it) leaves an ordinary linear
least-squares problem. This is GP's coefficient setter (``coefficients="least_squares"``)
and the start of the output-error refinement; it needs no hand-set intervals or scaling.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import sympy as sp
from scipy.signal import savgol_filter

from ._canonical import Symbols
from ._data import Measurement

POLYORDER = 4


@dataclasses.dataclass(frozen=True)
class Derivatives:
    """Smoothed response and its first two derivatives at the sample times."""

    x: np.ndarray
    x_dot: np.ndarray
    x_ddot: np.ndarray
    window: int


def savgol_window(measurement: Measurement, cutoff_hz: float) -> int:
    """Odd Savitzky–Golay window whose −3 dB frequency is ~2× ``cutoff_hz``.

    Uses Schafer's (2011) approximation f_3dB/fs ≈ (p+1)/(3.2·w − 4.6) for order p = 4.
    """
    fs = 1.0 / measurement.dt
    window = ((POLYORDER + 1) * fs / (2.0 * max(cutoff_hz, 1e-12)) + 4.6) / 3.2
    window = int(np.clip(window, POLYORDER + 3, max(POLYORDER + 3, measurement.n_samples // 4)))
    return window if window % 2 else window + 1


def smoothed_derivatives(measurement: Measurement, cutoff_hz: float) -> Derivatives:
    """x, x', x'' from a Savitzky–Golay filter that keeps frequencies up to ~``cutoff_hz``."""
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


def test_functions(n_samples: int, half_width: int, dt: float
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weak-form test functions ψ_k(t) = (1 − s²)^4 on windows of ±``half_width`` samples.

    Windows are centred every ``half_width // 2`` samples. Returns the quadrature-weighted
    matrices (K, N) of ψ, ψ' and ψ'' (each row times a sampled signal and summed is the
    integral of that product); ψ and ψ' vanish at the window ends, so integration by parts
    has no boundary terms.
    """
    half_width = max(2, min(half_width, (n_samples - 1) // 2))
    step = max(1, half_width // 2)
    centres = np.arange(half_width, n_samples - half_width, step)
    offsets = np.arange(-half_width, half_width + 1)
    s = offsets / half_width
    scale = half_width * dt  # ds/dt = 1/scale
    psi = (1 - s**2) ** 4
    dpsi = -8 * s * (1 - s**2) ** 3 / scale
    ddpsi = (-8 * (1 - s**2) ** 3 + 48 * s**2 * (1 - s**2) ** 2) / scale**2
    matrices = []
    for values in (psi, dpsi, ddpsi):
        matrix = np.zeros((centres.size, n_samples))
        for k, c in enumerate(centres):
            matrix[k, c - half_width:c + half_width + 1] = values * dt
        matrices.append(matrix)
    return tuple(matrices)


class EquationError:
    """Solves the weak-form equation-error least-squares problem for any structure.

    Each row integrates the canonical form against one test function ψ_k (see
    :func:`test_functions`): ``m·∫ψ_k''·x + Σ c·∫ψ_k·φ(x, x') − Σ g·∫ψ_k·ψ(t, u) = 0``,
    with ``∫ψ_k·x' = −∫ψ_k'·x``. No second derivative of the noisy response is needed;
    nonlinear features of x' use the smoothed derivative.

    Args:
        measurement: the data.
        symbols: names of response, time and inputs.
        derivatives: smoothed x, x', x'' (see :func:`smoothed_derivatives`).
        half_width: test-function half width in samples (default: the smoothing window).
    """

    def __init__(self, measurement: Measurement, symbols: Symbols, derivatives: Derivatives,
                 *, half_width: int | None = None):
        self.measurement = measurement
        self.symbols = symbols
        self.derivatives = derivatives
        self._psi, self._dpsi, self._ddpsi = test_functions(
            measurement.n_samples, half_width or derivatives.window, measurement.dt)
        self._columns: dict[sp.Expr, np.ndarray] = {}

    def column(self, feature: sp.Expr) -> np.ndarray:
        """∫ψ_k·feature for every test function k (cached)."""
        if feature not in self._columns:
            s, d, m = self.symbols, self.derivatives, self.measurement
            if feature == s.x_dot:
                self._columns[feature] = -self._dpsi @ m.response
            else:
                args = (s.x, s.x_dot, s.t, *s.u)
                values = sp.lambdify(args, feature, modules="numpy")(
                    m.response, d.x_dot, m.time, *m.inputs.values())
                values = np.broadcast_to(np.asarray(values, dtype=np.float64), m.time.shape)
                self._columns[feature] = self._psi @ values
        return self._columns[feature]

    def solve(self, state: tuple[sp.Expr, ...], forcing: tuple[sp.Expr, ...]
              ) -> tuple[float, np.ndarray, np.ndarray]:
        """Least-squares (mass, state coefficients, forcing coefficients) for a structure.

        The first input's linear forcing coefficient is fixed to 1 if that feature is in
        ``forcing``; otherwise the mass is fixed to 1.
        """
        acceleration = self._ddpsi @ self.measurement.response
        u0 = self.symbols.u[0] if self.symbols.u else None
        normalise_input = u0 is not None and u0 in forcing
        columns = [acceleration] if normalise_input else []
        columns += [self.column(f) for f in state]
        columns += [-self.column(f) for f in forcing if not (normalise_input and f == u0)]
        target = self.column(u0) if normalise_input else -acceleration
        if columns:
            matrix = np.stack(columns, axis=1)
            scale = np.linalg.norm(matrix, axis=0)
            scale[scale == 0] = 1.0
            solution, *_ = np.linalg.lstsq(matrix / scale, target, rcond=None)
            solution = solution / scale
        else:
            solution = np.zeros(0)
        k = 0
        if normalise_input:
            mass, k = float(solution[0]), 1
        else:
            mass = 1.0
        state_coefficients = solution[k:k + len(state)]
        k += len(state)
        rest = iter(solution[k:])
        forcing_coefficients = np.array(
            [1.0 if normalise_input and f == u0 else float(next(rest)) for f in forcing])
        return mass, np.asarray(state_coefficients, dtype=np.float64), forcing_coefficients
