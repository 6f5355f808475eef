"""Synthetic systems with a known truth: their equations, constants and excitation.

Each :class:`System` holds its true equations (sympy, one per coordinate, in the symbols
``x, x_dot, x_ddot, u, t`` or ``x1, x2, …`` for chains), its true constants and how it is
excited; :data:`SYSTEMS` is the catalogue (the nine single-coordinate systems of the
physics benchmark, :data:`PHYSICS_SUITE`, two and three masses in a chain with cubic
coupling springs (with and without a ground spring on the last mass), two with dry
friction between them, two driven at the free end with a damper between them, and a
drifting positioning stage in a PD loop). Records are made by :mod:`gpjax._synthetic`.

Units: x in m (rad for the pendulum), u in N (N·m), t in s, constants in SI.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Callable

import numpy as np
import sympy as sp

#: Largest step (s) of the truth integration of the systems with sign(x') or |x'|: half a
#: sample, so that no velocity reversal falls between two steps unseen (halving it
#: changes the response by < 1e-11 relative; tests/test_systems.py).
SIGN_MAX_STEP = 5e-3

T, U = sp.symbols("t u")


def state_symbols(coordinate: str) -> tuple[sp.Symbol, sp.Symbol, sp.Symbol]:
    """(x, x_dot, x_ddot) of a coordinate named ``coordinate``."""
    return sp.symbols(f"{coordinate} {coordinate}_dot {coordinate}_ddot")


@dataclasses.dataclass(frozen=True, kw_only=True)
class Excitation:
    """Band-limited random excitation (a random-phase multisine): ``tones`` sines of equal
    amplitude at frequencies evenly spaced over [``low``, ``high``] Hz, each with a
    uniform random phase, scaled to ``rms`` (input units) on the record's sample grid."""

    low: float
    high: float
    rms: float
    tones: int = 60

    def draw(self, rng: np.random.Generator, time: np.ndarray, scale: float) -> "Multisine":
        """One realisation whose samples on ``time`` (s) have RMS ``scale`` × ``rms``."""
        frequencies = np.linspace(self.low, self.high, self.tones)
        phases = rng.uniform(0.0, 2.0 * np.pi, self.tones)
        unit = Multisine(frequencies=frequencies, phases=phases, amplitude=1.0)
        amplitude = scale * self.rms / float(np.sqrt(np.mean(unit(time) ** 2)))
        return dataclasses.replace(unit, amplitude=amplitude)


@dataclasses.dataclass(frozen=True, kw_only=True)
class Multisine:
    """u(t) = amplitude · Σ sin(2π·f_j·t + φ_j), exact in continuous time (t in s)."""

    frequencies: np.ndarray
    phases: np.ndarray
    amplitude: float

    def __call__(self, t):
        t = np.asarray(t, dtype=np.float64)
        angles = 2.0 * np.pi * np.multiply.outer(t, self.frequencies) + self.phases
        return self.amplitude * np.sin(angles).sum(axis=-1)


@dataclasses.dataclass(frozen=True, kw_only=True)
class StageLoop:
    """The positioning stage's PD loop: force u_k = kp·e_k + kd·(e_k − e_(k−1))/dt (N)
    held for one sample, e = reference − encoder reading (m), encoder ``resolution`` in m;
    the reference is the system's ``excitation`` (its rms in m)."""

    kp: float
    kd: float
    resolution: float


