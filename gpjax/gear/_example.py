"""The bundled gear-pair example, generated from the paper's own numbers.

The paper's measurements are not public. This generator rebuilds a data set with a known
truth from what the paper states:

* model, eq. 14: ``J·φ'' + K1·φ + K2·φ² = T(t)`` with J = 7.918e-5, K1 = 413.191,
  K2 = 51721 (paper units: φ in degrees, T in N·m);
* initial conditions, eq. 13: φ = 0.010955, φ' = −0.692100 at t0 = 0.0012973 s;
* one pinion revolution at 900 rpm (1/15 s), sampled at 20 kHz;
* a generic driving torque for the 19/54-tooth pair: 13 N·m mean, shaft orders
  (15, 30, 45 Hz) and mesh orders (285, 570, 855 Hz), with fixed amplitudes and phases
  (the paper's Fig. 8 shape is not published numerically; these are stated here instead).

The truth is integrated with scipy's DOP853 (rtol 1e-12) on the continuous torque, an
integrator independent of gpjax's. Measurement noise is Gaussian: σ_φ on the torsional
deformation and σ_T on the torque, drawn from ``numpy.random.default_rng(seed)``.
"""

from __future__ import annotations

import dataclasses
import json
from importlib import resources
from pathlib import Path
from typing import Callable

import numpy as np

from .._data import Measurement

#: The paper's identified model (eq. 14) and initial conditions (eq. 13).
PAPER_TRUTH = {"J": 7.918e-5, "K1": 413.191, "K2": 51721.0}
PAPER_T0 = 0.0012973
PAPER_PHI0 = 0.010955
PAPER_PHI_DOT0 = -0.692100
SHAFT_SPEED_RPM = 900.0
PINION_TEETH = 19
GEAR_TEETH = 54
MEAN_TORQUE = 13.0
SAMPLE_RATE = 20_000.0


@dataclasses.dataclass(frozen=True)
class Torque:
    """T(t) = mean + Σ shaft orders + Σ mesh orders, in N·m (t in s)."""

    mean: float = MEAN_TORQUE
    shaft_hz: float = SHAFT_SPEED_RPM / 60.0
    teeth: int = PINION_TEETH
    shaft_amplitudes: tuple[float, ...] = (0.60, 0.30, 0.15)
    shaft_phases: tuple[float, ...] = (0.3, 1.9, 4.0)
    mesh_amplitudes: tuple[float, ...] = (1.20, 0.50, 0.20)
    mesh_phases: tuple[float, ...] = (0.0, 2.5, 5.1)

    @property
    def mesh_hz(self) -> float:
        return self.shaft_hz * self.teeth

    def __call__(self, t):
        t = np.asarray(t, dtype=np.float64)
        value = np.full_like(t, self.mean)
        for k, (a, p) in enumerate(zip(self.shaft_amplitudes, self.shaft_phases), start=1):
            value = value + a * np.cos(2 * np.pi * k * self.shaft_hz * t + p)
        for k, (a, p) in enumerate(zip(self.mesh_amplitudes, self.mesh_phases), start=1):
            value = value + a * np.cos(2 * np.pi * k * self.mesh_hz * t + p)
        return value


@dataclasses.dataclass(frozen=True)
class GearExample:
    """A generated data set: the noisy measurement, the clean response and the truth."""

    measurement: Measurement
    clean_response: np.ndarray
    truth: dict[str, float]
    settings: dict


