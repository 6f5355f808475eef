"""Two-degree-of-freedom gear-pair model (paper §6, eqs. 21–22) and its 1-DOF reduction (eq. 23).

The 2-DOF model is the torsional gear pair of Parey & Tandon (2003) as printed in the paper:
two rigid disks (inertias J1, J2, base radii r1, r2) coupled along the line of action by the
mesh spring k_m (constant or time-varying, e.g. from :mod:`gpjax.gear._stiffness`) and the
mesh damper c_m, excited by the gear errors e1(t), e2(t) through the coefficients c1, c2, k1,
k2, by the input torque T1(t) on the pinion and the output (load) torque T2(t) on the gear.
With the relative displacement along the line of action ``δ = r1 Θ1 − r2 Θ2`` and the mesh
force ``F = c_m δ' + k_m δ − (c1 e1' + c2 e2' + k1 e1 + k2 e2)``::

    J1 Θ1'' = T1 − r1 F                                   (eq. 21)
    J2 Θ2'' = r2 F − T2                                   (eq. 22)

Eq. 21 is exactly the paper's. In eq. 22 the paper prints the error terms with the same sign
as in eq. 21 (``− r2 c1 e1' …``); that would make the error act on the two gears with
torques of the same sense, violating action and reaction, so the gear here receives the
reaction of the pinion's mesh force (``+ r2 c1 e1' …`` on the left of eq. 22). The two forms
coincide in the limit J2 → ∞ that eq. 23 rests on.

Reduction to eq. 23. Let ``φ1 = Θ1 − (r2/r1) Θ2`` be the pinion's angular displacement
relative to the gear (rad) and ``φ = r1 φ1 = δ`` the corresponding displacement along the
line of action (m). If the gear does not move dynamically (assumption 1: its shaft is much
stiffer than the driving shaft, or assumption 3: J2 ≫ J1, so Θ2'' → 0 and Θ1'' = φ1''), the
mesh damping is negligible (assumption 2: c_m = 0) and the gear errors vanish (assumption 4:
e1 = e2 = 0), eq. 21 becomes::

    J1 φ1'' + r1 k_m φ = T1,    φ = r1 φ1                 (eq. 23)

which is the paper's eq. 23 read with φ1 (angle) in the inertia term and φ (displacement)
in the stiffness term. It is driven by the input torque T1 alone: T2 only accelerates the
gear, which the reduction holds still. How far J2 must exceed J1 is set by the effective
inertia ratio ``μ = (J1/r1²)/(J2/r2²)``: the relative mode sees the stiffness
``k_m (r1²/J1)(1 + μ)``, so the 1-DOF frequency is off by a factor ``sqrt(1 + μ)``.

Integration: diffrax's Tsit5, stepped at a fixed step inside ``jax.lax.scan`` (this compiles
in about a second, ``diffeqsolve`` in several), float64. The step is at most ``dt`` (default
1/64 of the shortest undamped period of the relative mode), shortened so that the output
times fall on steps. Torques, errors and a time-varying k_m are functions of time t (s)
written with ``jax.numpy`` (they are traced; compiled solves are reused while the same
function objects are passed); numbers are taken as constants. The error rates e1', e2' are
the forward-mode derivatives of e1, e2.

Units: SI throughout (kg·m², m, N/m, N·s/m, N·m, rad, s). Invalid settings raise
:class:`gpjax.ConfigError` with a one-line message.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Callable, Union

import jax
import jax.numpy as jnp
import numpy as np

from .._errors import ConfigError
from .._integrate import enable_float64
from ._stiffness import GearPair, average_mesh_stiffness, mesh_cycle_angles, mesh_stiffness


#: A constant, or a jax-traceable function of time t (s).
Signal = Union[float, Callable[[jax.Array], jax.Array]]

#: Fixed steps per shortest undamped period of the relative mode (default step size).
STEPS_PER_PERIOD = 64
#: Points at which a time-varying k_m is sampled to find its maximum (default step size).
STIFFNESS_PROBES = 4097
#: The most integration steps a single simulation may take.
MAX_STEPS = 2_000_000


@dataclasses.dataclass(frozen=True, kw_only=True)
class TwoDofGearPair:
    """Parameters of eqs. 21–22 (SI units).

    Attributes:
        J1, J2: mass moments of inertia of pinion and gear (kg·m²), > 0; ``J2=math.inf``
            holds the gear's acceleration at zero (rigid/clamped gear side).
        r1, r2: base radii (m), > 0.
        k_m: mesh stiffness (N/m): a positive number or a function of t.
        c_m: mesh damping (N·s/m), >= 0.
        T1, T2: input torque on the pinion and output torque on the gear (N·m).
        e1, e2: gear errors along the line of action (m).
        c1, c2: error damping coefficients (N·s/m); k1, k2: error stiffness coefficients (N/m).
    """

    J1: float
    J2: float
    r1: float
    r2: float
    k_m: Signal
    c_m: float = 0.0
    T1: Signal = 0.0
    T2: Signal = 0.0
    e1: Signal = 0.0
    e2: Signal = 0.0
    c1: float = 0.0
    c2: float = 0.0
    k1: float = 0.0
    k2: float = 0.0

    def __post_init__(self) -> None:
        for name in ("J1", "r1", "r2"):
            if _number(name, getattr(self, name)) <= 0.0 or not math.isfinite(getattr(self, name)):
                raise ConfigError(f"{name} must be a positive finite number, got "
                                  f"{getattr(self, name)!r}")
        if _number("J2", self.J2) <= 0.0 or math.isnan(self.J2):
            raise ConfigError(f"J2 must be positive (math.inf for a clamped gear), got {self.J2!r}")
        if _number("c_m", self.c_m) < 0.0 or not math.isfinite(self.c_m):
            raise ConfigError(f"c_m must be a finite number >= 0, got {self.c_m!r}")
        for name in ("c1", "c2", "k1", "k2"):
            if not math.isfinite(_number(name, getattr(self, name))):
                raise ConfigError(f"{name} must be a finite number, got {getattr(self, name)!r}")
        for name in ("k_m", "T1", "T2", "e1", "e2"):
            value = getattr(self, name)
            if not callable(value) and not math.isfinite(_number(name, value)):
                raise ConfigError(f"{name} must be a finite number or a function of t, "
                                  f"got {value!r}")
        if not callable(self.k_m) and self.k_m <= 0.0:
            raise ConfigError(f"k_m must be positive, got {self.k_m!r}")

    @property
    def inertia_ratio(self) -> float:
        """Effective inertia ratio μ = (J1/r1²)/(J2/r2²); 0 for a clamped gear."""
        return (self.J1 / self.r1 ** 2) * (self.r2 ** 2 / self.J2)


@dataclasses.dataclass(frozen=True)
class TwoDofResponse:
    """Solution of eqs. 21–22 at the sample times ``t`` (s).

    ``theta1``, ``theta2`` (rad), ``omega1``, ``omega2`` (rad/s), ``relative_displacement``
    δ = r1 Θ1 − r2 Θ2 (m) and ``relative_angle`` φ1 = δ / r1 (rad).
    """

    t: np.ndarray
    theta1: np.ndarray
    theta2: np.ndarray
    omega1: np.ndarray
    omega2: np.ndarray
    relative_displacement: np.ndarray
    relative_angle: np.ndarray


@dataclasses.dataclass(frozen=True)
class OneDofResponse:
    """Solution of eq. 23 at the sample times ``t`` (s).

    ``phi1``: pinion angle relative to the gear (rad); ``phi1_dot`` (rad/s); ``phi`` = r1 φ1,
    the displacement along the line of action (m), comparable with δ of the 2-DOF model.
    """

    t: np.ndarray
    phi1: np.ndarray
    phi1_dot: np.ndarray
    phi: np.ndarray


def _number(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ConfigError(f"{name} must be a number, got {value!r}")
    return float(value)


def _split(value: Signal) -> tuple[Callable | None, float]:
    """(function, 0.0) for a function of t, (None, value) for a constant."""
    return (value, 0.0) if callable(value) else (None, float(value))


def _evaluate(function: Callable | None, constant: jax.Array, t: jax.Array) -> jax.Array:
    return constant if function is None else function(t)


def _evaluate_rate(function: Callable | None, t: jax.Array) -> jax.Array:
    if function is None:
        return jnp.zeros_like(t)
    return jax.jvp(function, (t,), (jnp.ones_like(t),))[1]


def _two_dof_field(t, y, args):
    """Eqs. 21–22; the functions are static (jit-cache key), the numbers are traced."""
    (j1, inverse_j2, r1, r2, c_m, c1, c2, k1, k2, constants), functions = args
    k_m, torque1, torque2, error1, error2 = (
        _evaluate(f, c, t) for f, c in zip(functions, constants))
    theta1, theta2, omega1, omega2 = y
    delta = r1 * theta1 - r2 * theta2
    delta_dot = r1 * omega1 - r2 * omega2
    excitation = (c1 * _evaluate_rate(functions[3], t) + c2 * _evaluate_rate(functions[4], t)
                  + k1 * error1 + k2 * error2)
    force = c_m * delta_dot + k_m * delta - excitation
    return jnp.stack([omega1, omega2, (torque1 - r1 * force) / j1,
                      (r2 * force - torque2) * inverse_j2])


def _one_dof_field(t, y, args):
    """Eq. 23 in the state (φ1, φ1')."""
    (j1, r1, constants), functions = args
    k_m, torque1 = (_evaluate(f, c, t) for f, c in zip(functions, constants))
    phi1, phi1_dot = y
    return jnp.stack([phi1_dot, (torque1 - r1 * k_m * (r1 * phi1)) / j1])




def _max_stiffness(system: TwoDofGearPair, t_end: float) -> float:
    if not callable(system.k_m):
        return float(system.k_m)
    probes = jnp.linspace(0.0, t_end, STIFFNESS_PROBES)
    values = np.asarray(jax.vmap(system.k_m)(probes))
    if not np.all(np.isfinite(values)) or np.any(values <= 0.0):
        raise ConfigError("k_m(t) must be positive and finite over [0, t_end]")
    return float(np.max(values))


def _step(system: TwoDofGearPair, t_end: float, dt: float | None, *, two_dof: bool) -> float:
    if dt is None:
        compliance = system.r1 ** 2 / system.J1
        if two_dof:
            compliance *= 1.0 + system.inertia_ratio
        omega = math.sqrt(_max_stiffness(system, t_end) * compliance)
        dt = 2.0 * math.pi / omega / STEPS_PER_PERIOD
    elif _number("dt", dt) <= 0.0 or not math.isfinite(dt):
        raise ConfigError(f"dt must be a positive finite number, got {dt!r}")
    if t_end / dt > MAX_STEPS:
        raise ConfigError(f"t_end / dt = {t_end / dt:.3g} steps exceeds {MAX_STEPS}; shorten "
                          "t_end or enlarge dt")
    return dt


def _check_span(t_end: float, samples: int) -> None:
    if _number("t_end", t_end) <= 0.0 or not math.isfinite(t_end):
        raise ConfigError(f"t_end must be a positive finite number of seconds, got {t_end!r}")
    if isinstance(samples, bool) or not isinstance(samples, int) or samples < 2:
        raise ConfigError(f"samples must be an integer >= 2, got {samples!r}")


@functools.cache
def _integrator():
    """The compiled fixed-step Tsit5 integrator (built on first use: importing diffrax costs
    a process that only reads the bundled example ~0.6 s; :func:`gpjax._integrate.rk4_solver`)."""
    import diffrax
    import equinox as eqx

    @eqx.filter_jit
    def integrate(field, args, y0, dt, substeps, samples: int):
        """Fixed-step Tsit5: ``samples − 1`` blocks of ``substeps`` steps; states at block
        ends. ``dt`` and ``substeps`` are traced, so one compilation serves every step size."""
        term = diffrax.ODETerm(field)
        solver = diffrax.Tsit5()
        state0 = solver.init(term, 0.0, dt, y0, args)

        def step(_, carry):
            index, y, state = carry
            t = index * dt
            y, _, _, state, _ = solver.step(term, t, t + dt, y, args, state, made_jump=False)
            return index + 1, y, state

        def block(carry, _):
            carry = jax.lax.fori_loop(0, substeps, step, carry)
            return carry, carry[1]

        _, ys = jax.lax.scan(block, (jnp.asarray(0.0), y0, state0), None, length=samples - 1)
        return jnp.concatenate([y0[None], ys])

    return integrate


def _solve(field, args, y0, t_end: float, dt: float, samples: int):
    substeps = max(1, math.ceil(t_end / ((samples - 1) * dt) - 1e-9))
    step = t_end / ((samples - 1) * substeps)
    ys = _integrator()(field, args, jnp.asarray(y0, dtype=jnp.float64), jnp.asarray(step),
                    jnp.asarray(substeps), samples)
    return np.linspace(0.0, t_end, samples), np.asarray(ys)


def simulate_two_dof(system: TwoDofGearPair, *, t_end: float, dt: float | None = None,
                     theta0: tuple[float, float] = (0.0, 0.0),
                     omega0: tuple[float, float] = (0.0, 0.0),
                     samples: int = 1001) -> TwoDofResponse:
    """Integrate eqs. 21–22 from t = 0 to ``t_end`` (s); returns a :class:`TwoDofResponse`.

    ``theta0``/``omega0`` are the initial angles (rad) and speeds (rad/s) of pinion and gear;
    ``samples`` equally spaced output times; ``dt`` the largest fixed step (s), by default
    1/64 of the shortest undamped period of the relative mode. Raises :class:`ConfigError`
    for a bad span, step or sample count.
    """
    enable_float64()
    _check_span(t_end, samples)
    dt = _step(system, t_end, dt, two_dof=True)
    split = [_split(getattr(system, name)) for name in ("k_m", "T1", "T2", "e1", "e2")]
    functions = tuple(f for f, _ in split)
    constants = jnp.asarray([c for _, c in split])
    inverse_j2 = 0.0 if math.isinf(system.J2) else 1.0 / system.J2
    numbers = jnp.asarray([system.J1, inverse_j2, system.r1, system.r2, system.c_m, system.c1,
                           system.c2, system.k1, system.k2])
    args = ((*numbers, constants), functions)
    y0 = [float(theta0[0]), float(theta0[1]), float(omega0[0]), float(omega0[1])]
    t, ys = _solve(_two_dof_field, args, y0, t_end, dt, samples)
    delta = system.r1 * ys[:, 0] - system.r2 * ys[:, 1]
    return TwoDofResponse(t=t, theta1=ys[:, 0], theta2=ys[:, 1], omega1=ys[:, 2],
                          omega2=ys[:, 3], relative_displacement=delta,
                          relative_angle=delta / system.r1)


def simulate_one_dof(system: TwoDofGearPair, *, t_end: float, dt: float | None = None,
                     phi0: float = 0.0, phi_dot0: float = 0.0,
                     samples: int = 1001) -> OneDofResponse:
    """Integrate the reduced model eq. 23, J1 φ1'' + r1 k_m(t) (r1 φ1) = T1(t).

    Uses J1, r1, k_m and T1 of ``system``; J2, c_m, T2 and the error terms are dropped (the
    four assumptions). ``phi0`` (rad) and ``phi_dot0`` (rad/s) are φ1 and φ1'
    at t = 0; the other options are those of :func:`simulate_two_dof`.
    """
    enable_float64()
    _check_span(t_end, samples)
    dt = _step(system, t_end, dt, two_dof=False)
    split = [_split(system.k_m), _split(system.T1)]
    args = ((jnp.asarray(system.J1), jnp.asarray(system.r1),
             jnp.asarray([c for _, c in split])), tuple(f for f, _ in split))
    t, ys = _solve(_one_dof_field, args, [float(phi0), float(phi_dot0)], t_end, dt, samples)
    return OneDofResponse(t=t, phi1=ys[:, 0], phi1_dot=ys[:, 1], phi=system.r1 * ys[:, 0])


def reduction_error(system: TwoDofGearPair, *, t_end: float, dt: float | None = None,
                    theta0: tuple[float, float] = (0.0, 0.0),
                    omega0: tuple[float, float] = (0.0, 0.0), samples: int = 1001) -> float:
    """Relative RMS difference between the 2-DOF δ(t) and the 1-DOF φ(t) = r1 φ1(t).

    ``‖δ − φ‖_rms / ‖δ‖_rms`` over the ``samples`` output times in [0, t_end]. The 1-DOF run
    starts from the same relative state: φ1(0) = Θ1(0) − (r2/r1) Θ2(0), likewise for the
    speeds. Both runs use the same fixed step (the 2-DOF default unless ``dt`` is given).
    Raises :class:`ConfigError` if δ is identically zero (nothing to compare).
    """
    _check_span(t_end, samples)
    dt = _step(system, t_end, dt, two_dof=True)
    two = simulate_two_dof(system, t_end=t_end, dt=dt, theta0=theta0, omega0=omega0,
                           samples=samples)
    ratio = system.r2 / system.r1
    one = simulate_one_dof(system, t_end=t_end, dt=dt, phi0=theta0[0] - ratio * theta0[1],
                           phi_dot0=omega0[0] - ratio * omega0[1], samples=samples)
    reference = float(np.sqrt(np.mean(two.relative_displacement ** 2)))
    if reference == 0.0:
        raise ConfigError("the 2-DOF relative displacement is identically zero; apply a "
                          "torque or a non-zero initial state")
    return float(np.sqrt(np.mean((two.relative_displacement - one.phi) ** 2)) / reference)


def mesh_stiffness_signal(pair: GearPair, *, pinion_speed_rpm: float, samples: int = 512,
                          phase_rad: float = 0.0) -> Callable[[jax.Array], jax.Array]:
    """Time-varying mesh stiffness k_m(t) (N/m) of ``pair`` at a constant pinion speed.

    k_m(t) = K(Ω t + phase) with K from :func:`~gpjax.gear._stiffness.mesh_stiffness`
    tabulated at ``samples`` angles over one mesh cycle and interpolated periodically
    (jax-traceable). Raises :class:`ConfigError` for a non-positive speed.
    """
    enable_float64()
    if _number("pinion_speed_rpm", pinion_speed_rpm) <= 0.0 or not math.isfinite(
            pinion_speed_rpm):
        raise ConfigError(f"pinion_speed_rpm must be positive, got {pinion_speed_rpm!r}")
    angles = mesh_cycle_angles(pair, samples=samples)
    table = jnp.asarray(mesh_stiffness(pair, angles).k)
    grid = jnp.asarray(angles)
    period = pair.geometry.mesh_period_rad
    speed = pinion_speed_rpm * 2.0 * math.pi / 60.0
    phase = float(phase_rad)
    return lambda t: jnp.interp(speed * t + phase, grid, table, period=period)


#: Paper operating point (§4): pinion speed, mean driving torque, pinion inertia (eq. 14).
PAPER_SPEED_RPM = 900.0
PAPER_TORQUE = 13.0
PAPER_J1 = 7.918e-5


def reduction_scenarios(*, pair: GearPair | None = None, mesh_cycles: float = 1.0,
                        damping_ratio: float = 0.05, error_amplitude_m: float = 1e-6,
                        samples: int = 1001) -> dict[str, float]:
    """Reduction errors (see :func:`reduction_error`) with the assumptions kept and broken.

    Set-up (paper pair and operating point by default): J1 = 7.918e-5 kg·m² (eq. 14),
    r1, r2 the base radii, k_m(t) the pair's mesh stiffness at 900 rpm, T1(t) = 13 N·m plus
    a 1.2 N·m ripple at the mesh frequency, T2 = (r2/r1)·13 N·m (the load that balances
    the mean input), both gears at rest and unloaded at t = 0 (a suddenly applied load),
    simulated over ``mesh_cycles`` mesh periods. Cases (μ: effective inertia ratio):

    * ``assumptions_hold``: clamped gear (J2 = ∞), c_m = 0, no error excitation
      (c1 = c2 = k1 = k2 = 0, which removes the error terms of eqs. 21–22);
    * ``J2_much_larger``: as above but J2 = 10⁴ (r2/r1)² J1, i.e. μ = 10⁻⁴;
    * ``similar_disks``: J2 = J1 (z2/z1)⁴, a geometrically similar gear disk (μ = (z1/z2)²);
    * ``J2_equals_J1``: J2 = J1 (μ = (r2/r1)²; assumption 3 broken);
    * ``mesh_damping``: clamped gear with c_m for ``damping_ratio`` of the relative mode
      (assumption 2 broken);
    * ``gear_errors``: clamped gear with the errors e1 = a sin(2π f_mesh t),
      e2 = (a/2) sin(2π f_gear t), a = ``error_amplitude_m``, switched on through
      k1 = k2 = the mean mesh stiffness (assumption 4 broken).
    """
    pair = GearPair.paper() if pair is None else pair
    rb1, rb2 = (r * 1e-3 for r in pair.geometry.base_radius_mm)
    k_m = mesh_stiffness_signal(pair, pinion_speed_rpm=PAPER_SPEED_RPM)
    k_mean = average_mesh_stiffness(pair)
    shaft_hz = PAPER_SPEED_RPM / 60.0
    mesh_hz = shaft_hz * pair.teeth1
    gear_hz = shaft_hz * pair.teeth1 / pair.teeth2

    def torque(t):
        return PAPER_TORQUE + 1.2 * jnp.cos(2.0 * jnp.pi * mesh_hz * t)

    def error1(t):
        return error_amplitude_m * jnp.sin(2.0 * jnp.pi * mesh_hz * t)

    def error2(t):
        return 0.5 * error_amplitude_m * jnp.sin(2.0 * jnp.pi * gear_hz * t)

    # every case carries the same e1, e2 (one compiled solve); their coefficients switch them
    base = TwoDofGearPair(J1=PAPER_J1, J2=math.inf, r1=rb1, r2=rb2, k_m=k_m, T1=torque,
                          T2=PAPER_TORQUE * rb2 / rb1, e1=error1, e2=error2)
    critical = 2.0 * math.sqrt(k_mean * PAPER_J1 / rb1 ** 2)
    cases = {
        "assumptions_hold": base,
        "J2_much_larger": dataclasses.replace(base, J2=1e4 * (rb2 / rb1) ** 2 * PAPER_J1),
        "similar_disks": dataclasses.replace(
            base, J2=PAPER_J1 * (pair.teeth2 / pair.teeth1) ** 4),
        "J2_equals_J1": dataclasses.replace(base, J2=PAPER_J1),
        "mesh_damping": dataclasses.replace(base, c_m=damping_ratio * critical),
        "gear_errors": dataclasses.replace(base, k1=k_mean, k2=k_mean),
    }
    t_end = mesh_cycles / mesh_hz
    return {name: reduction_error(system, t_end=t_end, samples=samples)
            for name, system in cases.items()}
