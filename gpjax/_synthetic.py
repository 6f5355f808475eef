"""Records of the synthetic systems: :func:`generate` and :func:`write_csv`.

:func:`generate` integrates a :class:`~gpjax._systems.System` twice — the fit record, and
an extrapolation record with another input realisation whose amplitude is
``extrapolation_scale`` times larger — and adds Gaussian noise to the response and to the
input. Seeds: four streams spawned from ``numpy.random.SeedSequence(seed)`` (fit input,
extrapolation input, fit noise, extrapolation noise), so a seed gives the same arrays bit
for bit.

The truth is exact up to the integrator's tolerance: the open-loop input is band-limited
random excitation, a random-phase multisine evaluated in continuous time, and the
equations (the exact discontinuous laws for sign and |x'|) are integrated by scipy's
DOP853 with rtol 1e-10, atol 1e-12 (:func:`gpjax._scoring.solve`), with ``max_step``
:data:`~gpjax._systems.SIGN_MAX_STEP` = 5 ms (half a sample) for the systems with sign or
|x'|. Dry friction is solved as a Filippov system — events at x' = 0, sticking while the
friction can hold the mass — since an event-free solve chatters and stalls once the mass
sticks. The positioning stage is closed loop and solved in closed form between its
samples (:mod:`gpjax._stage`).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Callable

import numpy as np
from scipy.interpolate import CubicSpline

from ._data import Measurement
from ._scoring import solve
from ._stage import stage_hold, stage_response
from ._systems import System, get_system

#: Relative tolerance of the truth integration (scipy DOP853; atol 1e-12).
RTOL = 1e-10


@dataclasses.dataclass(frozen=True, kw_only=True)
class Record:
    """One record of a synthetic system.

    Attributes:
        time: sample times (s), shape (N,).
        input_true, input_measured: the input (N) without and with noise, shape (N,).
        response_true, response_measured: positions without and with noise (encoder
            quantisation for the stage), shape (C, N), rows in ``coordinates`` order.
        velocity_true: true velocities, shape (C, N).
        coordinates: the response names.
        scale: the input amplitude relative to the nominal one.
    """

    time: np.ndarray
    input_true: np.ndarray
    input_measured: np.ndarray
    response_true: np.ndarray
    response_measured: np.ndarray
    velocity_true: np.ndarray
    coordinates: tuple[str, ...]
    scale: float

    @property
    def initial_state(self) -> np.ndarray:
        """The true state (positions, velocities) at the first sample."""
        return np.concatenate([self.response_true[:, 0], self.velocity_true[:, 0]])

    def measurement(self, coordinate: str | None = None) -> Measurement:
        """The measured response of ``coordinate`` (default: the first) and measured input
        as a :class:`~gpjax.Measurement` (columns t, the coordinate's name, u).

        Raises:
            ValueError: an unknown coordinate.
        """
        coordinate = coordinate or self.coordinates[0]
        if coordinate not in self.coordinates:
            raise ValueError(f"unknown coordinate {coordinate!r}; use one of {self.coordinates}")
        row = self.coordinates.index(coordinate)
        return Measurement(time=self.time, response=self.response_measured[row],
                           inputs={"u": self.input_measured}, response_name=coordinate)

    def system_measurement(self) -> Measurement:
        """Every coordinate's measured response and the measured input as one
        :class:`~gpjax.Measurement` (D = number of coordinates)."""
        return Measurement(time=self.time, responses=self.response_measured.T,
                           inputs={"u": self.input_measured}, response_names=self.coordinates)


@dataclasses.dataclass(frozen=True, kw_only=True)
class SyntheticRecord:
    """The fit and extrapolation records of one system and seed, and how they were made."""

    system: System
    seed: int
    noise: float
    input_noise: float
    fit: Record
    extrapolation: Record

    @property
    def truth(self) -> dict[str, float]:
        """The true constants."""
        return dict(self.system.constants)


def generate(system: System | str, *, seed: int, noise: float = 0.01,
             input_noise: float = 0.01, extrapolation_scale: float = 1.2) -> SyntheticRecord:
    """The fit record and the extrapolation record (another input realisation, amplitude
    × ``extrapolation_scale``) of ``system``, with response noise σ = ``noise`` × std of
    each true response and input noise σ = ``input_noise`` × std of the true input. For
    the stage the noisy position is then rounded to the encoder's resolution (``noise=0``
    gives the encoder reading alone), and ``extrapolation_scale`` scales the reference.

    Raises:
        ValueError: an unknown system name, a negative seed, negative or non-finite noise,
            or a non-positive scale.
    """
    system = get_system(system) if isinstance(system, str) else system
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    for name, value in (("noise", noise), ("input_noise", input_noise)):
        if not (math.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
    if not (math.isfinite(extrapolation_scale) and extrapolation_scale > 0):
        raise ValueError(f"extrapolation_scale must be a finite number > 0, "
                         f"got {extrapolation_scale!r}")
    streams = [np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(4)]
    records = [_record(system, streams[i], streams[i + 2], scale, noise, input_noise)
               for i, scale in enumerate((1.0, extrapolation_scale))]
    return SyntheticRecord(system=system, seed=int(seed), noise=noise,
                           input_noise=input_noise, fit=records[0],
                           extrapolation=records[1])


def _record(system: System, input_rng, noise_rng, scale: float, noise: float,
            input_noise: float) -> Record:
    time = system.time
    if system.loop is not None:
        positions, velocities, force = stage_response(system, time, input_rng, scale)
    else:
        force = system.excitation.draw(input_rng, time, scale)
        positions, velocities = integrate(system, time, force)
        force = force(time)
    n = time.size
    measured = positions + noise * positions.std(axis=1, keepdims=True) * \
        noise_rng.standard_normal(positions.shape)
    if system.loop is not None:
        step = system.loop.resolution
        measured = step * np.round(measured / step)
    measured_input = force + input_noise * force.std() * noise_rng.standard_normal(n)
    return Record(time=time, input_true=force, input_measured=measured_input,
                  response_true=positions, response_measured=measured,
                  velocity_true=velocities, coordinates=system.coordinates, scale=scale)


def integrate(system: System, time: np.ndarray, force: Callable, *,
              state0: np.ndarray | None = None, rtol: float = RTOL,
              max_step: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(positions, velocities), each (C, N), of ``system``'s truth driven by ``force(t)``
    (N) from ``state0`` (default: rest at 0), by DOP853 at ``rtol`` and the system's
    ``max_step`` (s) unless given (:func:`gpjax._scoring.solve`).

    Raises:
        SimulationError: the integration failed.
    """
    n = len(system.coordinates)
    state0 = np.zeros(2 * n) if state0 is None else state0
    return solve(system.acceleration, n, time, force, state0=state0, rtol=rtol,
                 max_step=max_step or system.max_step)


