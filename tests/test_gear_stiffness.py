"""Gear mesh stiffness (paper §6, eqs. 15–20): hand computations and independent formulas."""

from __future__ import annotations

import dataclasses
import math
import os
import warnings

import numpy as np
import pytest

from gpjax._errors import ConfigError
from gpjax.gear._stiffness import (
    GearPair,
    average_mesh_stiffness,
    bending_stiffness,
    contact_points,
    hertz_stiffness,
    iso6336_stiffness,
    kuang_yang_coefficients,
    mesh_cycle_angles,
    mesh_stiffness,
    pair_stiffness,
    stiffness_report,
    torsional_stiffness,
)

PAPER = GearPair.paper()


def test_paper_pair_fields():
    assert (PAPER.module_mm, PAPER.teeth1, PAPER.teeth2) == (4.0, 19, 54)
    assert (PAPER.x1, PAPER.x2, PAPER.face_width_mm) == (0.228, -0.228, 25.0)
    assert (PAPER.pressure_angle_deg, PAPER.youngs_modulus_pa, PAPER.poisson) == (
        20.0, 2.06e11, 0.3)


def test_hertz_stiffness_matches_hand_computation_of_eq15():
    # π · 2.06e11 Pa · 0.025 m / (4 · (1 − 0.3²)) = 1.6179e10 / 3.64
    assert hertz_stiffness(PAPER) == pytest.approx(4.44484e9, rel=1e-5)
    assert hertz_stiffness(PAPER, per_unit_width=True) == pytest.approx(177.7934, rel=1e-5)


def test_paper_geometry_by_hand():
    g = PAPER.geometry
    assert g.pitch_radius_mm == pytest.approx((38.0, 108.0))
    assert g.base_radius_mm == pytest.approx((38.0 * math.cos(math.radians(20)),
                                               108.0 * math.cos(math.radians(20))))
    # r_a = r + m (1 + x), no tip shortening when x1 + x2 = 0
    assert g.tip_radius_mm == pytest.approx((42.912, 111.088))
    assert g.operating_pressure_angle_deg == pytest.approx(20.0, abs=1e-12)
    assert g.operating_center_distance_mm == pytest.approx(146.0)
    assert g.operating_pitch_radius_mm == pytest.approx((38.0, 108.0))
    assert g.base_pitch_mm == pytest.approx(math.pi * 4.0 * math.cos(math.radians(20)))


def _contact_ratio_from_roll_angles(pair: GearPair) -> float:
    """ε = [z1 (tan α_a1 − tan α_w) + z2 (tan α_a2 − tan α_w)] / 2π (ISO 21771 form)."""
    g = pair.geometry
    tan_w = math.tan(math.radians(g.operating_pressure_angle_deg))
    total = 0.0
    for z, rb, ra in zip(pair.teeth, g.base_radius_mm, g.tip_radius_mm):
        total += z * (math.tan(math.acos(rb / ra)) - tan_w)
    return total / (2.0 * math.pi)


@pytest.mark.parametrize("pair", [
    PAPER,
    GearPair(module_mm=4.0, teeth1=19, teeth2=54, face_width_mm=25.0),
    GearPair(module_mm=3.0, teeth1=25, teeth2=40, x1=0.5, x2=0.2, face_width_mm=20.0),
    GearPair(module_mm=2.0, teeth1=30, teeth2=90, x1=0.1, x2=-0.3, face_width_mm=10.0,
             pressure_angle_deg=25.0),
])
def test_contact_ratio_agrees_with_roll_angle_formula(pair):
    assert pair.geometry.contact_ratio == pytest.approx(_contact_ratio_from_roll_angles(pair),
                                                        rel=1e-12)


def test_paper_contact_ratio_is_plausible():
    assert PAPER.geometry.contact_ratio == pytest.approx(1.6124, abs=1e-4)


def test_operating_pressure_angle_solves_the_involute_equation():
    pair = GearPair(module_mm=3.0, teeth1=25, teeth2=40, x1=0.5, x2=0.2, face_width_mm=20.0)
    g = pair.geometry
    alpha, alpha_w = math.radians(20.0), math.radians(g.operating_pressure_angle_deg)
    involute = math.tan(alpha_w) - alpha_w
    assert involute == pytest.approx(math.tan(alpha) - alpha + 2 * math.tan(alpha) * 0.7 / 65,
                                     rel=1e-12)
    assert g.operating_pressure_angle_deg > 20.0
    assert g.operating_center_distance_mm == pytest.approx(
        97.5 * math.cos(alpha) / math.cos(alpha_w), rel=1e-12)
    assert 0.0 < g.tip_shortening < 0.7


