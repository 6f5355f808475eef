"""Mesh stiffness of an involute spur-gear pair (paper §6, eqs. 15–20).

What this module computes, and from where:

* **Geometry** of an external spur pair with addendum modification (profile shift) x1, x2:
  reference and base radii, operating pressure angle from the involute relation
  ``inv αw = inv α + 2 tan α (x1 + x2)/(z1 + z2)``, operating centre distance, tip radii
  with the usual tip shortening ``k = (x1 + x2) − (a_w − a)/m`` (ISO 21771 / DIN 3960),
  path of contact, transverse contact ratio, and the single/double-tooth-contact zones.
  Positions on the line of action are measured in mm from T1, the point where the line of
  action touches the pinion's base circle; a contact at distance s lies on radius
  ``sqrt(r_b1² + s²)`` of the pinion and ``sqrt(r_b2² + (T1T2 − s)²)`` of the gear.
* **Hertzian contact stiffness**, eq. 15: ``k_h = π E b / (4 (1 − ν²))`` (Yang & Sun 1985, as
  quoted by Kuang & Lin and by the paper). Constant along the path of contact.
* **Tooth bending stiffness**, eqs. 16–18: ``k = b · k̄`` with the Kuang & Yang (1992)
  finite-element curve fit ``k̄ = (A0 + A1 x) + (A2 + A3 x)(r − R)/((1 + x) m)`` in N/µm/mm
  (r, R, m in mm; R is the reference pitch radius m·z/2). The coefficients are cubic
  polynomials in the tooth number N, see :data:`KUANG_YANG_COEFFICIENTS`.
* **Mesh stiffness**, eqs. 19–20: per tooth pair ``K = (1/k1 + 1/k2 + 1/k_h)⁻¹``; with the
  two pairs A and B in contact ``K = K_A + K_B``, and ``K_B = 0`` in single-tooth contact.
  Over one mesh cycle (pinion rotation 2π/z1) the averaged value (Shing 1994) is
  ``K̄ = (1/p_b) ∫_A^E K_pair(s) ds`` (p_b: base pitch), computed by Gauss–Legendre.
* **Cross-check** against ISO 6336-1:2019 method B: single stiffness
  ``c' = c'_th C_M C_R C_B cos β`` with ``1/c'_th = q'`` from the standard's regression
  (C1 … C9), and mesh stiffness ``c_γα = c' (0.75 ε_α + 0.25)``; both in N/µm/mm.

Provenance of A0 … A3. Kuang, J. H. & Yang, Y. T. (1992) "An estimate of mesh stiffness and
load sharing ratio of a spur gear pair", Proc. ASME 6th Int. Power Transmission and Gearing
Conf., DE-Vol. 43-1, pp. 1–9, fitted the FE tooth stiffness as the cubic polynomials below;
the paper (§6) points to Kuang & Lin (1997) for them, and they are printed again in
Kuang, J. H. & Lin, A. D. (2001) "The effect of tooth wear on the vibration spectrum of a
spur gear pair", J. Vib. Acoust. 123(3):311–317. The values here were transcribed from that
secondary literature; no copy of either paper was reachable while writing this module, so
they were *checked*, not verified against a scan: for the paper's pair they give a single
pair stiffness of 12.9 N/µm/mm at the pitch point against ISO 6336-1's c'_th = 16.9 and
c' = 13.2 N/µm/mm, and a mean mesh stiffness 1.4 % below ISO's c_γα. For the unshifted
19/54 pair the mean is 3 % above the potential-energy TVMS of ``ross-rotordynamics``
(``GearElementTVMS``, Ma et al. 2014 with the Sainsot et al. 2004 foundation term) with
30/60 mm bores; ross's value depends on the bores (ours is 5 % below to 52 % above it for
bores between 35/80 and 20/30 mm). The cubic is used only for 12 ≤ N ≤ 100 teeth: past
100 it grows without bound (A0 = 45.8 at N = 120, 113.7 at N = 150). This limit is ours;
the range of the source's FE study could not be checked. A later search for an independent
copy of the table (public source code, documentation and web pages reachable to this
project, searched for the coefficient values themselves, e.g. 1.612, 0.02916, 0.0001553,
17.060, 0.7289, and for the Kuang–Yang fit by name) found none: no public implementation
or page quoting A0 … A3 turned up, so the values remain unverified against a second source.

Units: lengths in mm at the interface (as in the paper), stiffness in N/m unless a name says
``per_width`` (then N/µm/mm, i.e. N/µm per mm of face width), angles in rad unless ``_deg``.
Bad inputs raise :class:`gpjax.ConfigError` with a one-line message naming the fix.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from .._errors import ConfigError

#: Kuang & Yang (1992) coefficients: row i gives A_i = c0 + c1 N + c2 N² + c3 N³, in N/µm/mm.
KUANG_YANG_COEFFICIENTS = np.array([
    [3.867, 1.612, -0.02916, 0.0001553],     # A0
    [17.060, 0.7289, -0.01728, 0.0000999],   # A1
    [2.637, -1.222, 0.02217, -0.0001179],    # A2
    [-6.330, -1.033, 0.02068, -0.0001130],   # A3
])
#: Tooth numbers for which the Kuang & Yang cubic is used (our limit, see the module doc).
KUANG_YANG_TEETH = (12, 100)
#: ISO 6336-1:2019 method B regression for q' (mm·µm/N), C1 … C9.
ISO6336_Q_COEFFICIENTS = (0.04723, 0.15551, 0.25791, -0.00635, -0.11654, -0.00193,
                          -0.24188, 0.00529, 0.00182)
#: ISO 6336-1 theoretical-to-real correction C_M for solid spur gears.
ISO6336_CM = 0.8
#: Basic-rack dedendum h_fP/m (addendum 1 plus root clearance 0.25) assumed for ISO's C_B.
DEDENDUM_COEFFICIENT = 1.25

_POSITION_TOLERANCE_MM = 1e-9


def _involute(angle: float) -> float:
    return math.tan(angle) - angle


def _inverse_involute(value: float, start: float) -> float:
    angle = start
    for _ in range(50):
        step = (_involute(angle) - value) / math.tan(angle) ** 2
        angle -= step
        if abs(step) < 1e-15:
            break
    return angle


@dataclasses.dataclass(frozen=True)
class MeshGeometry:
    """Geometry of the meshing pair; lengths in mm, angles in rad unless ``_deg``.

    Positions ``s`` on the line of action are measured from T1 (tangent point on the pinion's
    base circle) towards T2; the pinion drives, so contact runs from A (start of active
    profile, gear tip) to E (pinion tip). B = E − p_b and D = A + p_b bound the
    single-tooth-contact zone [B, D]; C is the pitch point.
    """

    pitch_radius_mm: tuple[float, float]
    base_radius_mm: tuple[float, float]
    tip_radius_mm: tuple[float, float]
    pressure_angle_deg: float
    operating_pressure_angle_deg: float
    center_distance_mm: float
    operating_center_distance_mm: float
    tip_shortening: float
    line_of_action_mm: float
    base_pitch_mm: float
    start_of_contact_mm: float
    end_of_contact_mm: float
    pitch_point_mm: float
    mesh_period_rad: float

    @property
    def operating_pitch_radius_mm(self) -> tuple[float, float]:
        """Operating (rolling) pitch radii r_b / cos α_w (mm); the paper's "kinematic radius"."""
        cos_w = math.cos(math.radians(self.operating_pressure_angle_deg))
        return (self.base_radius_mm[0] / cos_w, self.base_radius_mm[1] / cos_w)

    @property
    def path_of_contact_mm(self) -> float:
        """Length of the path of contact g_α = AE (mm)."""
        return self.end_of_contact_mm - self.start_of_contact_mm

    @property
    def contact_ratio(self) -> float:
        """Transverse contact ratio ε_α = g_α / p_b."""
        return self.path_of_contact_mm / self.base_pitch_mm

    @property
    def lowest_single_contact_mm(self) -> float:
        """Point B = E − p_b: single-tooth contact starts here (mm from T1)."""
        return self.end_of_contact_mm - self.base_pitch_mm

    @property
    def highest_single_contact_mm(self) -> float:
        """Point D = A + p_b: single-tooth contact ends here (mm from T1)."""
        return self.start_of_contact_mm + self.base_pitch_mm

    @property
    def zones_mm(self) -> dict[str, tuple[float, float]]:
        """The contact zones on the line of action: two double zones and the single zone."""
        a, b = self.start_of_contact_mm, self.lowest_single_contact_mm
        d, e = self.highest_single_contact_mm, self.end_of_contact_mm
        return {"double_approach": (a, b), "single": (b, d), "double_recess": (d, e)}

    def radii_at(self, position_mm) -> tuple[np.ndarray, np.ndarray]:
        """Contact radii (pinion, gear) in mm of points on the line of action (mm from T1)."""
        s = np.asarray(position_mm, dtype=np.float64)
        rb1, rb2 = self.base_radius_mm
        return np.hypot(rb1, s), np.hypot(rb2, self.line_of_action_mm - s)


