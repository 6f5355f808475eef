"""Weak-form equation error: derivatives, window integrals and the least-squares solve,
for any number of coordinates.

Given x, x' and x'' estimated from the smoothed measurement (Savitzky–Golay, scipy), the
canonical form ``m·x'' + Σ c·φ(x, x') − Σ g·ψ(t, u) = 0`` is linear in (m, c, g); a
system's equation i (eqs. 21–22) is, in m_i and its own c and g, with features of every
coordinate. Integrated against compact test functions ψ_k = (1 − s²)^4 it needs no second
derivative of the noisy response (``∫ψ_k·x'' = ∫ψ_k''·x``, ``∫ψ_k·x' = −∫ψ_k'·x``). Holding
one forcing coefficient (one coordinate: the first input's, at 1) or the mass at 1 leaves
an ordinary linear least-squares problem: GP's coefficient setter
(``coefficients="least_squares"``), the start of every output-error refinement, the
selection's held-out test and the diagnosis's evidence, for one coordinate and for
systems alike (:class:`WeakForm`, :func:`design`).

The features nonlinear in the states are evaluated on state estimates the caller chooses:
one coordinate's fit and selection take the measured x (and the smoothed or simulated x'),
a system's the smoothed x_i and x_i' of every coordinate (:func:`smoothed_weak_form`).

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

from ._data import Measurement
from ._objective import SPECTRAL_ENERGY_FRACTION, amplitude_spectrum, default_n_bins

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
    """Weak-form integrals ∫ψ_k·f dt for test functions ψ_k = (1 − s²)^4 of half width h,
    for a record of D ≥ 1 coordinates (one set of windows serves every equation).

    Windows span ±h samples around centres h, h + h//2, … < N − h; ψ and ψ' vanish at the
    window ends, so integration by parts has no boundary terms. A feature linear in the
    states (x_i, x_i', x_i'' and their differences, e.g. a coupling's x_1' − x_2') is
    integrated exactly against the measured positions (∫ψ·x' = −∫ψ'·x, ∫ψ·x'' = ∫ψ''·x):
    no estimate of a derivative enters its column. Any other feature is evaluated on the
    state estimates given (``positions``, ``velocities``) and integrated.

    Args:
        measurement: the data (D coordinates).
        velocities: x_i' estimates at the samples (N,) or (N, D), units of x per second,
            for the features nonlinear in them (e.g. smoothed, or a model's simulated
            velocity).
        half_width: h in samples (clipped to 2 … (N − 1)/2).
        positions: x_i estimates (N,) or (N, D) for the features nonlinear in them;
            default the measured responses.
        excluded: samples (N,) bool whose windows are left out (e.g. a stage at rest,
            where dry friction is set-valued); default none.
    """

    def __init__(self, measurement: Measurement, velocities: np.ndarray, half_width: int, *,
                 positions: np.ndarray | None = None, excluded: np.ndarray | None = None):
        self.measurement = measurement
        n, count = measurement.n_samples, measurement.n_coordinates
        self.positions = np.reshape(measurement.responses if positions is None else positions,
                                    (n, count))
        self.velocities = np.reshape(velocities, (n, count))
        self.u0 = sp.Symbol(measurement.input_names[0]) if measurement.input_names else None
        self._states = {sp.Symbol(name + suffix): (d, order)
                        for d, name in enumerate(measurement.response_names)
                        for order, suffix in enumerate(("", "_dot", "_ddot"))}
        h = max(2, min(half_width, (n - 1) // 2))
        self.half_width, self.step = h, max(1, h // 2)
        s = np.arange(-h, h + 1) / h
        scale, dt = h * measurement.dt, measurement.dt
        self._kernels = ((1 - s ** 2) ** 4 * dt, -8 * s * (1 - s ** 2) ** 3 / scale * dt,
                         (-8 * (1 - s ** 2) ** 3 + 48 * s ** 2 * (1 - s ** 2) ** 2)
                         / scale ** 2 * dt)
        self.centres = np.arange(h, n - h, self.step)
        self._kept = (None if excluded is None else
                      ~self._windows(np.asarray(excluded, dtype=bool)).any(axis=1))
        if self._kept is not None:
            self.centres = self.centres[self._kept]
        self.kernel_area = float(np.sum(self._kernels[0]))
        self._cache: dict[sp.Expr, np.ndarray] = {}

    @property
    def rows(self) -> int:
        """Test-function windows (rows of every equation's least squares)."""
        return self.centres.size

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

    def acceleration(self, equation: int = 0) -> np.ndarray:
        """∫ψ_k''·x_i of coordinate ``equation``: its inertia column (exact; cached, as
        every column is: every least-squares problem of the run has it)."""
        name = self.measurement.response_names[equation]
        return self.column(sp.Symbol(f"{name}_ddot"))

    def column(self, feature: sp.Expr) -> np.ndarray:
        """∫ψ_k·feature(states, t, u) for every window (cached; class docstring)."""
        if feature not in self._cache:
            linear = self._linear(feature)
            if linear is None:
                column = self._integrate(self.values(feature), 0)
            else:  # by parts against the measured positions, one derivative order at a time
                column = None
                for order, samples in linear.items():
                    part = self._integrate(samples, order) * (-1.0 if order == 1 else 1.0)
                    column = part if column is None else column + part
            self._cache[feature] = column
        return self._cache[feature]

    def _linear(self, feature: sp.Expr) -> dict[int, np.ndarray] | None:
        """{derivative order: Σ a_i·x_i (N,) measured} of a feature linear in the states
        without a constant term; ``None`` for any other feature."""
        symbols = feature.free_symbols
        if not symbols or not symbols <= self._states.keys():
            return None
        if feature in self._states:
            terms = {feature: 1.0}
        else:
            if not feature.is_polynomial(*symbols):
                return None
            poly = sp.Poly(feature, *symbols)
            if poly.total_degree() != 1 or poly.coeff_monomial(1):
                return None
            terms = {s: float(poly.coeff_monomial(s)) for s in symbols}
        measured = self.measurement.responses
        out: dict[int, np.ndarray] = {}
        for symbol, coefficient in terms.items():
            d, order = self._states[symbol]
            samples = coefficient * measured[:, d]
            out[order] = samples if order not in out else out[order] + samples
        return {order: np.ascontiguousarray(v) for order, v in sorted(out.items())}

    def values(self, expression: sp.Expr) -> np.ndarray:
        """(N,) a function of the states, time and inputs at the samples, on the state
        estimates (:func:`evaluate`)."""
        return evaluate(expression, self.measurement, self.positions, self.velocities)

    def rms(self, expression: sp.Expr) -> float:
        """RMS of a function of the states on the state estimates."""
        return float(np.sqrt(np.mean(np.square(self.values(expression)))))

    def initial_state(self, equation: int) -> tuple[float, float]:
        """(x_i, x_i') of coordinate ``equation`` at the first sample, from the state
        estimates (eq. 13's robust estimate where they are smoothed)."""
        return float(self.positions[0, equation]), float(self.velocities[0, equation])


def system_band_hz(measurement: Measurement) -> float:
    """The band (Hz) a system's smoothed states keep: the widest of the bands holding
    99 % of the signal energy above the noise floor (:func:`signal_band_bins`) of each
    coordinate x_i and each relative coordinate x_i − x_j. Both are terminals of the
    search, and a power of x_i − x_j is evaluated on the smoothed states, so smoothing
    below its band biases that column: a stiff coupling's high mode lives in x_i − x_j and
    barely moves x_i (``torsion2_stiff``: 4× the coordinates' band; smoothed to theirs,
    the true structure's least squares gave the coupling 18 for 50 and its cubic 1.2e3 for
    5e4, at this band 50.5 and 4.9e4). One coordinate: :func:`smoothing_cutoff_hz`."""
    coordinates, relative = _band_bins(measurement)
    return max(coordinates + relative) / (measurement.n_samples * measurement.dt)


def _band_bins(measurement: Measurement) -> tuple[list[int], list[int]]:
    """(:func:`signal_band_bins` of each coordinate, of each x_i − x_j with i < j)."""
    r = measurement.responses
    count = r.shape[1]
    return ([signal_band_bins(r[:, i]) for i in range(count)],
            [signal_band_bins(r[:, i] - r[:, j]) for i in range(count)
             for j in range(i + 1, count)])


def signal_band_bins(signal: np.ndarray) -> int:
    """Smallest m whose bins (DC included) hold 99 % of ``signal``'s AC energy above its
    white-noise floor: :func:`gpjax._objective.default_n_bins` with the floor taken out of
    every bin. The floor is the periodogram's median over the upper half of the
    frequencies divided by ln 2 (a white noise's ordinates are exponential, median ln 2 ×
    mean; the median ignores the few bins a band reaching there holds). Without it the
    noise's own share decides the band once it exceeds 1 %: a relative coordinate is a
    difference of two noisy coordinates and may be a fifth of either (``torsion2_stiff``
    at 2 % noise: 231 Hz for its 54 Hz; with the floor taken out 54 Hz from 0 to 10 %).
    Where nothing stands above the floor, :func:`gpjax._objective.default_n_bins`."""
    energy = amplitude_spectrum(signal)[1:] ** 2
    if energy.size < 2:
        return default_n_bins(signal)
    above = np.cumsum(energy - np.median(energy[energy.size // 2:]) / np.log(2.0))
    if not above[-1] > 0:
        return default_n_bins(signal)
    return 2 + int(np.searchsorted(above / above[-1], SPECTRAL_ENERGY_FRACTION))


def smoothed_weak_form(measurement: Measurement) -> WeakForm:
    """The weak form of a record of D coordinates on its smoothed states: every
    coordinate's x and x' from :func:`smoothed_derivatives` at the system's band
    (:func:`system_band_hz`), so the nonlinear columns keep it. The windows are the
    widest that still pass that band at their −3 dB point (a Savitzky–Golay window for
    cutoff f passes ~2f there, :func:`savgol_window`), never wider than the smoothing
    window of the coordinate with the lowest band. Narrower windows pass more noise (a
    gear's mesh, 2,001 samples, 1 % noise: the true structure's start 2.0e-5 at the
    system band's windows, 3.8e-6 at these); wider ones leave the low modes alone to
    decide the constants (``torsion2_stiff``: the coordinates' windows gave the true
    structure's start 1.9 and the search a wrong structure at 1.3; these give 0.58)."""
    coordinates, relative = _band_bins(measurement)
    seconds = measurement.n_samples * measurement.dt
    cutoff, lowest = max(coordinates + relative) / seconds, min(coordinates) / seconds
    smooth = [smoothed_derivatives(measurement.coordinate(d), cutoff)
              for d in range(measurement.n_coordinates)]
    return WeakForm(measurement, np.stack([s.x_dot for s in smooth], axis=1),
                    savgol_window(measurement, max(cutoff / 2, lowest)),
                    positions=np.stack([s.x for s in smooth], axis=1))


def evaluate(feature: sp.Expr, measurement: Measurement, positions: np.ndarray,
             velocities: np.ndarray) -> np.ndarray:
    """A feature's values at the samples (N,), given every coordinate's x and x' ((N,) for
    one coordinate, else (N, D)) and the measurement's time and inputs (numpy)."""
    n, count = measurement.n_samples, measurement.n_coordinates
    positions, velocities = np.reshape(positions, (n, count)), np.reshape(velocities, (n, count))
    fn = _lambdified(feature, measurement.response_names, measurement.time_name,
                     measurement.input_names)
    # A candidate's feature may overflow (exp(150·x')); the non-finite values make its
    # least squares NaN (:func:`scaled_lstsq`), so the candidate scores as diverged.
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        values = fn(*positions.T, *velocities.T, measurement.time,
                    *(measurement.inputs[name] for name in measurement.input_names))
    return np.broadcast_to(np.asarray(values, dtype=np.float64), (n,)).copy()


@lru_cache(maxsize=4096)
def _lambdified(feature: sp.Expr, coordinates: tuple[str, ...], time: str,
                inputs: tuple[str, ...]):
    arguments = ([sp.Symbol(c) for c in coordinates] + [sp.Symbol(f"{c}_dot") for c in coordinates]
                 + [sp.Symbol(time)] + [sp.Symbol(u) for u in inputs])
    return sp.lambdify(arguments, feature, modules="numpy")


def design(weak: WeakForm, lhs: tuple[sp.Expr, ...], forcing: tuple[sp.Expr, ...], *,
           equation: int = 0, held: dict[sp.Expr, float] | None = None
           ) -> tuple[np.ndarray, np.ndarray, bool]:
    """(matrix (K, p), target (K,), normalised) of equation ``equation``'s least-squares
    problem for left-hand side features ``lhs`` (state and parametric) and ``forcing``
    features. ``held``: forcing features whose coefficient is held at the value given (the
    equation's normalisation: the first unknown is then the mass); default the first input
    at 1 where it is in ``forcing``. With none held the mass is 1. ``normalised``: some
    coefficient is held."""
    if held is None:
        held = {weak.u0: 1.0} if weak.u0 is not None and weak.u0 in forcing else {}
    acceleration = weak.acceleration(equation)
    columns = [acceleration] if held else []
    columns += [weak.column(f) for f in lhs]
    columns += [-weak.column(g) for g in forcing if g not in held]
    target = (sum((v * weak.column(g) for g, v in held.items()), np.zeros(acceleration.size))
              if held else -acceleration)
    matrix = np.stack(columns, axis=1) if columns else np.zeros((target.size, 0))
    return matrix, target, bool(held)


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
                           forcing: tuple[sp.Expr, ...], *, equation: int = 0,
                           held: dict[sp.Expr, float] | None = None) -> float:
    """Norm of the weak-form least-squares residual of a structure (how much of the data
    its features leave unexplained), in the weak form's units (:func:`design`'s
    arguments)."""
    matrix, target, _ = design(weak, lhs, forcing, equation=equation, held=held)
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