def test_contact_radii_at_the_ends_and_the_pitch_point():
    g = PAPER.geometry
    r1_a, r2_a = g.radii_at(g.start_of_contact_mm)
    r1_e, r2_e = g.radii_at(g.end_of_contact_mm)
    r1_c, r2_c = g.radii_at(g.pitch_point_mm)
    assert float(r2_a) == pytest.approx(g.tip_radius_mm[1], rel=1e-12)  # contact starts at gear tip
    assert float(r1_e) == pytest.approx(g.tip_radius_mm[0], rel=1e-12)  # and ends at pinion tip
    assert (float(r1_c), float(r2_c)) == pytest.approx((38.0, 108.0), rel=1e-12)


def test_zone_lengths():
    g = PAPER.geometry
    zones = g.zones_mm
    eps, pb = g.contact_ratio, g.base_pitch_mm
    single = zones["single"][1] - zones["single"][0]
    assert single == pytest.approx((2.0 - eps) * pb, rel=1e-12)
    for name in ("double_approach", "double_recess"):
        assert zones[name][1] - zones[name][0] == pytest.approx((eps - 1.0) * pb, rel=1e-12)
    assert zones["double_approach"][0] == g.start_of_contact_mm
    assert zones["double_recess"][1] == g.end_of_contact_mm


def test_kuang_yang_coefficients_for_the_paper_teeth():
    assert kuang_yang_coefficients(19) == pytest.approx((25.0334, 25.3562, -13.3863, -19.2666),
                                                        abs=5e-4)
    assert kuang_yang_coefficients(54) == pytest.approx((30.3386, 21.7628, -17.2683, -19.6026),
                                                        abs=5e-4)
    for teeth in (11, 101):
        with pytest.raises(ConfigError, match="Kuang-Yang"):
            kuang_yang_coefficients(teeth)


def test_bending_stiffness_follows_eq18_by_hand():
    a0, a1, a2, a3 = kuang_yang_coefficients(19)
    x, m, b = 0.228, 4.0, 25.0
    at_pitch = bending_stiffness(PAPER, 1, 38.0, per_unit_width=True)
    assert at_pitch == pytest.approx(a0 + a1 * x, rel=1e-12)
    r = 38.0 + (1.0 + x) * m  # (r − R)/((1 + x) m) = 1: the pinion's tip
    assert bending_stiffness(PAPER, 1, r, per_unit_width=True) == pytest.approx(
        a0 + a1 * x + a2 + a3 * x, rel=1e-12)
    assert bending_stiffness(PAPER, 1, 38.0) == pytest.approx(b * (a0 + a1 * x) * 1e6, rel=1e-12)


def test_bending_stiffness_falls_towards_the_tip():
    for gear in (1, 2):
        g = PAPER.geometry
        radii = np.linspace(g.base_radius_mm[gear - 1] + 1.0, g.tip_radius_mm[gear - 1], 50)
        values = bending_stiffness(PAPER, gear, radii)
        assert np.all(np.diff(values) < 0.0)
        assert np.all(values > 0.0)


def test_bending_stiffness_rejects_bad_gear_and_radius():
    with pytest.raises(ConfigError, match="gear must be 1"):
        bending_stiffness(PAPER, 3, 38.0)
    with pytest.raises(ConfigError, match="flank of gear 1"):
        bending_stiffness(PAPER, 1, 50.0)
    with pytest.raises(ConfigError, match="flank of gear 2"):
        bending_stiffness(PAPER, 2, [100.0, 90.0])


def test_mesh_stiffness_is_the_series_formula_of_eq19():
    angles = mesh_cycle_angles(PAPER, samples=97)
    result = mesh_stiffness(PAPER, angles)
    points = result.points
    k_h = hertz_stiffness(PAPER)
    for i in range(angles.size):
        k1 = bending_stiffness(PAPER, 1, points.radius1_a_mm[i])
        k2 = bending_stiffness(PAPER, 2, points.radius2_a_mm[i])
        assert result.k_a[i] == pytest.approx(1.0 / (1.0 / k1 + 1.0 / k2 + 1.0 / k_h), rel=1e-12)
        if points.double[i]:
            k1 = bending_stiffness(PAPER, 1, points.radius1_b_mm[i])
            k2 = bending_stiffness(PAPER, 2, points.radius2_b_mm[i])
            assert result.k_b[i] == pytest.approx(1.0 / (1.0 / k1 + 1.0 / k2 + 1.0 / k_h),
                                                  rel=1e-12)


