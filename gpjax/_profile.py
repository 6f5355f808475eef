"""Profile intervals of a family's inner constants (a sin's frequency and phase, a tanh's
width): where the output error is far from quadratic in them, the linearised interval
misplaces its ends.

For an inner constant θ with fitted value θ̂, the output error S(θ) is profiled: θ held at
each point of a grid outward from θ̂ and every other constant refitted
(:meth:`gpjax._refine.Refiner.refine` with ``held_inner``), each point started from the
last one's fit (continuation: a point far from θ̂ started from θ̂'s constants can stall in
a worse local minimum and overstate S); both sides of every inner constant are one batch. Its signed root
r(θ) = sign(θ − θ̂)·√(S(θ) − S(θ̂)) is linear, r ≈ (θ − θ̂)/s₀, where S is quadratic, s₀ the
Gauss–Newton standard error (√[A⁻¹]_θθ of :mod:`gpjax._uncertainty`'s bread). The robust
standard error s of the sandwich is larger where the residual is coloured, so the profile is
rescaled to it, z(θ) = r(θ)·s₀/s: the magnitude adjustment of Chandler & Bate (2007) for a
likelihood whose curvature does not match the estimator's variance. The interval is
{θ : |z(θ)| ≤ t₀.₉₇₅(ν)}, ν the constant's degrees of freedom; where S is quadratic it is
the sandwich interval exactly, elsewhere it keeps the profile's asymmetry. An end not
reached within the grid (:data:`REACH` × the linearised half-width) stays the linearised one.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ._coefficients import Population

#: Grid points each side of θ̂, and how far the grid reaches in linearised half-widths.
POINTS, REACH = 4, 2.0


def profile_bounds(refiner, population: Population, fixed_forcing: np.ndarray,
                   held_inner: np.ndarray | None, *, inner: dict[str, dict],
                   objective, fitted: float) -> dict[str, tuple[float, float]]:
    """The profile 95 % interval (low, high) of each inner constant of the population of
    one ``population`` (module docstring). ``inner``: name -> {"slot": its inner slot,
    "value": θ̂, "se": sandwich standard error s, "naive_se": Gauss–Newton s₀, "quantile":
    t₀.₉₇₅(ν)}; ``objective(population) -> (P,)`` the output error S of each model,
    ``fitted`` S at the fit;
    ``fixed_forcing`` and ``held_inner`` as :meth:`gpjax._refine.Refiner.refine` takes them."""
    if not inner:
        return {}
    steps = np.arange(1, POINTS + 1) * (REACH / POINTS)  # in linearised half-widths
    held = (np.zeros(population.inner.shape, dtype=bool) if held_inner is None
            else np.asarray(held_inner, dtype=bool))
    legs = [(c, side) for c in inner.values() for side in (-1.0, 1.0)]
    masks = []
    for c, _ in legs:
        mask = held.copy()
        mask[0, c["slot"]] = True
        masks.append(mask)
    fixed = np.repeat(np.asarray(fixed_forcing), len(legs), axis=0)
    current = Population.concatenate([population] * len(legs))
    excess = np.empty((len(legs), steps.size))
    for j, step in enumerate(steps):  # continuation: each point starts from the last
        values = current.inner.copy()
        for row, (c, side) in enumerate(legs):
            values[row, c["slot"]] = c["value"] + side * step * c["quantile"] * c["se"]
        current = refiner.refine(dataclasses.replace(current, inner=values), fixed,
                                 np.concatenate(masks)).population
        excess[:, j] = np.nan_to_num(objective(current) - fitted, nan=np.inf)
    bounds = {}
    for k, (name, c) in enumerate(inner.items()):
        ends = []
        for row in (2 * k, 2 * k + 1):
            z = np.sqrt(np.clip(excess[row], 0, None)) * c["naive_se"] / c["se"]  # |z(θ)|
            ends.append(legs[row][1] * _crossing(steps, z, c["quantile"]))
        half = c["quantile"] * c["se"]
        bounds[name] = (c["value"] + ends[0] * half, c["value"] + ends[1] * half)
    return bounds


def _crossing(steps: np.ndarray, z: np.ndarray, quantile: float) -> float:
    """The distance (in linearised half-widths, from θ̂ where z = 0, ``steps`` increasing)
    at which |z| first reaches ``quantile``, by linear interpolation; 1 (the linearised
    end) if it does not within the grid."""
    previous_step, previous_z = 0.0, 0.0
    for step, value in zip(steps, z):
        if value >= quantile:
            if not np.isfinite(value):
                return float(step)
            return float(previous_step + (step - previous_step) * (quantile - previous_z)
                         / (value - previous_z))
        previous_step, previous_z = step, value
    return 1.0
