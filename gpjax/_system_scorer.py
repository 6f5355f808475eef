"""Objective of candidate systems by structure (:mod:`gpjax._system_search`), with the
least-squares and refined constants cached, and the cache as JSON records for checkpoints
and island migrants.

A structure (``key``) is per equation the pair (state features, forcing features). Its
record is ``{"key": text, "trees": one tree per equation, "objective": f}`` and, once
refined, ``"values"``: per equation ``[m, state coefficients, forcing coefficients, (x0,
x0')]`` in the order of the least-squares start's features. A record is read back through
its trees (:meth:`SystemScorer.key`), so no feature text is parsed: the smoothed sign's
width is a float that printing would round.
"""

from __future__ import annotations

import json

import numpy as np

from . import _trees
from ._canonical import feature_name
from ._coefficients import Coefficients, from_system_population, to_system_population
from ._evaluator import PENALTY, PopulationEvaluator
from ._refine import HORIZONS, REFIT_HORIZONS, Refiner, free_width
from ._select import input_noise_shares, simulates_better
from ._system_couplings import (couple, coupled_least_squares, coupled_residual,
                                fixed_columns, held_structure, tie_columns)
from ._system_fit import equation_constants, equation_residual, held_out
from ._weak_form import WeakForm
from ._system_grammar import Equations