def test_total_is_sum_and_single_contact_has_no_second_pair():
    angles = mesh_cycle_angles(PAPER, samples=4000)
    result = mesh_stiffness(PAPER, angles)
    np.testing.assert_allclose(result.k, result.k_a + result.k_b, rtol=0, atol=0)
    single = ~result.points.double
    assert np.all(result.k_b[single] == 0.0)
    assert np.all(result.k_b[~single] > 0.0)
    assert np.all(np.isnan(result.points.position_b_mm[single]))
    # the double-contact share of the cycle is ε − 1
    assert np.mean(result.points.double) == pytest.approx(PAPER.geometry.contact_ratio - 1.0,
                                                          abs=1e-3)
    # the single zone is stiffer than one pair alone nowhere, softer than double everywhere
    assert result.k[single].max() < result.k[~single].min()


def test_contact_points_are_periodic_and_move_with_the_base_radius():
    period = PAPER.geometry.mesh_period_rad
    first = contact_points(PAPER, [0.01, 0.02])
    shifted = contact_points(PAPER, [0.01 + 3 * period, 0.02 - period])
    np.testing.assert_allclose(first.position_a_mm, shifted.position_a_mm, rtol=1e-12)
    step = first.position_a_mm[1] - first.position_a_mm[0]
    assert step == pytest.approx(0.01 * PAPER.geometry.base_radius_mm[0], rel=1e-10)


def test_pair_stiffness_matches_mesh_stiffness_in_single_contact():
    g = PAPER.geometry
    angle = (g.pitch_point_mm - g.start_of_contact_mm) / g.base_radius_mm[0]
    result = mesh_stiffness(PAPER, [angle])
    assert not result.points.double[0]
    assert result.k[0] == pytest.approx(pair_stiffness(PAPER, g.pitch_point_mm), rel=1e-12)


def test_average_agrees_with_dense_sampling():
    dense = mesh_stiffness(PAPER, mesh_cycle_angles(PAPER, samples=200_000)).k
    average = average_mesh_stiffness(PAPER)
    assert average == pytest.approx(float(np.mean(dense)), rel=2e-5)
    assert dense.min() < average < dense.max()


def test_torsional_conversion_by_hand():
    rb1 = 0.038 * math.cos(math.radians(20))
    assert torsional_stiffness(PAPER, 1e8) == pytest.approx(1e8 * rb1 ** 2, rel=1e-12)
    assert torsional_stiffness(PAPER, 1e8, per_degree=True) == pytest.approx(
        1e8 * rb1 ** 2 * math.pi / 180.0, rel=1e-12)


def test_report_for_the_paper_pair():
    report = stiffness_report(PAPER)
    assert report["k_h"] == pytest.approx(4.44484e9, rel=1e-5)
    assert report["contact_ratio"] == pytest.approx(PAPER.geometry.contact_ratio)
    assert report["K_min"] < report["K_mean_single"] < report["K_mean"] < report["K_mean_double"]
    assert report["K_mean_double"] < report["K_max"]
    points = report["points"]
    assert points["A"]["double_contact"] and points["B_double"]["double_contact"]
    for name in ("B_single", "C", "D_single"):
        assert not points[name]["double_contact"]
        assert points[name]["K_B"] == 0.0
        assert points[name]["K"] == points[name]["K_A"]
    for point in points.values():
        assert point["K"] == pytest.approx(point["K_A"] + point["K_B"], rel=1e-12)
    low, high = report["K1_interval_N_m_per_deg"]
    assert low == pytest.approx(torsional_stiffness(PAPER, report["K_min"], per_degree=True))
    assert high == pytest.approx(torsional_stiffness(PAPER, report["K_max"], per_degree=True))
    # the paper-pair figures quoted in the documentation
    assert report["K_mean"] == pytest.approx(4.742e8, rel=1e-3)
    assert report["K_min"] == pytest.approx(3.179e8, rel=1e-3)
    assert report["K_max"] == pytest.approx(5.796e8, rel=1e-3)
    assert (low, high) == pytest.approx((7075.0, 12899.0), rel=1e-3)
    # K1 := r1 k1 with r1 the operating pitch radius (38 mm for the paper pair)
    assert report["k1_interval_N_per_deg"] == pytest.approx((low / 0.038, high / 0.038))