def write_csv(record: Record, path: str | Path) -> None:
    """Write the measured columns ``t, <coordinates…>, u`` of ``record`` as CSV (readable by
    :func:`gpjax.load_csv`)."""
    columns = np.column_stack([record.time, *record.response_measured, record.input_measured])
    np.savetxt(path, columns, fmt="%.17g", delimiter=",", comments="",
               header=",".join(["t", *record.coordinates, "u"]))


def truth_error(synthetic: SyntheticRecord, *, record: str = "fit") -> np.ndarray:
    """RMS difference between the measured response and the truth driven by the
    *measured* input (cubic spline between samples; held samples for the stage), in
    units of the response noise σ, per coordinate: a few at most unless the system is
    chaotic or drifts.

    Raises:
        ValueError: ``record`` is not "fit" or "extrapolation", or the noise is zero.
    """
    if record not in ("fit", "extrapolation"):
        raise ValueError(f"record must be 'fit' or 'extrapolation', got {record!r}")
    if synthetic.noise == 0:
        raise ValueError("the noise is zero; truth_error is in units of the noise")
    data = getattr(synthetic, record)
    system = synthetic.system
    if system.loop is not None:
        positions, _ = stage_hold(system, data.time, data.input_measured)
    else:
        positions = _driven_by_measured_input(system, data)
    sigma = synthetic.noise * data.response_true.std(axis=1)
    return np.sqrt(np.mean((positions - data.response_measured) ** 2, axis=1)) / sigma