@dataclasses.dataclass(frozen=True, kw_only=True)
class System:
    """A system with a known truth.

    Attributes:
        name: catalogue name.
        description: one line.
        equations: one ``Eq(lhs, rhs)`` per coordinate, constants as symbols.
        constants: constant name -> true value (SI).
        coordinates: response names (x1, x2, … for chains); the input is ``u``.
        sample_rate: samples per second (Hz).
        duration: record length (s).
        excitation: the open-loop input (N), or the loop's reference (m) for the stage.
        max_step: largest truth-integration step (s), ``None`` for none.
        loop: the closed loop of the positioning stage, else ``None``.
    """

    name: str
    description: str
    equations: tuple[sp.Eq, ...]
    constants: dict[str, float]
    coordinates: tuple[str, ...] = ("x",)
    sample_rate: float = 100.0
    duration: float = 20.0
    excitation: Excitation
    max_step: float | None = None
    loop: StageLoop | None = None

    @property
    def time(self) -> np.ndarray:
        """The sample times (s)."""
        return np.arange(int(round(self.duration * self.sample_rate)) + 1) / self.sample_rate

    @property
    def input_interpolation(self) -> str:
        """How the input is defined between samples: ``"hold"`` (stage) or ``"cubic"``."""
        return "hold" if self.loop is not None else "cubic"

    def truth(self) -> tuple[sp.Eq, ...]:
        """The equations with the true constants substituted."""
        values = {sp.Symbol(k): v for k, v in self.constants.items()}
        return tuple(sp.Eq(e.lhs.subs(values), e.rhs.subs(values)) for e in self.equations)

    @functools.cached_property
    def acceleration(self) -> Callable:
        """The numpy right-hand side: ``f(positions, velocities, u, t) -> accelerations``
        (C,) from :meth:`truth`."""
        return accelerations(self.truth(), self.coordinates)


def accelerations(equations, coordinates) -> Callable:
    """``f(positions, velocities, u, t) -> accelerations`` of ``equations`` solved for each
    coordinate's second derivative (linear in it; lambdified with numpy).

    Raises:
        ValueError: an equation is not linear in its second derivative, or it holds other
            symbols than the states, u and t.
    """
    states = [state_symbols(c) for c in coordinates]
    known = {s for x, v, _ in states for s in (x, v)} | {U, T}
    solved = []
    for equation, (_, _, x_ddot) in zip(equations, states):
        residual = sp.expand(equation.lhs - equation.rhs)
        mass = residual.coeff(x_ddot)
        rest = residual - mass * x_ddot
        if mass == 0 or mass.free_symbols or x_ddot in rest.free_symbols:
            raise ValueError(f"equation {equation} is not linear in {x_ddot} with a "
                             "constant non-zero coefficient")
        if not rest.free_symbols <= known:
            raise ValueError(f"equation {equation} holds unknown symbols "
                             f"{sorted(map(str, rest.free_symbols - known))}")
        solved.append(-rest / mass)
    args = [[x for x, _, _ in states], [v for _, v, _ in states], U, T]
    function = sp.lambdify(args, solved, modules="numpy")
    return lambda x, v, u, t: np.array(function(x, v, u, t), dtype=np.float64)


# --- the catalogue ---------------------------------------------------------------------
X, X_DOT, X_DDOT = state_symbols("x")
_m, _c, _k = sp.symbols("m c k")


def _single(name: str, description: str, forces: sp.Expr, constants: dict[str, float],
            rms: float, **fields) -> System:
    """m·x'' + ``forces`` = u, excited at 0.1–3 Hz with ``rms`` N."""
    return System(name=name, description=description, equations=(sp.Eq(_m * X_DDOT + forces, U),),
                  constants={"m": 1.0, **constants},
                  excitation=Excitation(low=0.1, high=3.0, rms=rms), **fields)


def _chain(n: int, grounded_last: bool = True) -> System:
    """n masses on ground springs and dampers, neighbours coupled by kc·d + k3·d³;
    ``grounded_last`` False: the last mass has a damper but no spring to ground, excited at
    4 N RMS instead of 6: at 6 the free chain's extrapolation record (× 1.2) is sensitive
    to its constants — a 0.5 % change of one true constant moved it by up to 20 % NRMS
    (seed 1) — and at 4 by at most 1 % (seeds 0–4), so an NRMS there measures the model,
    not the record's sensitivity."""
    names = tuple(f"x{i}" for i in range(1, n + 1))
    kc, k3 = sp.symbols("kc k3")
    equations = []
    for i, name in enumerate(names):
        x, x_dot, x_ddot = state_symbols(name)
        lhs = sp.Symbol(f"m{i + 1}") * x_ddot + _c * x_dot
        lhs += _k * x if grounded_last or i < n - 1 else 0
        for j in (i - 1, i + 1):
            if 0 <= j < n:
                d = x - sp.Symbol(names[j])
                lhs += kc * d + k3 * d ** 3
        equations.append(sp.Eq(lhs, U if i == 0 else 0))
    masses = {f"m{i + 1}": v for i, v in enumerate((1.0, 0.8, 1.2)[:n])}
    return System(name=f"chain{n}" + ("" if grounded_last else "_free"),
                  description=f"{n}-mass chain, cubic coupling springs, input on mass 1"
                  + ("" if grounded_last else ", no ground spring on the last mass"),
                  equations=tuple(equations), coordinates=names,
                  constants={**masses, "c": 0.8, "k": 30.0, "kc": 20.0, "k3": 300.0},
                  excitation=Excitation(low=0.1, high=3.0, rms=6.0 if grounded_last else 4.0))