class SystemScorer:
    """Objective of systems by structure, with least-squares and refined constants cached."""

    def __init__(self, weak: WeakForm, equations: Equations,
                 evaluator: PopulationEvaluator, *, batch: int, iterations: int):
        self.equations, self.evaluator, self.weak = equations, evaluator, weak
        self.batch = max(1, batch)  # systems per compiled refinement call
        self.iterations = iterations  # Levenberg–Marquardt steps per horizon of a refinement
        self.objective: dict[tuple, float] = {}
        self.refined: dict[tuple, list[Coefficients]] = {}
        self._refiners: dict[tuple, Refiner] = {}
        self._residuals: dict[tuple, float] = {}
        #: equation feature sets by weak-form residual, by (equation, size, key)
        #: (:func:`gpjax._system_search._selections`)
        self.selections: dict[tuple, list] = {}

    def key(self, system) -> tuple | None:
        parts = [self.equations.structure(i, tree) for i, tree in enumerate(system)]
        return None if any(p is None for p in parts) else tuple(parts)

    def normalised(self, key):
        """``key`` as a :data:`gpjax._system_fit.Structure`
        (:func:`gpjax._system_couplings.held_structure`)."""
        e = self.equations
        return held_structure(key, e.names, e.inputs, e.third_law)

    def coupled(self, key):
        """(structure with every coupling's mirror, ties): with the third law
        (:func:`gpjax._system_couplings.couple`), else (``key``, ())."""
        if not self.equations.third_law:
            return key, ()
        return couple(key, self.equations.names)

    def residual(self, key, i: int, part) -> float:
        """Weak-form equation error of ``key`` with equation ``i`` as ``part`` (state,
        forcing features): that equation's own
        (:func:`gpjax._system_fit.equation_residual`), or with
        the third law that of all equations together
        (:func:`gpjax._system_couplings.coupled_residual`)."""
        if not self.equations.third_law:
            return equation_residual(self.weak, i, *part)
        changed = key[:i] + (tuple(tuple(p) for p in part),) + key[i + 1:]
        if changed not in self._residuals:
            self._residuals[changed] = coupled_residual(self.weak, changed,
                                                        self.equations.names)
        return self._residuals[changed]

    def held_out(self, key) -> np.ndarray:
        """Held-out weak-form residual of ``key`` with every coupling's mirror
        (:func:`gpjax._system_fit.held_out`)."""
        return held_out(self.weak, self.coupled(key)[0])

    def simulates_better(self, current, simpler, alpha: float, resolution: float) -> bool:
        """Whether ``current``'s simulated responses fit the measured ones significantly
        better than ``simpler``'s at level ``alpha``, both refined: one coordinate's guard
        (:func:`gpjax._select.simulates_better`) on the root sum of squares over the
        coordinates of each residual scaled by its response's standard deviation. The guard
        exists because the equation error is blind where the states' smoothing blurs a weak
        term's effect: a gear's mesh damping at 5 % of critical, whose removal moves the
        fitted inertia by 80 %. A worsening of the simulated mean square by less than
        ``resolution`` (the run's ``convergence_tolerance``: the accuracy to which the
        fixed-step objective is claimed, :mod:`gpjax._convergence`) is not evidence
        either. Both mean squares are taken less each model's share of the measured
        input's noise (:func:`gpjax._select.input_noise_shares`): on a lightly damped
        2-mass chain (1 % noise on the response and the input, 8,001 samples, a record
        outside the repository) two needless relative dampers, c·d' − c₃·d'³, lowered the
        true structure's simulated objective by 3 % (by 17.5 % with the input's noise
        alone, by 0.03 % with the response's alone), passed this guard, and the reported
        system missed a 20 % larger input by 5.8 % NRMS, where the true one did by 2.1 %."""
        trees = [as_trees(k, self.equations) for k in (simpler, current)]
        self.refine_best(trees, self(trees), 2, horizons=REFIT_HORIZONS)
        population = to_system_population([self.coefficients(k) for k in (simpler, current)],
                                          self.evaluator)
        responses, _ = self.evaluator.simulate(population)
        measured = self.evaluator.measurement.responses.T
        scale = measured.std(axis=1)
        scaled = (responses - measured) / scale[:, None]  # (2, D, N)
        simple, full = np.sqrt(np.sum(scaled ** 2, axis=1))
        shares = input_noise_shares(self.evaluator, population, scale)
        if np.mean(simple ** 2) - shares[0] <= (1 + resolution) * (np.mean(full ** 2) - shares[1]):
            return False
        return simulates_better(simple, full, alpha, offset=float(shares[0] - shares[1]))

    def coefficients(self, key) -> list[Coefficients]:
        if key in self.refined:
            return self.refined[key]
        structure, ties = self.coupled(self.normalised(key))
        if ties:
            return coupled_least_squares(self.weak, structure, ties)
        return [equation_constants(self.weak, i, state, forcing)
                for i, (state, forcing) in enumerate(structure)]

    def __call__(self, systems) -> np.ndarray:
        keys = [self.key(s) for s in systems]
        new = list({k for k in keys if k is not None and k not in self.objective})
        if new:
            starts = [self.coefficients(k) for k in new]
            usable = [all(np.isfinite(c.mass) and all(np.isfinite(list(c.state.values())))
                          for c in start) for start in starts]
            chosen = [k for k, ok in zip(new, usable) if ok]
            for k, ok in zip(new, usable):
                if not ok:
                    self.objective[k] = PENALTY
            if chosen:
                population = to_system_population([self.coefficients(k) for k in chosen],
                                                  self.evaluator)
                scores = self.evaluator.score(population)
                for k, value in zip(chosen, scores.objective):
                    self.objective[k] = float(value)
        return np.array([PENALTY if k is None else self.objective[k] for k in keys])

    def refine_best(self, systems, scores, top: int, *,
                    horizons: tuple[float, ...] = HORIZONS) -> None:
        """Levenberg–Marquardt on the best ``top`` distinct systems not refined yet, with
        the continuation ``horizons`` (:data:`gpjax._refine.REFIT_HORIZONS` for the
        selection's guard)."""
        chosen = []
        for index in np.argsort(scores):
            key = self.key(systems[index])
            if scores[index] >= PENALTY or len(chosen) == top:
                break
            if key is not None and key not in self.refined and key not in chosen:
                chosen.append(key)
        if not chosen:
            return
        starts = [self.coefficients(k) for k in chosen]
        population = to_system_population(starts, self.evaluator)
        coupled = [self.coupled(self.normalised(k)) for k in chosen]
        fixed = np.array([fixed_columns(structure, ties, self.evaluator.forcing_index)
                          for structure, ties in coupled])
        free = max(sum(1 + len(s) + len(f) + 2 for s, f in structure)
                   for structure, _ in coupled)
        # Few distinct Jacobian widths and batches: few compiles. A generation refines
        # ``batch`` systems in one call, the selection's simulated-response guard one: the
        # cost of a call grows with its padded batch (a 3-mass chain of 8,000 samples:
        # 6 s for one system alone, 12 s padded to 4, 15 s for 5).
        width = free_width(free)
        batch = 1 if len(chosen) == 1 else self.batch
        if (width, batch, horizons) not in self._refiners:
            self._refiners[width, batch, horizons] = Refiner(
                self.evaluator, iterations=self.iterations, max_free=width, batch=batch,
                horizons=horizons)
        ties = [tie_columns(t, self.evaluator) for _, t in coupled]
        refiner = self._refiners[width, batch, horizons]
        refined = refiner.refine(population, fixed, ties=ties).population
        scores = self.evaluator.score(refined)
        for k, start, coefficients, value in zip(
                chosen, starts, from_system_population(refined, self.evaluator, starts),
                scores.objective):
            if value < self.objective[k]:
                self.refined[k], self.objective[k] = coefficients, float(value)
            else:
                self.refined[k] = start

    def record(self, key) -> dict:
        """``key``'s JSON record (module docstring); ``key`` must have been scored."""
        item = {"key": key_text(key),
                "trees": [_trees.to_json(t) for t in as_trees(key, self.equations)],
                "objective": self.objective[key]}
        if key in self.refined:
            item["values"] = [[c.mass, list(c.state.values()), list(c.forcing.values()),
                               list(c.y0)] for c in self.refined[key]]
        return item

    def records(self) -> list[dict]:
        """The records of every refined structure (what a resumed run cannot recompute)."""
        return [self.record(key) for key in self.refined]

    def load(self, records: list[dict]) -> None:
        """Put ``records`` (:meth:`record`) into the caches.

        Raises:
            ValueError: a record's trees are not a valid system.
        """
        for item in records:
            key = self.key(tuple(_trees.from_json(t) for t in item["trees"]))
            if key is None:
                raise ValueError(f"record {item['key']} is not a valid system")
            if "values" in item:
                self.refined.pop(key, None)
                like = self.coefficients(key)
                self.refined[key] = [Coefficients(
                    mass=float(m), state=dict(zip(c.state, map(float, state))),
                    forcing=dict(zip(c.forcing, map(float, forcing))),
                    y0=(float(y0[0]), float(y0[1])))
                    for c, (m, state, forcing, y0) in zip(like, item["values"])]
            self.objective[key] = float(item["objective"])

    def clear(self) -> None:
        """Forget every scored structure (a reused island engine)."""
        self.objective.clear()
        self.refined.clear()
        self._residuals.clear()
        self.selections.clear()


def key_text(key) -> str:
    """A structure as text, the same in every process (a record's identity)."""
    return json.dumps([[[feature_name(f) for f in state], [feature_name(f) for f in forcing]]
                       for state, forcing in key])


def as_trees(key, equations: Equations) -> tuple:
    return tuple(equations.tree(i, *part) for i, part in enumerate(key))
