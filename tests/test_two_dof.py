"""2-DOF gear pair (eqs. 21–22) and its 1-DOF reduction (eq. 23): closed forms and scenarios.

Constant-coefficient cases share one compiled solve per model (same static structure), so
the whole file compiles five solves.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from gpjax._errors import ConfigError
from gpjax.gear._stiffness import GearPair, mesh_cycle_angles, mesh_stiffness
from gpjax.gear._two_dof import (
    TwoDofGearPair,
    mesh_stiffness_signal,
    reduction_error,
    reduction_scenarios,
    simulate_one_dof,
    simulate_two_dof,
)

J1, R1, R2, K, TORQUE = 7.918e-5, 0.0357, 0.1015, 4.7e8, 13.0
T_END = 1e-3


def _constant_pair(**change) -> TwoDofGearPair:
    fields = dict(J1=J1, J2=20 * J1, r1=R1, r2=R2, k_m=K, T1=TORQUE, T2=TORQUE * R2 / R1)
    return TwoDofGearPair(**(fields | change))


def test_one_dof_matches_the_closed_form_step_response():
    # J1 φ1'' + r1² k φ1 = T from rest: φ1 = T/(r1² k) (1 − cos ω t), ω² = r1² k / J1
    response = simulate_one_dof(_constant_pair(), t_end=T_END)
    omega = math.sqrt(R1 ** 2 * K / J1)
    expected = TORQUE / (R1 ** 2 * K) * (1.0 - np.cos(omega * response.t))
    np.testing.assert_allclose(response.phi1, expected, rtol=0, atol=1e-7 * expected.max())
    np.testing.assert_allclose(response.phi, R1 * response.phi1)


def test_two_dof_relative_mode_matches_the_closed_form():
    # with T2 = (r2/r1) T1: δ = T/(r1 k) (1 − cos ω t), ω² = k (r1²/J1 + r2²/J2)
    system = _constant_pair()
    response = simulate_two_dof(system, t_end=T_END)
    omega = math.sqrt(K * (R1 ** 2 / J1 + R2 ** 2 / system.J2))
    expected = TORQUE / (R1 * K) * (1.0 - np.cos(omega * response.t))
    np.testing.assert_allclose(response.relative_displacement, expected, rtol=0,
                               atol=1e-7 * expected.max())
    np.testing.assert_allclose(response.relative_angle, response.relative_displacement / R1)
    assert system.inertia_ratio == pytest.approx((J1 / R1 ** 2) / (system.J2 / R2 ** 2))


def test_mesh_forces_are_action_and_reaction():
    # d/dt (J1 Ω1 + (r1/r2) J2 Ω2) = T1 − (r1/r2) T2 whatever the mesh force, errors included
    system = _constant_pair(T2=0.0, c_m=300.0, e1=2e-6, e2=-1e-6, k1=K, k2=0.5 * K)
    response = simulate_two_dof(system, t_end=T_END)
    momentum = J1 * response.omega1 + (R1 / R2) * system.J2 * response.omega2
    np.testing.assert_allclose(momentum, TORQUE * response.t, rtol=0, atol=1e-9 * TORQUE * T_END)


def test_clamped_gear_stays_put():
    response = simulate_two_dof(_constant_pair(J2=math.inf), t_end=T_END,
                                theta0=(0.0, 0.2), omega0=(0.0, 3.0))
    np.testing.assert_allclose(response.theta2, 0.2 + 3.0 * response.t, rtol=1e-12)


@pytest.fixture(scope="module")
def scenarios():
    return reduction_scenarios()


def test_reduction_is_exact_for_a_clamped_gear_without_damping_or_errors(scenarios):
    assert scenarios["assumptions_hold"] < 1e-9


def test_reduction_error_grows_with_the_inertia_ratio(scenarios):
    assert scenarios["J2_much_larger"] < 0.02
    assert scenarios["similar_disks"] > 0.3
    assert scenarios["J2_equals_J1"] > 0.3


def test_reduction_fails_with_mesh_damping_or_gear_errors(scenarios):
    assert scenarios["mesh_damping"] > 0.3
    assert scenarios["gear_errors"] > 0.3


def test_reduction_error_needs_a_response():
    with pytest.raises(ConfigError, match="identically zero"):
        reduction_error(_constant_pair(T1=0.0, T2=0.0), t_end=T_END)


def test_reduction_error_starts_the_reduced_model_from_the_same_relative_state():
    # clamped gear, released from a deflected state: the reduction is exact
    system = _constant_pair(J2=math.inf, T1=0.0, T2=0.0)
    error = reduction_error(system, t_end=T_END, theta0=(1e-4, 2e-5), omega0=(0.5, 0.0))
    assert error < 1e-9


def test_mesh_stiffness_signal_reproduces_the_table():
    pair = GearPair.paper()
    signal = mesh_stiffness_signal(pair, pinion_speed_rpm=900.0)
    angles = mesh_cycle_angles(pair, samples=512)
    speed = 900.0 * 2.0 * math.pi / 60.0
    times = angles[::37] / speed
    expected = mesh_stiffness(pair, angles[::37]).k
    np.testing.assert_allclose(np.array([signal(t) for t in times]), expected, rtol=1e-9)
    period = pair.geometry.mesh_period_rad / speed
    assert float(signal(times[3] + 5 * period)) == pytest.approx(expected[3], rel=1e-9)


@pytest.mark.parametrize("change, message", [
    ({"J1": 0.0}, "J1 must be a positive finite number"),
    ({"J2": -1.0}, "J2 must be positive"),
    ({"r2": float("inf")}, "r2 must be a positive finite number"),
    ({"k_m": -5.0}, "k_m must be positive"),
    ({"k_m": "stiff"}, "k_m must be a number"),
    ({"c_m": -1.0}, "c_m must be a finite number >= 0"),
    ({"k1": float("nan")}, "k1 must be a finite number"),
    ({"T1": float("inf")}, "T1 must be a finite number or a function of t"),
])
def test_bad_parameters_raise_config_error(change, message):
    with pytest.raises(ConfigError, match=message):
        _constant_pair(**change)


@pytest.mark.parametrize("options, message", [
    ({"t_end": 0.0}, "t_end must be a positive"),
    ({"t_end": T_END, "samples": 1}, "samples must be an integer"),
    ({"t_end": T_END, "dt": -1e-6}, "dt must be a positive"),
    ({"t_end": 10.0, "dt": 1e-6}, "exceeds"),
])
def test_bad_options_raise_config_error(options, message):
    with pytest.raises(ConfigError, match=message):
        simulate_two_dof(_constant_pair(), **options)


def test_two_dof_parameters_are_frozen_and_keyword_only():
    with pytest.raises(dataclasses.FrozenInstanceError):
        _constant_pair().J1 = 1.0  # type: ignore[misc]
    with pytest.raises(TypeError):
        TwoDofGearPair(J1, J1, R1, R2, K)  # type: ignore[misc]