def _driven_by_measured_input(system: System, data: Record, *, rtol: float = RTOL
                              ) -> np.ndarray:
    """Positions (C, N) of ``system`` driven by ``data``'s *measured* input (cubic spline
    between samples) from its true initial state, at ``rtol`` (:func:`integrate`)."""
    force = CubicSpline(data.time, data.input_measured)
    return integrate(system, data.time, force, state0=data.initial_state, rtol=rtol)[0]


def cramer_rao(synthetic: SyntheticRecord, *, step: float = 1e-3) -> dict[str, float]:
    """The Cramér–Rao floor of the fit record: per truth constant, the smallest relative
    standard deviation any unbiased estimator reaches from the response alone, with white
    noise σ = ``noise`` × std(x) and the true input known — a lower bound, since the
    measured input is noisy too. Fisher information JᵀJ/σ², J the response's sensitivity
    to each constant's logarithm by central differences (relative ``step``) of
    :func:`integrate`. A constant above a benchmark's tolerance is not identifiable to it
    on this record by any method.

    Raises:
        ValueError: the stage (closed loop) or zero noise; a singular Fisher matrix.
    """
    system, data = synthetic.system, synthetic.fit
    if system.loop is not None or synthetic.noise == 0:
        raise ValueError("the Cramér–Rao floor needs an open-loop system and nonzero noise")
    force = CubicSpline(data.time, data.input_true)
    columns = []
    for name, value in system.constants.items():
        ends = [integrate(dataclasses.replace(system, constants={
            **system.constants, name: value * (1 + side * step)}), data.time, force,
            state0=data.initial_state)[0] for side in (1, -1)]
        columns.append(((ends[0] - ends[1]) / (2 * step)).ravel())
    sigma = np.repeat(synthetic.noise * data.response_true.std(axis=1), data.time.size)
    sensitivity = np.column_stack(columns) / sigma[:, None]
    covariance = np.linalg.inv(sensitivity.T @ sensitivity)
    return {name: float(math.sqrt(covariance[i, i])) for i, name in enumerate(system.constants)}


def truth_refit(synthetic: SyntheticRecord, *, rtol: float = 1e-8,
                max_evaluations: int = 80) -> dict[str, float]:
    """The truth's constants refitted to the fit record as a method sees it — the measured
    response, driven by the *measured* input (cubic spline between samples) — by
    nonlinear least squares from the true values: what an estimator that is given the
    right structure reaches on these data, response and input noise both (the
    Cramér–Rao floor knows the input exactly). A benchmark's "constants within 2 %" that
    this misses is the data's limit, not the structure search's.

    scipy's Levenberg–Marquardt (``least_squares``, "lm", forward differences of 0.01 %
    of each constant) on each constant's ratio to its true value, so that every constant
    is resolved alike (the step test is relative to the parameters' norm: on logarithms
    a constant near 1 went unresolved beside large ones, 0.3 σ short of the optimum);
    stopped when a step moves the ratios by less than 1e-6 or the squared error by less
    than 1e-8 of itself. Every residual is :func:`integrate` (the exact sign laws,
    sticking included) at ``rtol``, from the true initial state, at most
    ``max_evaluations`` solves. The start at the truth keeps it in the truth's basin.

    Raises:
        ValueError: the stage (closed loop).
        SimulationError: an integration failed.
    """
    from scipy.optimize import least_squares

    system, data = synthetic.system, synthetic.fit
    if system.loop is not None:
        raise ValueError("the truth refit needs an open-loop system")
    truth = np.array(list(system.constants.values()))
    scale = data.response_true.std(axis=1, keepdims=True)

    def constants(ratio: np.ndarray) -> dict[str, float]:
        return {n: float(v) for n, v in zip(system.constants, truth * ratio)}

    def residuals(ratio: np.ndarray) -> np.ndarray:
        positions = _driven_by_measured_input(
            dataclasses.replace(system, constants=constants(ratio)), data, rtol=rtol)
        return ((positions - data.response_measured) / scale).ravel()

    fit = least_squares(residuals, np.ones(truth.size), method="lm", diff_step=1e-4,
                        xtol=1e-6, ftol=1e-8, max_nfev=max_evaluations)
    return constants(fit.x)
