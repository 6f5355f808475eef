"""The drifting positioning stage, solved exactly: m·x'' + c·x' + F·sign(x') + f0 = u.

Its force is held for one sample (a digital controller, or a recorded input replayed by
zero-order hold), so between samples the equation is linear with a constant drive:
v(τ) = v∞ + (v0 − v∞)·e^(−cτ/m), v∞ = (u − f0 − F·s)/c with s the sign of the motion.
A velocity reversal inside a hold is found in closed form; at rest the stage sticks
while |u − f0| ≤ F (the set-valued sign of Coulomb friction) — and since the drive is
constant, for the rest of the hold. No integrator, so the truth is exact to rounding.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np


def stage_response(system, time: np.ndarray, rng: np.random.Generator, scale: float
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(positions (1, N), velocities (1, N), force (N,)) of the stage in its PD loop
    tracking a reference drawn from ``system.excitation`` × ``scale`` (m); the controller
    reads the encoder (true position rounded to ``loop.resolution``) at every sample."""
    loop = system.loop
    reference = system.excitation.draw(rng, time, scale)(time)
    dt = float(time[1] - time[0])
    previous = [reference[0]]

    def controller(i: int, x: float) -> float:
        error = reference[i] - loop.resolution * round(x / loop.resolution)
        force = loop.kp * error + loop.kd * (error - previous[0]) / dt
        previous[0] = error
        return force

    return _run(system, time, controller)


def stage_hold(system, time: np.ndarray, force: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(positions (1, N), velocities (1, N)) of the stage from rest under ``force`` (N,)
    in N, each sample held for one period."""
    positions, velocities, _ = _run(system, time, lambda i, x: float(force[i]))
    return positions, velocities


def _run(system, time: np.ndarray, force_at: Callable[[int, float], float]):
    values = system.constants
    m, c, friction, offset = values["m"], values["c"], values["F"], values["f0"]
    n = time.size
    dt = float(time[1] - time[0])
    positions, velocities, forces = np.empty(n), np.empty(n), np.empty(n)
    x = v = 0.0
    for i in range(n):
        positions[i], velocities[i] = x, v
        forces[i] = force_at(i, x)
        x, v = hold_step(x, v, forces[i] - offset, dt, mass=m, damping=c, friction=friction)
    return positions[None], velocities[None], forces


def hold_step(x: float, v: float, drive: float, h: float, *, mass: float, damping: float,
              friction: float) -> tuple[float, float]:
    """(x, v) after ``h`` s of mass·v' = drive − damping·v − friction·sign(v), drive
    constant (N), sticking at rest while |drive| ≤ friction."""
    tau = mass / damping
    while h > 0.0:
        if v == 0.0:
            if abs(drive) <= friction:
                return x, 0.0
            s = math.copysign(1.0, drive)
        else:
            s = math.copysign(1.0, v)
        terminal = (drive - friction * s) / damping
        if v != 0.0 and s * terminal < 0.0:
            reversal = tau * math.log((v - terminal) / -terminal)
            if reversal < h:
                x += terminal * reversal + (v - terminal) * tau * (1.0 - math.exp(-reversal / tau))
                v, h = 0.0, h - reversal
                continue
        decay = math.exp(-h / tau)
        return x + terminal * h + (v - terminal) * tau * (1.0 - decay), \
            terminal + (v - terminal) * decay
    return x, v