def test_iso6336_cross_check():
    iso = iso6336_stiffness(PAPER)
    assert iso["c_prime_th"] == pytest.approx(16.899, rel=1e-4)
    assert iso["c_prime"] == pytest.approx(16.899 * 0.8 * 0.975, rel=1e-4)
    # Kuang-Yang mean mesh stiffness within 10 % of ISO's c_γα (independent method)
    assert average_mesh_stiffness(PAPER) == pytest.approx(iso["c_gamma_alpha_n_per_m"], rel=0.1)
    with pytest.raises(ConfigError, match="ISO 6336-1"):
        iso6336_stiffness(GearPair(module_mm=4.0, teeth1=19, teeth2=54, x1=-0.2, x2=0.2,
                                   face_width_mm=25.0))
    flipped = stiffness_report(GearPair(module_mm=4.0, teeth1=19, teeth2=54, x1=-0.2, x2=0.2,
                                        face_width_mm=25.0))
    assert flipped["iso6336"] is None


@pytest.mark.parametrize("change, message", [
    ({"module_mm": 0.0}, "module_mm must be positive"),
    ({"module_mm": float("nan")}, "module_mm must be a finite number"),
    ({"face_width_mm": -1.0}, "face_width_mm must be positive"),
    ({"teeth1": 4}, "teeth1 must be an integer >= 5"),
    ({"teeth2": 54.0}, "teeth2 must be an integer >= 5"),
    ({"teeth1": True}, "teeth1 must be an integer >= 5"),
    ({"x1": 1.0}, "x1 must lie in"),
    ({"x2": "0.1"}, "x2 must be a finite number"),
    ({"pressure_angle_deg": 45.0}, "pressure_angle_deg must lie in"),
    ({"poisson": 0.5}, "poisson must lie in"),
    ({"youngs_modulus_pa": -2e11}, "youngs_modulus_pa must be positive"),
    ({"addendum_coefficient": 0.0}, "addendum_coefficient must lie in"),
    ({"addendum_coefficient": 0.3}, "contact ratio"),
    ({"teeth1": 8, "x1": 0.0, "x2": 0.0}, "involute interference"),
])
def test_bad_gear_pair_raises_config_error(change, message):
    fields = dataclasses.asdict(PAPER) | change
    with pytest.raises(ConfigError, match=message):
        GearPair(**fields)


def test_gear_pair_is_frozen_and_keyword_only():
    with pytest.raises(dataclasses.FrozenInstanceError):
        PAPER.module_mm = 5.0  # type: ignore[misc]
    with pytest.raises(TypeError):
        GearPair(4.0, 19, 54, 0.228, -0.228, 25.0)  # type: ignore[misc]
    with pytest.raises(ConfigError, match="samples"):
        mesh_cycle_angles(PAPER, samples=1)


def _ross():
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            from ross.gear_element import GearElementTVMS, Mesh
            from ross.materials import Material
    except (ImportError, ValueError) as err:  # not installed, or broken by its plotly version
        if os.environ.get("CI"):
            pytest.fail(f"ross-rotordynamics unavailable on CI ({type(err).__name__}); "
                        'install the cross-check extra: pip install -e ".[crosscheck]"')
        pytest.skip(f"ross-rotordynamics unavailable: {type(err).__name__}; "
                    'pip install -e ".[crosscheck]"')
    return GearElementTVMS, Mesh, Material


@pytest.mark.slow
def test_against_ross_potential_energy_tvms():
    """ross has no profile shift, so compare the unshifted 19/54 pair (bores 30/60 mm).

    Marked slow: importing ross takes ~12 s and its Mesh evaluates 1000 positions (~5 s).
    """
    gear_element, mesh_class, material = _ross()
    steel = material(name="gear_steel", rho=7850.0, E=2.06e11, Poisson=0.3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pinion = gear_element(n=0, material=steel, width=0.025, bore_diameter=0.030,
                              module=0.004, n_teeth=19)
        wheel = gear_element(n=1, material=steel, width=0.025, bore_diameter=0.060,
                             module=0.004, n_teeth=54)
        mesh = mesh_class(pinion, wheel)  # evaluates its TVMS over one mesh period
    ours = GearPair(module_mm=4.0, teeth1=19, teeth2=54, face_width_mm=25.0)
    assert ours.geometry.contact_ratio == pytest.approx(mesh.contact_ratio, rel=1e-9)
    assert hertz_stiffness(ours) == pytest.approx(mesh.hertzian_stiffness, rel=1e-12)
    ross_mean = float(np.mean(mesh.stiffness_range))
    assert average_mesh_stiffness(ours) == pytest.approx(ross_mean, rel=0.15)