def _two_masses(ground, coupling, driven: int) -> tuple[sp.Eq, ...]:
    """The equations of masses m1, m2 at x1, x2: m_i·x_i'' + ``ground(i, x_i, x_i')`` +
    ``coupling(x_i − x_j, x_i' − x_j')`` = u on mass ``driven`` (0-based), 0 on the other."""
    names = ("x1", "x2")
    equations = []
    for i, name in enumerate(names):
        x, x_dot, x_ddot = state_symbols(name)
        other, other_dot, _ = state_symbols(names[1 - i])
        lhs = (sp.Symbol(f"m{i + 1}") * x_ddot + ground(i, x, x_dot)
               + coupling(x - other, x_dot - other_dot))
        equations.append(sp.Eq(lhs, U if i == driven else 0))
    return tuple(equations)


def _friction_chain() -> System:
    """Two masses on ground springs and dampers, coupled by a spring and by dry friction
    F·tanh((x_i' − x_j')/v0) between them, v0 = 1 mm/s (a sign resolved by the truth's
    integrator: the masses stick to each other for ~15 % of the time)."""
    F, kc, v0 = sp.symbols("F kc v0")
    equations = _two_masses(lambda i, x, x_dot: _c * x_dot + _k * x,
                            lambda d, d_dot: kc * d + F * sp.tanh(d_dot / v0), driven=0)
    return System(name="chain2_friction", description="2-mass chain, dry friction between "
                  "the masses, input on mass 1", equations=equations, coordinates=("x1", "x2"),
                  constants={"m1": 1.0, "m2": 0.8, "c": 0.5, "k": 30.0, "kc": 20.0, "F": 1.5,
                             "v0": 1e-3},
                  excitation=Excitation(low=0.1, high=3.0, rms=6.0), max_step=SIGN_MAX_STEP)


def _chain_driven_at_the_free_end() -> System:
    """Two masses driven on mass 2 only: mass 1 on a ground spring and damper, mass 2 with
    no ground connection; the masses coupled by a spring kc·d + k3·d³ and a damper cr·d'
    (d = x_i − x_j). Unlike the other chains, a damper acts between the masses and the
    input enters the last equation."""
    kc, k3, cr = sp.symbols("kc k3 cr")
    equations = _two_masses(lambda i, x, x_dot: _c * x_dot + _k * x if i == 0 else 0,
                            lambda d, d_dot: kc * d + k3 * d ** 3 + cr * d_dot, driven=1)
    return System(name="chain2_driven_free_end", description="2-mass chain driven on the "
                  "mass without a ground connection, a damper between the masses",
                  equations=equations, coordinates=("x1", "x2"),
                  constants={"m1": 1.5, "m2": 0.6, "c": 1.0, "k": 50.0, "kc": 25.0,
                             "k3": 500.0, "cr": 0.4},
                  excitation=Excitation(low=0.1, high=3.0, rms=3.0))


def _stiff_torsional_pair() -> System:
    """Two inertias at drivetrain scales (kg·m², N·m/rad, 1 kHz): inertia 1 on a ground
    spring, both on ground dampers, coupled by a shaft much stiffer than the ground
    spring, kc·d + k3·d³ (d = x1 − x2), torque on inertia 1. The shaft's twist d is a fifth
    of the rotations and lives in the high mode, its band ~4× theirs: state estimates
    smoothed to the coordinates' band alone lose it
    (:func:`gpjax._weak_form.system_band_hz`)."""
    kc, k3, inertia_1, inertia_2 = sp.symbols("kc k3 J1 J2")
    x1, x1_dot, x1_ddot = state_symbols("x1")
    x2, x2_dot, x2_ddot = state_symbols("x2")
    equations = (sp.Eq(inertia_1 * x1_ddot + _c * x1_dot + _k * x1 + kc * (x1 - x2)
                       + k3 * (x1 - x2) ** 3, U),
                 sp.Eq(inertia_2 * x2_ddot + _c * x2_dot + kc * (x2 - x1)
                       + k3 * (x2 - x1) ** 3, 0))
    return System(name="torsion2_stiff", description="2 inertias on a stiff cubic shaft, "
                  "a ground spring on the driven one only, drivetrain scales",
                  equations=equations, coordinates=("x1", "x2"),
                  constants={"J1": 2e-3, "J2": 5e-3, "c": 0.02, "k": 20.0, "kc": 50.0,
                             "k3": 5e4},
                  sample_rate=1000.0, duration=8.0,
                  excitation=Excitation(low=1.0, high=30.0, rms=1.0))


