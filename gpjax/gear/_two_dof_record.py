"""A measured record of the 2-DOF gear pair (eqs. 21–22) with known truth, for identifying
the system with both gears' coordinates measured (issue 14)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .._data import Measurement
from ._stiffness import GearPair, average_mesh_stiffness
from ._two_dof import PAPER_J1, PAPER_TORQUE, TwoDofGearPair, simulate_two_dof


@dataclasses.dataclass(frozen=True)
class TwoDofRecord:
    """Measured angles (rad) and torques (N·m) of a gear pair, and the truth.

    Attributes:
        measurement: responses ``th1``, ``th2`` (Θ1, Θ2 with noise), inputs ``T1``, ``T2``.
        truth: J1, J2 (kg·m²), r1, r2 (m), k_m (N/m), c_m (N·s/m).
    """

    measurement: Measurement
    truth: dict[str, float]

    def line_of_action(self) -> Measurement:
        """The angles as displacements along the line of action, ``s1`` = r1·Θ1 and
        ``s2`` = r2·Θ2 (m): δ = s1 − s2 is then a relative coordinate, and eqs. 21–22 read
        (J1/r1)·s1'' + r1·c_m·(s1' − s2') + r1·k_m·(s1 − s2) = T1 and
        (J2/r2)·s2'' + r2·c_m·(s2' − s1') + r2·k_m·(s2 − s1) = −T2."""
        m = self.measurement
        return Measurement(time=m.time, responses=m.responses * [self.truth["r1"],
                                                                 self.truth["r2"]],
                           response_names=("s1", "s2"), inputs=m.inputs)


def _multisine(rng, low: float, high: float, rms: float, tones: int = 40):
    import jax.numpy as jnp

    frequencies = np.linspace(low, high, tones)
    phases = rng.uniform(0, 2 * np.pi, tones)
    amplitude = rms * math.sqrt(2.0 / tones)
    return lambda t: amplitude * jnp.sum(jnp.sin(2 * jnp.pi * frequencies * t + phases))


def two_dof_record(*, seed: int = 0, samples: int = 2001, sample_rate: float = 300e3,
                   noise: float = 0.01, damping_ratio: float = 0.05,
                   torque_scale: float = 1.0) -> TwoDofRecord:
    """The paper's pinion (J1 = 7.918e-5 kg·m², eq. 14) and a geometrically similar gear
    (J2 = J1·(z2/z1)⁴), the paper pair's base radii, its mean mesh stiffness k_m (constant)
    and mesh damping c_m for ``damping_ratio`` of critical (relative mode, ~14.7 kHz);
    T1 = 13 N·m plus a 1 N·m RMS random-phase multisine (40 tones, 2–25 kHz), T2 =
    (r2/r1)·13 N·m plus a 0.5 N·m one, both applied at t = 0 to gears at rest; both angles
    measured with Gaussian noise σ = ``noise`` × their standard deviation, the torques
    exactly; ``torque_scale`` multiplies both torques (an extrapolation record). Integrated
    by :func:`simulate_two_dof` (Tsit5, 1/64 of the mode's period)."""
    import jax
    import jax.numpy as jnp

    pair = GearPair.paper()
    r1, r2 = (r * 1e-3 for r in pair.geometry.base_radius_mm)
    j1 = PAPER_J1
    j2 = j1 * (pair.teeth2 / pair.teeth1) ** 4
    k_m = average_mesh_stiffness(pair)
    mu = (j1 / r1 ** 2) * (r2 ** 2 / j2)
    c_m = damping_ratio * 2 * math.sqrt(k_m / ((r1 ** 2 / j1) * (1 + mu)))
    rng = np.random.default_rng(seed)
    ripple1, ripple2 = _multisine(rng, 2e3, 25e3, 1.0), _multisine(rng, 2e3, 25e3, 0.5)

    def torque1(t):
        return torque_scale * (PAPER_TORQUE + ripple1(t))

    def torque2(t):
        return torque_scale * (PAPER_TORQUE * r2 / r1 + ripple2(t))

    system = TwoDofGearPair(J1=j1, J2=j2, r1=r1, r2=r2, k_m=k_m, c_m=c_m, T1=torque1,
                            T2=torque2)
    response = simulate_two_dof(system, t_end=(samples - 1) / sample_rate, samples=samples)
    t = np.asarray(response.t)
    angles = np.stack([np.asarray(response.theta1), np.asarray(response.theta2)], axis=1)
    noisy = angles + noise * angles.std(axis=0) * rng.standard_normal(angles.shape)
    inputs = {"T1": np.asarray(jax.vmap(torque1)(jnp.asarray(t))),
              "T2": np.asarray(jax.vmap(torque2)(jnp.asarray(t)))}
    measurement = Measurement(time=t, responses=noisy, response_names=("th1", "th2"),
                              inputs=inputs)
    return TwoDofRecord(measurement, {"J1": j1, "J2": j2, "r1": r1, "r2": r2, "k_m": k_m,
                                      "c_m": c_m})