def generate_gear_example(*, seed: int = 0, noise_phi: float = 2e-5, noise_torque: float = 0.005,
                          torque: Torque = Torque(), truth: dict[str, float] | None = None,
                          sample_rate: float = SAMPLE_RATE, revolutions: float = 1.0,
                          phi0: float = PAPER_PHI0, phi_dot0: float = PAPER_PHI_DOT0,
                          t0: float = PAPER_T0, time_name: str = "t",
                          response_name: str = "phi", input_name: str = "T",
                          extra_force: Callable[[float, float, float], float] | None = None,
                          ) -> GearExample:
    """Simulate eq. 14 driven by ``torque`` and add measurement noise.

    Args:
        seed: seed of the noise.
        noise_phi: standard deviation of the noise on φ, in degrees.
        noise_torque: standard deviation of the noise on the recorded torque, in N·m.
        torque: the driving torque T(t).
        truth: ``{"J", "K1", "K2"}``; the paper's values by default.
        sample_rate: samples per second.
        revolutions: length of the record in pinion revolutions.
        phi0, phi_dot0, t0: initial conditions (eq. 13).
        time_name, response_name, input_name: column names of the measurement.
        extra_force: ``(t, φ, φ') -> N·m``, a further force on the left-hand side of
            eq. 14 (an effect the model does not declare; see :mod:`gpjax.gear._undeclared`).
    """
    truth = dict(PAPER_TRUTH if truth is None else truth)
    j, k1, k2 = truth["J"], truth["K1"], truth["K2"]
    n = int(round(revolutions * sample_rate / torque.shaft_hz)) + 1
    time = t0 + np.arange(n) / sample_rate

    from scipy.integrate import solve_ivp  # not at import: the demo reads the bundled CSV

    def field(t, y):
        extra = 0.0 if extra_force is None else extra_force(t, y[0], y[1])
        return [y[1], (torque(t) - k1 * y[0] - k2 * y[0] ** 2 - extra) / j]

    solution = solve_ivp(field, (time[0], time[-1]), [phi0, phi_dot0], method="DOP853",
                         t_eval=time, rtol=1e-12, atol=1e-15, max_step=0.25 / sample_rate)
    clean = solution.y[0]
    rng = np.random.default_rng(seed)
    phi = clean + noise_phi * rng.standard_normal(n)
    recorded_torque = torque(time) + noise_torque * rng.standard_normal(n)
    measurement = Measurement(time=time, response=phi, inputs={input_name: recorded_torque},
                              time_name=time_name, response_name=response_name)
    settings = {"seed": seed, "noise_phi": noise_phi, "noise_torque": noise_torque,
                "sample_rate": sample_rate, "revolutions": revolutions, "phi0": phi0,
                "phi_dot0": phi_dot0, "t0": t0, "torque": dataclasses.asdict(torque)}
    return GearExample(measurement=measurement, clean_response=clean, truth=truth,
                       settings=settings)


BUNDLED_CSV = "gear_example.csv"
BUNDLED_TRUTH = "gear_example_truth.json"


def write_example(directory: str | Path, *, seed: int = 0) -> GearExample:
    """Write the bundled example (CSV and truth JSON) into ``directory``.

    The shipped files in ``gpjax/data`` were made with ``write_example("gpjax/data")``.
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    example = generate_gear_example(seed=seed)
    example.measurement.to_csv(directory / BUNDLED_CSV)
    truth = {"model": "J*phi_ddot + K1*phi + K2*phi**2 = T", "units": {
        "phi": "deg", "T": "N*m", "t": "s"}, **example.truth,
        "initial_conditions": {"t0": example.settings["t0"], "phi": example.settings["phi0"],
                               "phi_dot": example.settings["phi_dot0"]},
        "generator": {k: v for k, v in example.settings.items()},
        "clean_response_rms": float(np.sqrt(np.mean(example.clean_response ** 2)))}
    (directory / BUNDLED_TRUTH).write_text(json.dumps(truth, indent=2) + "\n", encoding="utf-8")
    return example


def load_bundled_example() -> tuple[Measurement, dict]:
    """The shipped gear example as a Measurement (columns t, phi, T) and its truth dict."""
    from .._data import load_csv

    data = resources.files("gpjax") / "data"
    with resources.as_file(data / BUNDLED_CSV) as path:
        measurement = load_csv(path, time="t", response="phi", inputs=["T"])
    truth = json.loads((data / BUNDLED_TRUTH).read_text(encoding="utf-8"))
    return measurement, truth