def _light_middle_chain() -> System:
    """``chain3_free`` with a light middle mass (2, 0.5, 1 kg), stiffer cubic couplings and
    lighter damping: the middle equation's own x2 and its couplings to both neighbours are
    nearly collinear, each of little use alone, so forward selection by equation error
    misses them (:func:`gpjax._system_search._selections`)."""
    return dataclasses.replace(
        _chain(3, grounded_last=False), name="chain3_light_middle",
        description="3-mass chain, a light middle mass, cubic coupling springs, input on "
        "mass 1, no ground spring on the last mass",
        constants={"m1": 2.0, "m2": 0.5, "m3": 1.0, "c": 0.3, "k": 45.0, "kc": 40.0,
                   "k3": 800.0},
        excitation=Excitation(low=0.1, high=4.0, rms=5.0))


def _light_free_chain() -> System:
    """``chain2_free`` lightly damped (m2 = 0.7 kg, c = 0.5, kc = 25, k3 = 400) and 80 s long:
    the measured input's noise rings through its lightly damped modes, so a needless
    relative damper lowers a simulation's residual by that ringing, not by physics (errors
    in variables, :func:`gpjax._select.input_noise_shares`). Its response to a 20 % larger
    input is sensitive to the constants: the true structure refitted to seed 12 misses it
    by 2.1 % NRMS."""
    base = _chain(2, grounded_last=False)
    return dataclasses.replace(
        base, name="chain2_free_light", description="2-mass chain, no ground spring on the "
        "last mass, lightly damped, 80 s", duration=80.0,
        constants={**base.constants, "m2": 0.7, "c": 0.5, "kc": 25.0, "k3": 400.0})


def _ground_friction(base: System, i: int) -> System:
    """``base`` with dry friction F·tanh(x_i'/v0), F = 1 N, v0 = 1 mm/s, between
    coordinate ``i`` (0-based) and the ground: an effect a model of ``base``'s structure
    lacks, for the diagnosis of a system to find."""
    F, v0 = sp.symbols("F v0")
    x_dot = state_symbols(base.coordinates[i])[1]
    equations = tuple(sp.Eq(e.lhs + F * sp.tanh(x_dot / v0), e.rhs) if k == i else e
                      for k, e in enumerate(base.equations))
    return dataclasses.replace(
        base, name=f"{base.name}_friction_{base.coordinates[i]}",
        description=f"{base.description}; dry friction on {base.coordinates[i]}",
        equations=equations, constants={**base.constants, "F": 1.0, "v0": 1e-3},
        max_step=SIGN_MAX_STEP)