@dataclasses.dataclass(frozen=True, kw_only=True)
class GearPair:
    """An external involute spur-gear pair; gear 1 (the pinion) drives.

    Attributes:
        module_mm: module m (mm), > 0.
        teeth1, teeth2: tooth numbers z1 (pinion) and z2 (gear), integers ≥ 5.
        x1, x2: addendum-modification (profile-shift) coefficients, −1 < x < 1.
        face_width_mm: face width b (mm), > 0.
        pressure_angle_deg: reference pressure angle α (deg), 10 … 35.
        youngs_modulus_pa: Young's modulus E (Pa), > 0; both gears are the same material.
        poisson: Poisson's ratio ν, 0 ≤ ν < 0.5.
        addendum_coefficient: addendum h_a*/m of the basic rack, 0 < h_a* ≤ 2.

    Construction raises :class:`ConfigError` for a bad value, and for a pair that cannot
    mesh: contact ratio below 1, or involute interference (a tip reaching below the mating
    base circle).
    """

    module_mm: float
    teeth1: int
    teeth2: int
    x1: float = 0.0
    x2: float = 0.0
    face_width_mm: float
    pressure_angle_deg: float = 20.0
    youngs_modulus_pa: float = 2.06e11
    poisson: float = 0.3
    addendum_coefficient: float = 1.0

    def __post_init__(self) -> None:
        _positive("module_mm", self.module_mm)
        _positive("face_width_mm", self.face_width_mm)
        _positive("youngs_modulus_pa", self.youngs_modulus_pa)
        for name in ("teeth1", "teeth2"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 5:
                raise ConfigError(f"{name} must be an integer >= 5, got {value!r}")
        for name in ("x1", "x2"):
            value = _finite(name, getattr(self, name))
            if not -1.0 < value < 1.0:
                raise ConfigError(f"{name} must lie in (-1, 1) (addendum modification "
                                  f"coefficient), got {value!r}")
        if not 10.0 <= _finite("pressure_angle_deg", self.pressure_angle_deg) <= 35.0:
            raise ConfigError("pressure_angle_deg must lie in [10, 35] degrees, got "
                              f"{self.pressure_angle_deg!r}")
        if not 0.0 <= _finite("poisson", self.poisson) < 0.5:
            raise ConfigError(f"poisson must lie in [0, 0.5), got {self.poisson!r}")
        if not 0.0 < _finite("addendum_coefficient", self.addendum_coefficient) <= 2.0:
            raise ConfigError("addendum_coefficient must lie in (0, 2], got "
                              f"{self.addendum_coefficient!r}")
        geometry = _build_geometry(self)
        if geometry.start_of_contact_mm < -_POSITION_TOLERANCE_MM or (
                geometry.end_of_contact_mm > geometry.line_of_action_mm + _POSITION_TOLERANCE_MM):
            raise ConfigError("involute interference: a tip reaches below the mating base "
                              "circle; increase the pinion's x1 or its tooth number")
        if geometry.contact_ratio < 1.0:
            raise ConfigError(f"contact ratio {geometry.contact_ratio:.3f} < 1: the teeth lose "
                              "contact; increase the addendum coefficient or the tooth numbers")
        object.__setattr__(self, "_geometry", geometry)

    @classmethod
    def paper(cls) -> "GearPair":
        """The paper's pair (§4): m = 4 mm, z = 19/54, x = ±0.228, b = 25 mm, β = 0, steel."""
        return cls(module_mm=4.0, teeth1=19, teeth2=54, x1=0.228, x2=-0.228,
                   face_width_mm=25.0)

    @property
    def geometry(self) -> MeshGeometry:
        """The pair's :class:`MeshGeometry` (computed once, on construction)."""
        return self._geometry  # type: ignore[attr-defined]

    @property
    def teeth(self) -> tuple[int, int]:
        return (int(self.teeth1), int(self.teeth2))

    @property
    def x(self) -> tuple[float, float]:
        return (float(self.x1), float(self.x2))


def _finite(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(value):
        raise ConfigError(f"{name} must be a finite number, got {value!r}")
    return float(value)


def _positive(name: str, value: Any) -> None:
    if _finite(name, value) <= 0.0:
        raise ConfigError(f"{name} must be positive, got {value!r}")


def _build_geometry(pair: GearPair) -> MeshGeometry:
    m = float(pair.module_mm)
    z1, z2 = int(pair.teeth1), int(pair.teeth2)
    alpha = math.radians(pair.pressure_angle_deg)
    r1, r2 = m * z1 / 2.0, m * z2 / 2.0
    rb1, rb2 = r1 * math.cos(alpha), r2 * math.cos(alpha)
    involute_w = _involute(alpha) + 2.0 * math.tan(alpha) * (pair.x1 + pair.x2) / (z1 + z2)
    alpha_w = alpha if pair.x1 + pair.x2 == 0.0 else _inverse_involute(involute_w, alpha)
    a = r1 + r2
    a_w = (rb1 + rb2) / math.cos(alpha_w)
    tip_shortening = (pair.x1 + pair.x2) - (a_w - a) / m
    ha = pair.addendum_coefficient
    ra1 = r1 + m * (ha + pair.x1 - tip_shortening)
    ra2 = r2 + m * (ha + pair.x2 - tip_shortening)
    line = a_w * math.sin(alpha_w)
    start = line - math.sqrt(max(ra2 ** 2 - rb2 ** 2, 0.0))
    end = math.sqrt(max(ra1 ** 2 - rb1 ** 2, 0.0))
    return MeshGeometry(
        pitch_radius_mm=(r1, r2), base_radius_mm=(rb1, rb2), tip_radius_mm=(ra1, ra2),
        pressure_angle_deg=float(pair.pressure_angle_deg),
        operating_pressure_angle_deg=math.degrees(alpha_w), center_distance_mm=a,
        operating_center_distance_mm=a_w, tip_shortening=tip_shortening,
        line_of_action_mm=line, base_pitch_mm=math.pi * m * math.cos(alpha),
        start_of_contact_mm=start, end_of_contact_mm=end, pitch_point_mm=rb1 * math.tan(alpha_w),
        mesh_period_rad=2.0 * math.pi / z1)


def hertz_stiffness(pair: GearPair, *, per_unit_width: bool = False) -> float:
    """Hertzian contact stiffness, eq. 15: k_h = π E b / (4 (1 − ν²)).

    Returns N/m, or N/µm/mm with ``per_unit_width=True``.
    """
    per_width_n_per_m2 = math.pi * pair.youngs_modulus_pa / (4.0 * (1.0 - pair.poisson ** 2))
    if per_unit_width:
        return per_width_n_per_m2 * 1e-9
    return per_width_n_per_m2 * pair.face_width_mm * 1e-3


def kuang_yang_coefficients(teeth: int) -> tuple[float, float, float, float]:
    """A0, A1, A2, A3 (N/µm/mm) of eq. 18 for a gear with ``teeth`` teeth.

    Raises :class:`ConfigError` outside 12 ≤ N ≤ 100, where the cubic fit is not used.
    """
    low, high = KUANG_YANG_TEETH
    if not low <= teeth <= high:
        raise ConfigError(f"the Kuang-Yang bending-stiffness fit is used for {low} <= N <= "
                          f"{high} teeth, got N = {teeth}; choose a pair within that range")
    powers = np.array([1.0, teeth, teeth ** 2, teeth ** 3], dtype=np.float64)
    a0, a1, a2, a3 = (float(v) for v in KUANG_YANG_COEFFICIENTS @ powers)
    return a0, a1, a2, a3


def bending_stiffness(pair: GearPair, gear: int, radius_mm, *, per_unit_width: bool = False):
    """Tooth bending stiffness of gear 1 or 2 loaded at radius r (mm), eqs. 16–18.

    ``k̄ = (A0 + A1 x) + (A2 + A3 x)(r − R)/((1 + x) m)`` (N/µm/mm), ``k = b · k̄``.
    Returns N/m (or N/µm/mm with ``per_unit_width=True``); a float for a scalar radius, an
    array otherwise. Raises :class:`ConfigError` if ``gear`` is not 1 or 2, if a radius lies
    off the flank between the base and tip circles, or if the tooth number is outside the
    fit's range (see :func:`kuang_yang_coefficients`).
    """
    if gear not in (1, 2):
        raise ConfigError(f"gear must be 1 (pinion) or 2 (gear), got {gear!r}")
    index = gear - 1
    geometry = pair.geometry
    radius = np.asarray(radius_mm, dtype=np.float64)
    base, tip = geometry.base_radius_mm[index], geometry.tip_radius_mm[index]
    if np.any(~np.isfinite(radius)) or np.any(radius < base - _POSITION_TOLERANCE_MM) or \
            np.any(radius > tip + _POSITION_TOLERANCE_MM):
        raise ConfigError(f"contact radius must lie on the flank of gear {gear}, between its "
                          f"base radius {base:.4f} mm and tip radius {tip:.4f} mm")
    a0, a1, a2, a3 = kuang_yang_coefficients(pair.teeth[index])
    x = pair.x[index]
    m = float(pair.module_mm)
    k_bar = (a0 + a1 * x) + (a2 + a3 * x) * (radius - geometry.pitch_radius_mm[index]) / (
        (1.0 + x) * m)
    value = k_bar if per_unit_width else k_bar * pair.face_width_mm * 1e6
    return float(value) if value.ndim == 0 else value


def pair_stiffness(pair: GearPair, position_mm):
    """Stiffness of one tooth pair in contact at ``position_mm`` (mm from T1), eq. 19, N/m.

    ``K = (1/k1 + 1/k2 + 1/k_h)⁻¹`` with k1, k2 the bending stiffnesses at the contact radii.
    """
    r1, r2 = pair.geometry.radii_at(position_mm)
    k1 = bending_stiffness(pair, 1, r1)
    k2 = bending_stiffness(pair, 2, r2)
    value = 1.0 / (1.0 / k1 + 1.0 / k2 + 1.0 / hertz_stiffness(pair))
    return float(value) if np.ndim(value) == 0 else value


@dataclasses.dataclass(frozen=True)
class ContactPoints:
    """Where the two possible tooth pairs touch at given pinion angles.

    Pair A entered contact at A at angle 0 of the cycle; pair B leads it by one base pitch
    and is in contact only where ``double`` is true. Lengths in mm (positions from T1).
    """

    angle_rad: np.ndarray
    position_a_mm: np.ndarray
    position_b_mm: np.ndarray
    double: np.ndarray
    radius1_a_mm: np.ndarray
    radius2_a_mm: np.ndarray
    radius1_b_mm: np.ndarray
    radius2_b_mm: np.ndarray


def contact_points(pair: GearPair, angles_rad) -> ContactPoints:
    """Contact positions and radii at pinion rotation angles (rad).

    Angle 0 is the instant a tooth pair enters contact at A (start of the active profile);
    angles are taken modulo the mesh period 2π/z1, and the contact moves r_b1 per radian.
    Where pair B is out of contact its position and radii are NaN.
    """
    geometry = pair.geometry
    angles = np.asarray(angles_rad, dtype=np.float64)
    rb1 = geometry.base_radius_mm[0]
    rolled = np.mod(angles, geometry.mesh_period_rad) * rb1
    position_a = geometry.start_of_contact_mm + rolled
    leading = position_a + geometry.base_pitch_mm
    double = leading <= geometry.end_of_contact_mm + _POSITION_TOLERANCE_MM
    position_b = np.where(double, np.minimum(leading, geometry.end_of_contact_mm), np.nan)
    radius1_a, radius2_a = geometry.radii_at(position_a)
    radius1_b, radius2_b = geometry.radii_at(position_b)
    return ContactPoints(angle_rad=angles, position_a_mm=position_a, position_b_mm=position_b,
                         double=double, radius1_a_mm=radius1_a, radius2_a_mm=radius2_a,
                         radius1_b_mm=radius1_b, radius2_b_mm=radius2_b)


@dataclasses.dataclass(frozen=True)
class MeshStiffness:
    """K_A, K_B and K = K_A + K_B (N/m) at the angles of ``points`` (eqs. 19–20)."""

    points: ContactPoints
    k_a: np.ndarray
    k_b: np.ndarray
    k: np.ndarray


def mesh_cycle_angles(pair: GearPair, *, samples: int = 400) -> np.ndarray:
    """``samples`` equally spaced pinion angles (rad) over one mesh cycle [0, 2π/z1)."""
    if isinstance(samples, bool) or not isinstance(samples, int) or samples < 2:
        raise ConfigError(f"samples must be an integer >= 2, got {samples!r}")
    return np.linspace(0.0, pair.geometry.mesh_period_rad, samples, endpoint=False)


def mesh_stiffness(pair: GearPair, angles_rad) -> MeshStiffness:
    """Mesh stiffness along the mesh cycle at pinion angles (rad), eqs. 19–20.

    K_A is pair A's stiffness, K_B pair B's (0 in single-tooth contact), K = K_A + K_B, all
    in N/m. Angle convention as in :func:`contact_points`.
    """
    points = contact_points(pair, angles_rad)
    k_a = np.asarray(pair_stiffness(pair, points.position_a_mm), dtype=np.float64)
    safe_b = np.where(points.double, points.position_b_mm, points.position_a_mm)
    k_b = np.where(points.double, pair_stiffness(pair, safe_b), 0.0)
    return MeshStiffness(points=points, k_a=k_a, k_b=k_b, k=k_a + k_b)


def _zone_average(pair: GearPair, start: float, end: float, nodes: int = 64) -> float:
    """Mean of the single-pair stiffness over [start, end] on the line of action (N/m)."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    s = 0.5 * (end - start) * x + 0.5 * (end + start)
    return float(0.5 * np.sum(w * pair_stiffness(pair, s)))


def average_mesh_stiffness(pair: GearPair) -> float:
    """Mesh stiffness averaged over one mesh cycle (N/m): (1/p_b) ∫_A^E K_pair(s) ds."""
    geometry = pair.geometry
    start, end = geometry.start_of_contact_mm, geometry.end_of_contact_mm
    return _zone_average(pair, start, end) * (end - start) / geometry.base_pitch_mm


def iso6336_stiffness(pair: GearPair) -> dict[str, float]:
    """ISO 6336-1 method B single and mesh stiffness, an independent cross-check.

    Returns ``c_prime_th``, ``c_prime`` and ``c_gamma_alpha`` in N/µm/mm and ``c_prime_n_per_m``
    and ``c_gamma_alpha_n_per_m`` (× face width) in N/m, for solid gears (C_R = 1) and
    C_M = 0.8. Raises :class:`ConfigError` outside the standard's range x1 ≥ x2,
    −0.5 ≤ x1 + x2 ≤ 2.
    """
    x1, x2 = pair.x
    if x1 < x2 or not -0.5 <= x1 + x2 <= 2.0:
        raise ConfigError("ISO 6336-1 method B needs x1 >= x2 and -0.5 <= x1 + x2 <= 2; "
                          "use a pair inside that range for the cross-check")
    c = ISO6336_Q_COEFFICIENTS
    z1, z2 = pair.teeth
    q = (c[0] + c[1] / z1 + c[2] / z2 + c[3] * x1 + c[4] * x1 / z1 + c[5] * x2
         + c[6] * x2 / z2 + c[7] * x1 ** 2 + c[8] * x2 ** 2)
    c_th = 1.0 / q
    c_b = (1.0 + 0.5 * (1.2 - DEDENDUM_COEFFICIENT)) * (
        1.0 - 0.02 * (20.0 - pair.pressure_angle_deg))
    c_prime = c_th * ISO6336_CM * c_b
    c_gamma = c_prime * (0.75 * pair.geometry.contact_ratio + 0.25)
    width_m_um = pair.face_width_mm * 1e6
    return {"c_prime_th": c_th, "c_prime": c_prime, "c_gamma_alpha": c_gamma,
            "c_prime_n_per_m": c_prime * width_m_um, "c_gamma_alpha_n_per_m": c_gamma * width_m_um}


def torsional_stiffness(pair: GearPair, k_n_per_m, *, per_degree: bool = False):
    """Mesh stiffness seen at the pinion as a torsional stiffness: K · r_b1².

    Returns N·m/rad, or N·m/deg (× π/180) with ``per_degree=True``, which is the unit of the
    paper's K1 (eq. 14, φ in degrees).
    """
    rb1_m = pair.geometry.base_radius_mm[0] * 1e-3
    value = np.asarray(k_n_per_m, dtype=np.float64) * rb1_m ** 2
    if per_degree:
        value = value * math.pi / 180.0
    return float(value) if value.ndim == 0 else value


def stiffness_report(pair: GearPair, *, samples: int = 2000) -> dict[str, Any]:
    """Figures for a pair: geometry, k_h, K_A/K_B/K at representative points, min/max/mean K.

    Representative cycle positions (pinion angle from the start of the cycle, pair A at):
    ``A`` (cycle start; pair B at D, double contact), ``B_double`` (pair A at B, pair B at E:
    last instant of double contact), ``B_single`` (just past B: single contact), ``C`` (pitch
    point) and ``D_single`` (just before D: last instant of single contact). Stiffness in N/m
    unless named ``per_width`` (N/µm/mm); torsional values are K·r_b1² in N·m/rad and
    N·m/deg. ``K1_interval_N_m_per_deg`` is [min, max] of the torsional mesh stiffness over
    the cycle: the range this mesh model implies for the paper's K1 (eq. 14) if φ were the
    pinion's mesh deflection alone; ``k1_interval_N_per_deg`` is that interval divided by the
    pinion's operating pitch radius r1 (m), the GP constant k1 of eq. 11 under the paper's
    K1 := r1 k1.
    """
    geometry = pair.geometry
    rb1 = geometry.base_radius_mm[0]
    start = geometry.start_of_contact_mm
    b_angle = (geometry.lowest_single_contact_mm - start) / rb1
    nudge = 1e-9 * geometry.mesh_period_rad
    positions = {
        "A": 0.0,
        "B_double": b_angle,
        "B_single": b_angle + nudge,
        "C": (geometry.pitch_point_mm - start) / rb1,
        "D_single": geometry.mesh_period_rad - nudge,
    }
    at = mesh_stiffness(pair, np.array(list(positions.values())))
    points = {}
    for i, name in enumerate(positions):
        points[name] = {"angle_rad": float(at.points.angle_rad[i]),
                        "position_mm": float(at.points.position_a_mm[i]),
                        "double_contact": bool(at.points.double[i]),
                        "K_A": float(at.k_a[i]), "K_B": float(at.k_b[i]), "K": float(at.k[i])}
    cycle = mesh_stiffness(pair, mesh_cycle_angles(pair, samples=samples))
    width_m_um = pair.face_width_mm * 1e6
    single = ~cycle.points.double
    k_min, k_max = float(np.min(cycle.k)), float(np.max(cycle.k))
    k_mean = average_mesh_stiffness(pair)
    torsion = {name: torsional_stiffness(pair, value) for name, value in
               (("min", k_min), ("max", k_max), ("mean", k_mean))}
    torsion_deg = {name: torsional_stiffness(pair, value, per_degree=True) for name, value in
                   (("min", k_min), ("max", k_max), ("mean", k_mean))}
    r1_m = geometry.operating_pitch_radius_mm[0] * 1e-3
    try:
        iso = iso6336_stiffness(pair)
    except ConfigError:
        iso = None
    return {
        "pair": dataclasses.asdict(pair),
        "pitch_radius_mm": geometry.pitch_radius_mm,
        "base_radius_mm": geometry.base_radius_mm,
        "tip_radius_mm": geometry.tip_radius_mm,
        "operating_pressure_angle_deg": geometry.operating_pressure_angle_deg,
        "base_pitch_mm": geometry.base_pitch_mm,
        "path_of_contact_mm": geometry.path_of_contact_mm,
        "contact_ratio": geometry.contact_ratio,
        "zones_mm": geometry.zones_mm,
        "k_h": hertz_stiffness(pair),
        "k_h_per_width": hertz_stiffness(pair, per_unit_width=True),
        "points": points,
        "K_min": k_min, "K_max": k_max, "K_mean": k_mean,
        "K_mean_single": float(np.mean(cycle.k[single])),
        "K_mean_double": float(np.mean(cycle.k[~single])),
        "K_mean_per_width": k_mean / width_m_um,
        "torsional_N_m_per_rad": torsion,
        "torsional_N_m_per_deg": torsion_deg,
        "K1_interval_N_m_per_deg": (torsion_deg["min"], torsion_deg["max"]),
        "k1_interval_N_per_deg": (torsion_deg["min"] / r1_m, torsion_deg["max"] / r1_m),
        "iso6336": iso,
    }
