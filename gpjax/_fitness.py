"""From trees to scores: structure check, coefficients, batched simulation, refinement.

Two caches make repeated individuals free: tree → structure check, and structure key →
scored record. With ``coefficients="least_squares"`` the key is the set of features (the
numbers come from the data); with ``"tree"`` it also holds the tree's coefficients, so one
feature set has many records (its coefficient variants) and :func:`feature_set_key` names
the set they share. A record's constants are one :class:`~gpjax._coefficients.Coefficients`
(sympy features); they become text only in a checkpoint (:meth:`Record.to_json`).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import sympy as sp

from ._canonical import CanonicalForm, Symbols, check_tree, feature_name
from ._coefficients import Coefficients, Population, from_population, to_population
from ._config import GPConfig
from ._convergence import search_substeps
from ._data import Measurement
from ._evaluator import INVALID_STRUCTURE, OK, PENALTY, PopulationEvaluator, Scores
from ._features import INNER_GRID, SIGN_WIDTH, Family, families_for, match, smoothed_sign
from ._memory import check_fit_memory
from ._refine import BATCH, HORIZONS, MAX_ROUNDS, WHOLE_RECORD, Refiner, until_converged
from ._trees import Tree
from ._weak_form import (WeakForm, least_squares, least_squares_residual, smoothed_derivatives,
                         smoothing_cutoff_hz)


@dataclasses.dataclass
class Record:
    """A scored model structure (one cache entry); ``coefficients`` is None when invalid;
    ``held``: slots of the evaluator's inner constants held at a snapped value (never
    refined, not counted as fitted); ``held_signs``: how many of them are a smoothed sign's
    scale (:meth:`Fitness.held_signs`); ``converged``: refined until a round no longer
    lowered the objective (:meth:`Fitness.refine` with ``to_convergence``)."""

    key: str
    valid: bool
    reason: str = ""
    coefficients: Coefficients | None = None
    objective: float = PENALTY
    f_time: float = PENALTY
    f_freq: float = PENALTY
    rms: float = PENALTY
    status: int = INVALID_STRUCTURE
    refined: bool = False
    held: tuple[int, ...] = ()
    held_signs: int = 0
    converged: bool = False

    @property
    def n_terms(self) -> int:
        """Inertia term + state terms + forcing terms."""
        return self.coefficients.n_terms if self.coefficients is not None else 0

    @property
    def n_constants(self) -> int:
        """Fitted constants (:attr:`Coefficients.n_constants`) less the held ones."""
        if self.coefficients is None:
            return 0
        return self.coefficients.n_constants - len(self.held)

    @property
    def complexity(self) -> tuple[int, int, int]:
        """(fitted constants, terms, held constants): the order in which models count as
        simpler (:mod:`gpjax._select`). A smoothed sign's held scale is not counted: it is
        the integration's smoothing of sign(z), which has no constant, not an assumed value
        (a snapped sin(x)'s a = 1, b = 0 are)."""
        return self.n_constants, self.n_terms, len(self.held) - self.held_signs

    def to_json(self) -> dict:
        data = dataclasses.asdict(dataclasses.replace(self, coefficients=None))
        data["coefficients"] = None if self.coefficients is None else self.coefficients.to_json()
        return data

    @classmethod
    def from_json(cls, data: dict, names: set[str]) -> "Record":
        """Inverse of :meth:`to_json`; ``names`` are the data's symbol names."""
        data = dict(data)
        if data["coefficients"] is not None:
            data["coefficients"] = Coefficients.from_json(data["coefficients"], names)
        data["held"] = tuple(data.get("held", ()))
        return cls(**data)


def structure_key(form: CanonicalForm, with_coefficients: bool) -> str:
    """Text key of a canonical form: its features, and its coefficients if asked, each part
    in feature-text order whatever the form's (a neighbour built from a model's terms in
    another order is the same record: before, the final selection scored and refined a
    duffing record's eight ends a second time under reordered keys)."""
    def part(pairs):
        pairs = sorted(pairs, key=lambda p: feature_name(p[0]))
        if with_coefficients:
            return ", ".join(f"{feature_name(f)}:{c!r}" for f, c in pairs)
        return ", ".join(feature_name(f) for f, _ in pairs)
    mass = f"{form.mass!r}" if with_coefficients else "m"
    return f"{mass} | {part(form.state)} | {part(form.forcing)}"


def feature_set_key(record: Record) -> str:
    """The key of a valid record's feature set, without coefficients (``record.key`` itself
    in least-squares mode; in tree mode shared by all coefficient variants of the set)."""
    return structure_key(record.coefficients.canonical(), with_coefficients=False)


class Fitness:
    """Scores trees against one measurement (see the module docstring).

    Args:
        measurement: the data.
        config: the run's settings.
        substeps: RK4 steps per sample interval (default: the config's; for ``"auto"``,
            the data's bandwidth rule, :func:`gpjax._convergence.search_substeps`).
        sign_width: width ε of the smoothed sign tanh(z/ε), as a fraction of RMS z
            (:mod:`gpjax._features`; narrowed by :mod:`gpjax._sign_width`).
        single: the fitness refits one model only (the reported model at a narrower
            sign): its evaluator and refiner compile calls of one model, where a call is
            otherwise padded to 16 and 8 models.

    Raises:
        UserInputError: the run's estimated memory (:mod:`gpjax._memory`) exceeds what is
            available.
    """

    def __init__(self, measurement: Measurement, config: GPConfig, *,
                 substeps: int | None = None, sign_width: float = SIGN_WIDTH,
                 single: bool = False):
        if substeps is None:
            substeps = search_substeps(measurement, config.substeps)
        check_fit_memory(n_samples=measurement.n_samples, substeps=substeps,
                         population=config.population)
        self.measurement = measurement
        self.config = config
        self.sign_width = sign_width
        self.symbols = Symbols(measurement.response_name, measurement.time_name,
                               measurement.input_names)
        self.evaluator = PopulationEvaluator(
            measurement, self.symbols, max_degree=config.max_degree,
            families=families_for(config.functions, config.variables, config.max_degree),
            substeps=substeps,
            n_bins=config.n_bins, w_time=config.w_time, w_freq=config.w_freq,
            batch=1 if single else min(config.population, 512),
            fit_initial_conditions=config.initial_conditions is None,
            input_interpolation=config.input_interpolation)
        self.derivatives = smoothed_derivatives(
            measurement, smoothing_cutoff_hz(measurement, self.evaluator.n_bins))
        self.weak_form = WeakForm(measurement, self.derivatives.x_dot,
                                  self.derivatives.window)
        # Least squares starts refinement inside the basin, where the short-horizon
        # continuation (for poor starts) would only double the compile. Tree constants are
        # poor starts: a wrong stiffness wraps the phase over the full record.
        self.refiner = Refiner(self.evaluator, iterations=config.refine_iterations,
                               batch=1 if single else BATCH,
                               horizons=WHOLE_RECORD if config.coefficients == "least_squares"
                               else HORIZONS)
        #: RMS of x and x' on the data: the scales of the bank's default inner constants
        self.scales = {role: float(np.sqrt(np.mean(z ** 2))) or 1.0 for role, z in
                       (("x", self.derivatives.x), ("x_dot", self.derivatives.x_dot))}
        if config.initial_conditions is not None:
            self.y0 = tuple(map(float, config.initial_conditions))
        else:  # eq. 13: response and a robust derivative estimate at the first sample
            self.y0 = self.derivatives.initial_state
        for u in self.symbols.u[:1]:
            self.evaluator.forcing_index(u)
        self.checks: dict[Tree, tuple[str, CanonicalForm | None, str]] = {}
        self.records: dict[str, Record] = {}

    # --- trees to structures --------------------------------------------------------------
    def classify(self, tree: Tree) -> tuple[str, CanonicalForm | None, str]:
        """(key, canonical form or None, reason) of a tree, cached."""
        if tree not in self.checks:
            check = check_tree(tree, self.symbols, self.config.named_constants,
                               max_degree=self.config.max_degree, bank=True,
                               linear_inputs=self.config.input_forcing == "linear")
            if check.valid:
                form = self._bank_form(check.canonical)
                reason = self.unsupported(form)
                check = dataclasses.replace(check, valid=not reason, reason=reason,
                                            canonical=None if reason else form)
            if check.valid:
                key = structure_key(check.canonical, self.config.coefficients == "tree")
                self.checks[tree] = (key, check.canonical, "")
            else:
                self.checks[tree] = ("invalid: " + check.reason, None, check.reason)
        return self.checks[tree]

    def unsupported(self, form: CanonicalForm) -> str:
        """Why the evaluator cannot score ``form`` ("" if it can): a state feature outside
        its basis, two members of one family (one column each), or a forcing term that is
        not finite on the data."""
        columns = [c for c, _, _ in self.evaluator.state_columns([f for f, _ in form.state])]
        outside = [f for (f, _), c in zip(form.state, columns) if c is None]
        if outside:
            return (f"state feature {outside[0]} is outside the evaluator's basis (powers of x "
                    f"and x' up to {self.config.max_degree} and the feature bank)")
        if len(set(columns)) < len(columns):
            return ("more members of one feature-bank family than its slots (e.g. two sines "
                    "of x): a model holds one of each, two of exp")
        if not all(self.evaluator.forcing_finite(g) for g, _ in form.forcing):
            return "a forcing term is not finite on the data (e.g. exp(a·t) overflows)"
        return ""

    def _bank_form(self, form: CanonicalForm) -> CanonicalForm:
        """``form`` with sign(z) smoothed to tanh(z/ε) (:mod:`gpjax._features`) and every
        family member written one way (equal inner constants, equal features)."""
        if not self.evaluator.families:
            return form
        widths = {role: self.sign_width * scale for role, scale in self.scales.items()}
        state: dict[sp.Expr, float] = {}
        for feature, value in form.state:
            feature = smoothed_sign(feature, self.symbols, widths)
            found = match(feature, self.symbols)
            if found is not None:
                feature = found[0].feature(self.symbols, found[1])
            state[feature] = state.get(feature, 0.0) + value
        state = _hyperbolic_pairs(state)
        return dataclasses.replace(form, state=tuple(sorted(state.items(), key=lambda p: feature_name(p[0]))))

    def records_for(self, trees: list[Tree]) -> list[Record]:
        """Score every tree (new structures in one batch) and return their records."""
        new: dict[str, CanonicalForm] = {}
        classified = [self.classify(tree) for tree in trees]
        for key, form, reason in classified:
            if key in self.records or key in new:
                continue
            if form is None:
                self.records[key] = Record(key=key, valid=False, reason=reason)
            else:
                new[key] = form
        if new:
            self.score_forms(new)
        return [self.records[key] for key, _, _ in classified]

    def score_forms(self, forms: dict[str, CanonicalForm],
                    held: dict[str, tuple[int, ...]] | None = None,
                    kept: dict[str, tuple[int, ...]] | None = None) -> None:
        """Set coefficients of each (key, form), score them in one batch, cache them; a form
        the evaluator cannot score (:meth:`unsupported`, e.g. a local-search move that adds
        a second member of a family) is cached as an invalid record. ``held``: per key,
        inner-constant slots held at the form's values (no grid start for that form);
        ``kept``: per key, slots that start at the form's values (no grid start) and are
        refined."""
        held, kept = held or {}, kept or {}
        rows = []
        for key, form in forms.items():
            reason = self.unsupported(form)
            if reason:
                self.records[key] = Record(key=key, valid=False, reason=reason)
                continue
            coefficients = Coefficients.from_canonical(form, self.y0)
            if self.config.coefficients == "least_squares":
                state, forcing = form.structure
                state = self._inner_start(state, forcing, held.get(key, ()) + kept.get(key, ()))
                mass, c, g, _ = least_squares(self.weak_form, state, forcing)
                coefficients = coefficients.replace(
                    mass=float(mass), state=dict(zip(state, map(float, c))),
                    forcing=dict(zip(forcing, map(float, g))))
            rows.append(Record(key=key, valid=True, coefficients=coefficients,
                               held=held.get(key, ()),
                               held_signs=self.held_signs(held.get(key, ()))))
        self._score_records(rows)
        for record in rows:
            self.records[record.key] = record

    def _inner_start(self, state: tuple[sp.Expr, ...], forcing: tuple[sp.Expr, ...],
                     fixed: tuple[int, ...] = ()) -> tuple[sp.Expr, ...]:
        """``state`` with each family member's scale θ0 taken from the tree or from
        :data:`gpjax._features.INNER_GRID`, whichever leaves the smaller weak-form
        least-squares residual (one feature at a time, in order); a scale among the
        ``fixed`` slots stays."""
        chosen = list(state)
        for i, feature in enumerate(state):
            found = match(feature, self.symbols)
            if (found is None or found[0].n_inner == 0
                    or self.evaluator.inner_of(feature)[0].start in fixed):
                continue
            family, theta = found
            scale = self.scales[family.role]
            options = [f for f in [feature] + [family.feature(self.symbols, (g / scale, *theta[1:]))
                                               for g in INNER_GRID[family.function]]
                       if f == feature or f not in chosen]  # two members stay distinct
            chosen[i] = min(options, key=lambda f: least_squares_residual(
                self.weak_form, tuple(chosen[:i] + [f] + chosen[i + 1:]), forcing))
        return tuple(chosen)

    # --- records to arrays and back -------------------------------------------------------
    def basis_features(self) -> dict[str, list[sp.Expr]]:
        """Features a one-term move may add: x^k and x'^k (k <= max_degree, where the
        configured variables allow them), each family of the feature bank as
        :meth:`default_feature`, a constant force and each input."""
        variables = self.config.variables
        state = [symbol ** k for symbol, role in ((self.symbols.x, "x"),
                                                  (self.symbols.x_dot, "x_dot"))
                 if role in variables for k in range(1, self.config.max_degree + 1)]
        state += [self.default_feature(f) for f in self.evaluator.families]
        forcing = [sp.Integer(1)] + (list(self.symbols.u) if "u" in variables else [])
        return {"state": state, "forcing": forcing}

    def held_signs(self, held) -> int:
        """How many of the ``held`` slots of :attr:`Population.inner` are a smoothed sign's
        scale: the last inner constant of a tanh or stribeck family (:mod:`gpjax._features`)."""
        if not held:
            return 0
        signs = {slots.stop - 1 for family, (_, slots) in
                 zip(self.evaluator.families, self.evaluator.inner_columns())
                 if family.function in ("tanh", "stribeck")}
        return len(signs & set(held))

    def sign_scale(self, role: str) -> float:
        """The scale a of the smoothed sign tanh(a·z) of variable ``role`` ("x" or
        "x_dot"): 1/(ε·RMS z), ε = :attr:`sign_width`."""
        return 1.0 / (self.sign_width * self.scales[role])

    def default_feature(self, family: Family) -> sp.Expr:
        """``family``'s member with default inner constants: sin(z), cos(z), tanh(z/ε) =
        smoothed sign(z), exp(±z/RMS z) (exp's two slots), sinh and cosh of z/RMS z,
        exp(−(z/vs)²)·tanh(z/ε) with vs = RMS(z)/10 (stribeck)."""
        scale = self.scales[family.role]
        sign = self.sign_scale(family.role)
        theta = {"abs": (), "tanh": (sign,), "sin": (1.0, 0.0), "cos": (1.0, 0.0),
                 "stribeck": (10.0 / scale, sign)}.get(family.function,
                                                      ((-1) ** family.slot / scale,))
        return family.feature(self.symbols, theta)

    def feature_tree(self, feature: sp.Expr) -> tuple:
        """A tree for a feature (powers of x, x', t and inputs, products, constant)."""
        return _expression_tree(feature, self.symbols)

    def population(self, records: list[Record]) -> Population:
        return to_population([r.coefficients for r in records], self.evaluator)

    def held(self, records: list[Record]) -> tuple[np.ndarray, np.ndarray]:
        """What refinement holds per record: the forcing column held at 1 (the first
        input, −1: none) and the inner constants held (``Record.held``), as
        :meth:`gpjax._refine.Refiner.refine` takes them."""
        u0 = self.symbols.u[0] if self.symbols.u else None
        fixed = np.array([self.evaluator.forcing_index(u0)
                          if u0 is not None and u0 in r.coefficients.forcing else -1
                          for r in records])
        inner = np.zeros((len(records), self.evaluator.n_inner), dtype=bool)
        for i, record in enumerate(records):
            inner[i, list(record.held)] = True
        return fixed, inner

    def _score_records(self, records: list[Record]) -> None:
        scores = self.evaluator.score(self.population(records))
        _store(records, scores)

    def adopt(self, records: list[Record]) -> list[Record]:
        """Copies of ``records`` (from a run at another step count) scored, refined and
        cached here; returns the copies."""
        copies = [dataclasses.replace(r, refined=False, converged=False)
                  for r in records if r.valid]
        self._score_records(copies)
        for record in copies:
            self.records[record.key] = record
        self.refine(copies)
        return copies

    def refine(self, records: list[Record], *, to_convergence: bool = False) -> None:
        """Refine the constants of ``records`` (in place) on the simulated response: one
        round of ``refine_iterations`` Levenberg–Marquardt steps from the least-squares
        start; with ``to_convergence`` further rounds, each from the last constants, until a
        round lowers the objective by less than :data:`gpjax._refine.CONVERGED` (relative),
        at most :data:`gpjax._refine.MAX_ROUNDS` rounds in all
        (:func:`gpjax._refine.until_converged`)."""
        self._refine_round([r for r in records if r.valid and not r.refined])
        if not to_convergence:
            return
        pending = [r for r in records if r.valid and r.status == OK and not r.converged]

        def refine_round(active):
            chosen = [pending[i] for i in active]
            self._refine_round(chosen)
            return [r.objective for r in chosen]

        until_converged(refine_round, [r.objective for r in pending], rounds=MAX_ROUNDS - 1)
        for record in pending:
            record.converged = True  # converged, or MAX_ROUNDS reached: not refined again

    def _refine_round(self, records: list[Record]) -> None:
        """One refinement of ``records`` from their current constants; a record keeps them
        where the refined ones do not score lower."""
        if not records:
            return
        population = self.population(records)
        refined = self.refiner.refine(population, *self.held(records))
        scores = self.evaluator.score(refined.population)
        moved = from_population(refined.population, self.evaluator,
                                [r.coefficients for r in records])
        for i, record in enumerate(records):
            record.refined = True
            if scores.status[i] != OK or scores.objective[i] >= record.objective:
                continue  # refinement did not help: keep the start values
            record.coefficients = moved[i]
            _store([record], _row(scores, i))


def _hyperbolic_pairs(state: dict[sp.Expr, float]) -> dict[sp.Expr, float]:
    """``state`` with each pair c1·exp(a·z) + c2·exp(−a·z) (one scale, opposite signs)
    rewritten by sympy as (c1 − c2)·sinh(a·z) + (c1 + c2)·cosh(a·z), a part whose
    coefficient cancels to within 1e-12 of the pair's dropped: a tree's sinh stays one
    term with one inner constant (:mod:`gpjax._features`)."""
    for first in [f for f in state if isinstance(f, sp.exp)]:
        second = sp.exp(-first.args[0])
        if first not in state or second not in state:
            continue
        pair = state.pop(first) * first + state.pop(second) * second
        rewritten = sp.expand(pair.rewrite(sp.cos))  # sympy's exp -> sinh + cosh rewrite
        size = max(abs(float(c)) for c in rewritten.as_coefficients_dict().values())
        for term, c in rewritten.as_coefficients_dict().items():
            if abs(float(c)) > 1e-12 * size:
                state[term] = state.get(term, 0.0) + float(c)
    return state


def _expression_tree(expression: sp.Expr, symbols: Symbols) -> tuple:
    leaves = {symbols.x: ("x",), symbols.x_dot: ("x_dot",), symbols.t: ("t",)}
    leaves.update({u: ("u", k) for k, u in enumerate(symbols.u)})
    if expression in leaves:
        return leaves[expression]
    if expression.is_Number:
        return ("n", float(expression))
    if expression.is_Pow and expression.exp.is_Integer and expression.exp > 0:
        base = _expression_tree(expression.base, symbols)
        tree = base
        for _ in range(int(expression.exp) - 1):
            tree = ("mul", base, tree)
        return tree
    functions = {sp.sin: "sin", sp.cos: "cos", sp.tanh: "tanh", sp.exp: "exp", sp.sinh: "sinh",
                 sp.cosh: "cosh", sp.Abs: "abs", sp.sign: "sign"}
    if expression.func in functions:
        return (functions[expression.func], _expression_tree(expression.args[0], symbols))
    if expression.is_Mul or expression.is_Add:
        head = "mul" if expression.is_Mul else "add"
        parts = [_expression_tree(a, symbols) for a in expression.args]
        tree = parts[0]
        for part in parts[1:]:
            tree = (head, tree, part)
        return tree
    raise ValueError(f"feature {expression} has no tree form")


def _row(scores: Scores, i: int) -> Scores:
    return Scores(*(np.asarray(getattr(scores, f.name))[i:i + 1]
                    for f in dataclasses.fields(Scores)))


def _store(records: list[Record], scores: Scores) -> None:
    for i, record in enumerate(records):
        record.objective = float(scores.objective[i])
        record.f_time = float(scores.f_time[i])
        record.f_freq = float(scores.f_freq[i])
        record.rms = float(scores.rms[i])
        record.status = int(scores.status[i])
        if record.status == OK:
            record.coefficients = record.coefficients.replace(
                y0=(float(scores.y0[i, 0]), float(scores.y0[i, 1])))