def _catalogue() -> dict[str, System]:
    F, Fc, Fs, vs, v0, a, k3, f0 = sp.symbols("F Fc Fs vs v0 a k3 f0")
    sign = sp.sign(X_DOT)
    systems = [
        _single("pendulum", "m·x'' + c·x' + k·sin(x) = u, swings to ~90°",
                _c * X_DOT + _k * sp.sin(X), {"c": 1.5, "k": 39.48}, 11.0),
        _single("quadratic_drag", "m·x'' + c·x'|x'| + k·x = u",
                _c * X_DOT * sp.Abs(X_DOT) + _k * X, {"c": 2.0, "k": 40.0}, 10.0,
                max_step=SIGN_MAX_STEP),
        _single("coulomb_viscous", "m·x'' + c·x' + F·sign(x') + k·x = u",
                _c * X_DOT + F * sign + _k * X, {"c": 0.6, "F": 1.5, "k": 40.0}, 8.0,
                max_step=SIGN_MAX_STEP),
        _single("stribeck", "m·x'' + c·x' + (Fc + (Fs − Fc)·exp(−(x'/vs)²))·sign(x') + k·x = u",
                _c * X_DOT + (Fc + (Fs - Fc) * sp.exp(-(X_DOT / vs) ** 2)) * sign + _k * X,
                {"c": 0.6, "Fc": 1.0, "Fs": 2.0, "vs": 0.05, "k": 40.0}, 8.0,
                max_step=SIGN_MAX_STEP),
        _single("stribeck_resolved", "Stribeck friction whose curve the record resolves "
                "(vs ≈ RMS x'/4) and whose slip is damped (c > the Stribeck drop's slope)",
                _c * X_DOT + (Fc + (Fs - Fc) * sp.exp(-(X_DOT / vs) ** 2)) * sign + _k * X,
                {"c": 2.0, "Fc": 1.0, "Fs": 2.0, "vs": 0.5, "k": 40.0}, 8.0,
                max_step=SIGN_MAX_STEP),
        _single("saturating_spring", "m·x'' + c·x' + k·tanh(x/a) = u, reaches x/a ≈ 2",
                _c * X_DOT + _k * sp.tanh(X / a), {"c": 2.0, "k": 20.0, "a": 0.5}, 9.0),
        _single("exponential_stiffening", "m·x'' + c·x' + k·sinh(x/a) = u",
                _c * X_DOT + _k * sp.sinh(X / a), {"c": 2.0, "k": 10.0, "a": 0.25}, 10.0),
        _single("duffing", "m·x'' + c·x' + k·x + k3·x³ = u, hardening, damped (not chaotic)",
                _c * X_DOT + _k * X + k3 * X ** 3, {"c": 2.0, "k": 40.0, "k3": 400.0}, 10.0),
        _single("duffing_load", "m·x'' + c·x' + k·x + k3·x³ + f0 = u: Duffing under a static "
                "load (a constant force; not in the physics suite)",
                _c * X_DOT + _k * X + k3 * X ** 3 + f0, {"c": 2.0, "k": 40.0, "k3": 400.0,
                                                         "f0": 2.0}, 10.0),
        _single("softening_spring", "m·x'' + c·x' + k·x − k3·x³ = u, below its escape",
                _c * X_DOT + _k * X - k3 * X ** 3, {"c": 2.0, "k": 40.0, "k3": 60.0}, 4.0),
        _single("smooth_friction", "m·x'' + c·x' + F·tanh(x'/v0) + k·x = u: a lubricated "
                "friction law beside viscous damping (not in the physics suite)",
                _c * X_DOT + F * sp.tanh(X_DOT / v0) + _k * X,
                {"c": 1.5, "F": 4.0, "v0": 0.2, "k": 30.0}, 6.0),
        _chain(2),
        _ground_friction(_chain(2), 1),
        _chain(3),
        _chain(2, grounded_last=False),
        _chain(3, grounded_last=False),
        _light_middle_chain(),
        _light_free_chain(),
        _friction_chain(),
        _chain_driven_at_the_free_end(),
        _stiff_torsional_pair(),
        System(name="stage", description="drifting positioning stage: m·x'' + c·x' + "
               "F·sign(x') + f0 = u, PD loop on a quantised encoder",
               equations=(sp.Eq(_m * X_DDOT + _c * X_DOT + F * sign + f0, U),),
               constants={"m": 2.0, "c": 4.0, "F": 2.0, "f0": 0.5}, sample_rate=200.0,
               excitation=Excitation(low=0.05, high=0.5, rms=0.01),
               loop=StageLoop(kp=2000.0, kd=80.0, resolution=1e-6)),
    ]
    return {s.name: s for s in systems}


#: Every system by name.
SYSTEMS: dict[str, System] = _catalogue()
#: The physics benchmark's single-coordinate systems.
PHYSICS_SUITE = ("pendulum", "quadratic_drag", "coulomb_viscous", "stribeck",
                 "stribeck_resolved", "saturating_spring", "exponential_stiffening", "duffing", "softening_spring")


def get_system(name: str) -> System:
    """The catalogue's system ``name``.

    Raises:
        ValueError: an unknown name.
    """
    if name not in SYSTEMS:
        raise ValueError(f"unknown system {name!r}; use one of {', '.join(SYSTEMS)}")
    return SYSTEMS[name]
