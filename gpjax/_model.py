"""The identified model: one Newton–Euler equation per measured coordinate (D ≥ 1).

Equation i reads ``m_i·x_i'' + Σ c·φ + Σ p·g(t)·h = Σ g·ψ(t, u)``: its state features φ
depend on x_i alone, on x_i' alone (eqs. 5–6), or, with several coordinates, on a relative
coordinate x_i − x_j or x_i' − x_j' alone (eqs. 21–22); its forcing features ψ on time and
the inputs alone. ``parametric`` terms are *declared* time-varying terms g(t)·h(x_i) or
g(t)·h(x_i') (an extension of eqs. 5–6, e.g. ``cos(1790.7*t)*phi`` for a mesh stiffness
varying at the mesh frequency). A single coordinate is D = 1; its equation is also reached
through the one-equation views (:attr:`Model.mass`, :attr:`Model.state`, …).

The file (``model.json``) is read and written by :mod:`gpjax._model_file`.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import re
from collections import OrderedDict
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import sympy as sp

from ._canonical import Symbols
from ._coefficients import Coefficients, Population, to_population, to_system_population
from ._data import Measurement
from ._errors import ModelFileError
from ._evaluator import PopulationEvaluator, split_state_features
from ._evaluator_columns import grown_capacity
from ._expressions import parse_expression
from ._objective import default_n_bins
from ._reference import prepared_reference_response, reference_response
from ._system_bank import KINDS, bank_of
from ._uncertainty import Uncertainty
from ._weak_form import estimate_initial_conditions


@dataclasses.dataclass(frozen=True)
class Equation:
    """One coordinate's equation: feature text -> constant.

    Attributes:
        mass: inertia coefficient m (non-zero).
        state: features of the coordinate (or of a relative coordinate) -> c.
        forcing: features of time and inputs -> g ("1" is a constant force).
        parametric: declared time-varying terms g(t)·h(x) or g(t)·h(x') -> p, on the
            left-hand side like ``state``.
    """

    mass: float
    state: dict[str, float]
    forcing: dict[str, float]
    parametric: dict[str, float] = dataclasses.field(default_factory=dict)


@dataclasses.dataclass(frozen=True)
class Model:
    """D equations, one per coordinate, with their names and initial states.

    Attributes:
        coordinates: the response names, one per equation (D ≥ 1).
        time: the time column's name.
        inputs: the input columns' names.
        equations: one :class:`Equation` per coordinate.
        initial_states: (x_i, x_i') of every coordinate at the first sample of the data the
            model was fitted to; ``None``: estimate them from the data when simulating.
        metrics: rms, objective, … on the fitting data (may be empty).
        provenance: free-form facts about the run (seed, generations, tree, …).
        input_interpolation: how inputs are reconstructed between samples when simulating,
            ``"linear"``, ``"bandlimited"`` or ``"hold"`` (:func:`gpjax._data.between_samples`).
        substeps: RK4 steps per sample interval the constants were fitted with.
        convergence: the check of that integration against the reference solve
            (:meth:`gpjax._convergence.Convergence.to_json`), or ``None``.
        uncertainty: standard errors, 95 % intervals and correlations of the constants
            and initial states (:mod:`gpjax._uncertainty`), or ``None``.
        third_law: every coupling term acts on both of its coordinates with opposite
            signs, its constants tied (:mod:`gpjax._system_couplings`).
    """

    coordinates: tuple[str, ...]
    time: str
    inputs: tuple[str, ...]
    equations: tuple[Equation, ...]
    initial_states: tuple[tuple[float, float], ...] | None = None
    metrics: dict = dataclasses.field(default_factory=dict)
    provenance: dict = dataclasses.field(default_factory=dict)
    input_interpolation: str = "linear"
    substeps: int = 1
    convergence: dict | None = None
    uncertainty: Uncertainty | None = None
    third_law: bool = False

    # --- construction -------------------------------------------------------------------
    @classmethod
    def single(cls, symbols: Symbols, *, mass: float, state: dict[str, float],
               forcing: dict[str, float], parametric: dict[str, float] | None = None,
               initial_conditions: tuple[float, float] | None = None, **fields) -> "Model":
        """The model of one coordinate (``symbols``: its response, time and inputs);
        ``initial_conditions`` its (x, x'); ``fields`` as the constructor's."""
        return cls(coordinates=(symbols.response,), time=symbols.time, inputs=symbols.inputs,
                   equations=(Equation(mass, dict(state), dict(forcing), dict(parametric or {})),),
                   initial_states=None if initial_conditions is None else (
                       tuple(map(float, initial_conditions)),), **fields)

    @classmethod
    def from_coefficients(cls, symbols: Symbols, coefficients: Coefficients,
                          **fields) -> "Model":
        """The one-coordinate model of ``coefficients`` (:meth:`from_equations`)."""
        return cls.from_equations((symbols.response,), symbols.time, symbols.inputs,
                                  [coefficients], **fields)

    @classmethod
    def from_equations(cls, coordinates: Sequence[str], time: str, inputs: Sequence[str],
                       equations: Sequence[Coefficients], **fields) -> "Model":
        """The model of one :class:`Coefficients` per coordinate (time-varying left-hand
        terms become ``parametric``; finite ``y0`` of every equation the initial states);
        ``fields`` as the constructor's. Its features are not parsed again."""
        t = sp.Symbol(time)
        out = []
        for coefficients in equations:
            lhs = coefficients.state.items()
            out.append(Equation(coefficients.mass,
                                {str(f): v for f, v in lhs if t not in f.free_symbols},
                                {str(f): v for f, v in coefficients.forcing.items()},
                                {str(f): v for f, v in lhs if t in f.free_symbols}))
        y0 = [tuple(map(float, c.y0)) for c in equations]
        model = cls(coordinates=tuple(coordinates), time=time, inputs=tuple(inputs),
                    equations=tuple(out),
                    initial_states=tuple(y0) if all(map(math.isfinite, np.ravel(y0))) else None,
                    **fields)
        model.__dict__["_parsed"] = tuple({str(f): f for f in (*c.state, *c.forcing)}
                                          for c in equations)
        return model

    # --- the coordinates ----------------------------------------------------------------
    @property
    def n_coordinates(self) -> int:
        """D, the number of coordinates (equations)."""
        return len(self.coordinates)

    def symbols_of(self, i: int) -> Symbols:
        """The symbols of coordinate ``i``'s equation (its response, time, inputs)."""
        return Symbols(self.coordinates[i], self.time, self.inputs)

    def _one(self, what: str) -> int:
        if self.n_coordinates != 1:
            raise ValueError(f"{what} is that of a single coordinate; this model has "
                             f"{self.n_coordinates} ({', '.join(self.coordinates)}): use "
                             f"model.equations[i] or the methods' i argument")
        return 0

    @property
    def symbols(self) -> Symbols:
        """The one coordinate's symbols (raises ValueError for several coordinates)."""
        return self.symbols_of(self._one("symbols"))

    @property
    def mass(self) -> float:
        return self.equations[self._one("mass")].mass

    @property
    def state(self) -> dict[str, float]:
        return self.equations[self._one("state")].state

    @property
    def forcing(self) -> dict[str, float]:
        return self.equations[self._one("forcing")].forcing

    @property
    def parametric(self) -> dict[str, float]:
        return self.equations[self._one("parametric")].parametric

    @property
    def initial_conditions(self) -> tuple[float, float] | None:
        """The one coordinate's (x, x') at the first sample, or ``None``."""
        self._one("initial_conditions")
        return None if self.initial_states is None else self.initial_states[0]

    # --- symbolic views -----------------------------------------------------------------
    def names(self) -> set[str]:
        """Every symbol name the equations may use."""
        return {self.time, *self.inputs, *(n for c in self.coordinates
                                           for n in (c, f"{c}_dot", f"{c}_ddot"))}

    @functools.cached_property
    def _parsed(self) -> tuple[dict[str, sp.Expr], ...]:
        """Every equation's feature texts parsed (once) by the whitelist parser."""
        names = self.names()
        return tuple({text: parse_expression(text, names)
                      for text in (*e.state, *e.parametric, *e.forcing)}
                     for e in self.equations)

    def _feature(self, text: str, i: int = 0) -> sp.Expr:
        return self._parsed[i][text]

    @functools.cached_property
    def system(self) -> tuple[Coefficients, ...]:
        """The constants keyed by sympy feature, one per coordinate; ``state`` holds the
        parametric terms too, ``y0`` the initial state (NaN when not set)."""
        out = []
        for i, e in enumerate(self.equations):
            y0 = self.initial_states[i] if self.initial_states else (math.nan, math.nan)
            out.append(Coefficients(
                mass=e.mass,
                state={self._feature(t, i): v for t, v in (*e.state.items(),
                                                         *e.parametric.items())},
                forcing={self._feature(t, i): v for t, v in e.forcing.items()},
                y0=tuple(y0)))
        return tuple(out)

    @property
    def coefficients(self) -> Coefficients:
        """The one coordinate's :class:`Coefficients` (:attr:`system`)."""
        return self.system[self._one("coefficients")]

    def constant_names(self) -> dict[str, tuple[int, str, str]]:
        """Constant name -> (equation, part, feature): per equation m; k1, k2 … for
        position terms; c1 … for velocity terms; p1 … for parametric (time-varying) terms;
        g1 … for forcing terms other than the normalising input (:meth:`normaliser`).
        With several coordinates each name is prefixed by its coordinate, ``x2.k1``."""
        names: dict[str, tuple[int, str, str]] = {}
        for i, e in enumerate(self.equations):
            prefix = f"{self.coordinates[i]}." if self.n_coordinates > 1 else ""
            velocities = {sp.Symbol(f"{c}_dot") for c in self.coordinates}
            names[f"{prefix}m"] = (i, "mass", "")
            k = c = g = 0
            for feature in e.state:
                if self._feature(feature, i).free_symbols & velocities:
                    c += 1
                    names[f"{prefix}c{c}"] = (i, "state", feature)
                else:
                    k += 1
                    names[f"{prefix}k{k}"] = (i, "state", feature)
            for p, feature in enumerate(e.parametric, start=1):
                names[f"{prefix}p{p}"] = (i, "parametric", feature)
            for feature in e.forcing:
                if self.normaliser(i) == feature:
                    continue
                g += 1
                names[f"{prefix}g{g}"] = (i, "forcing", feature)
        return names

    def normaliser(self, i: int = 0) -> str | None:
        """The input that normalises equation ``i`` (the first of the model's inputs in
        it, with coefficient ±1; not a named constant), or ``None``."""
        forcing = self.equations[i].forcing
        first = next((u for u in self.inputs if u in forcing), None)
        return first if first is not None and abs(forcing[first]) == 1.0 else None

    def unscaled(self) -> list[int]:
        """The equations normalised by their mass (held at 1) for want of an input: each
        is identified only up to a factor, so its constants are per unit of its mass."""
        return [i for i, e in enumerate(self.equations)
                if self.normaliser(i) is None and e.mass == 1.0]

    def constants(self) -> dict[str, float]:
        values = {}
        for name, (i, part, feature) in self.constant_names().items():
            e = self.equations[i]
            values[name] = e.mass if part == "mass" else getattr(e, part)[feature]
        return values

    def _index(self, i: int | None) -> int:
        return self._one("the equation") if i is None else range(self.n_coordinates)[i]

    def equation(self, i: int | None = None, *, numeric: bool = False) -> sp.Eq:
        """Coordinate ``i``'s ``Eq(lhs, rhs)`` with named constants, or with their values
        if ``numeric`` (``i`` may be left out for a single coordinate)."""
        i = self._index(i)
        values = self.constants()
        symbols = self.symbols_of(i)

        def term(name, feature):  # a relative coordinate's term is not multiplied out
            value = sp.Float(values[name]) if numeric else sp.Symbol(name)
            return sp.Mul(value, feature, evaluate=not isinstance(feature, sp.Add))
        lhs, rhs = sp.Integer(0), sp.Integer(0)
        for name, (e, part, feature) in self.constant_names().items():
            if e != i:
                continue
            if part == "mass":
                lhs += term(name, symbols.x_ddot)
            elif part in ("state", "parametric"):
                lhs += term(name, self._feature(feature, i))
            else:
                rhs += term(name, self._feature(feature, i))
        normaliser = self.normaliser(i)
        if normaliser is not None:
            rhs += int(self.equations[i].forcing[normaliser]) * sp.Symbol(normaliser)
        return sp.Eq(lhs, rhs, evaluate=False)

    def sympy(self, i: int | None = None):
        """Coordinate ``i``'s equation with numeric constants; without ``i``, the one
        equation of a single coordinate or the list of all."""
        if i is None and self.n_coordinates > 1:
            return [self.equation(k, numeric=True) for k in range(self.n_coordinates)]
        return self.equation(i, numeric=True)

    def latex(self, i: int | None = None, *, numeric: bool = False):
        """LaTeX of :meth:`equation` (a list for all of several coordinates without ``i``);
        derivatives print as \\dot{x} and \\ddot{x}. ``numeric``: the constants' values,
        as (value \\pm half of the 95 % interval) where the uncertainty is known."""
        if i is None and self.n_coordinates > 1:
            return [self.latex(k, numeric=numeric) for k in range(self.n_coordinates)]
        names = {}
        for c in self.coordinates:
            base = sp.latex(sp.Symbol(c))
            names |= {sp.Symbol(c): base, sp.Symbol(f"{c}_dot"): rf"\dot{{{base}}}",
                      sp.Symbol(f"{c}_ddot"): rf"\ddot{{{base}}}"}
        if numeric:
            names |= {sp.Symbol(name): _latex_value(text)
                      for name, text in self.constant_texts(latex=True).items()}
        else:
            names |= {sp.Symbol(name): _latex_name(name) for name in self.constant_names()}
        return sp.latex(self.equation(i), symbol_names=names)

    def constant_texts(self, *, latex: bool = False) -> dict[str, str]:
        """Name -> the constant's value as text, with ± half of its 95 % interval where
        the uncertainty is known (``latex``: ``\\pm`` and no exponent ``e``)."""
        texts = {}
        for name, value in self.constants().items():
            half = self.uncertainty.half_width(name) if self.uncertainty and (
                name in self.uncertainty.names) else None
            text = f"{value:.6g}" if half is None else f"{value:.6g} ± {half:.2g}"
            texts[name] = text.replace("±", r"\pm") if latex else text
        return texts

    def couplings(self) -> dict[tuple[int, int], sp.Expr]:
        """With ``third_law``, the coupling force F_ij of every coupled pair i < j (0-based
        equation numbers) with numbers: +F_ij in equation i, −F_ij in equation j."""
        out: dict[tuple[int, int], sp.Expr] = {}
        for tie in self.ties():
            (i, feature), (j, _) = tie.source, tie.mirror
            key = (min(i, j), max(i, j))
            term = sp.Float(self.system[i].state[feature]) * feature * (1 if i < j else -1)
            out[key] = out.get(key, sp.Integer(0)) + term
        return out

    def ties(self) -> tuple:
        """The :class:`gpjax._system_couplings.Tie` of every coupling term (none without
        ``third_law``)."""
        if not self.third_law:
            return ()
        from ._system_couplings import couple

        structure = tuple((tuple(e.state), e.forcing) for e in self.system)
        return couple(structure, self.coordinates)[1]

    def __str__(self) -> str:
        constants = ", ".join(f"{k} = {v}" for k, v in self.constant_texts().items())
        equations = "\n".join(str(self.equation(i)) for i in range(self.n_coordinates))
        return f"{equations}   with {constants}"

    # --- simulation ---------------------------------------------------------------------
    def evaluator(self, measurement: Measurement, *,
                  substeps: int | None = None, **options) -> PopulationEvaluator:
        """An RK4 evaluator on ``measurement`` whose basis holds this model's features
        (``substeps`` default: the model's; ``options``: :class:`PopulationEvaluator`'s; for
        a system, ``kinds`` are bank kinds it holds beside the model's own: a search's,
        so that refits of its structures share the compiled programs). Its forcing basis
        starts with room for the model's own forcing features (the next power of two), not
        a search's."""
        forcing = {f for c in self.system for f in c.forcing}
        settings = dict(substeps=substeps or self.substeps,
                        input_interpolation=self.input_interpolation,
                        forcing_capacity=options.pop("forcing_capacity",
                                                     grown_capacity(len(forcing), 1)))
        if self.n_coordinates == 1:
            degree, extra, families = split_state_features(self.coefficients.state,
                                                           self.symbols)
            return _evaluator(measurement, self.symbols, max_degree=degree,
                              extra_state_features=extra, families=families,
                              **settings, **options)
        kinds, scales = bank_of(self.coordinates, [list(c.state) for c in self.system])
        kinds = tuple(k for k in KINDS if k in {*kinds, *options.pop("kinds", ())})
        return PopulationEvaluator(measurement, self.symbols_of(0), kinds=kinds,
                                   sign_scales=scales,
                                   **{"max_degree": self.max_power(), **settings, **options})

    def max_power(self) -> int:
        """The highest integer power among the state features (at least 1)."""
        powers = [int(p) for c in self.system for f in c.state
                  for p in [f.as_base_exp()[1]] if p.is_Integer]
        return max([1, *powers])

    def population(self, evaluator: PopulationEvaluator, y0) -> Population:
        """This model as a population of one on ``evaluator``, starting from ``y0``
        ((2,) or (D, 2))."""
        y0 = np.reshape(np.asarray(y0, dtype=np.float64), (self.n_coordinates, 2))
        equations = [c.replace(y0=tuple(map(float, s))) for c, s in zip(self.system, y0)]
        if self.n_coordinates == 1:
            return to_population(equations, evaluator)
        return to_system_population([equations], evaluator)

    def estimated_initial_states(self, measurement: Measurement) -> np.ndarray:
        """(D, 2): every coordinate's (x, x') at the first sample by eq. 13."""
        return np.array([estimate_initial_conditions(measurement.coordinate(d))
                         for d in range(measurement.n_coordinates)])

    def simulate(self, measurement: Measurement, *, initial_conditions=None,
                 solver: str = "reference") -> np.ndarray:
        """The response on ``measurement``'s time grid and inputs: (N,) for a single
        coordinate, else (N, D).

        Args:
            measurement: time grid and inputs (names as the model's); where it holds the
                responses, they set the solver's scale.
            initial_conditions: (x, x') or (D, 2) at the first sample; default: estimated
                from the measurement's first samples (eq. 13).
            solver: ``"reference"`` (adaptive diffrax Dopri8, :mod:`gpjax._reference`) or
                ``"rk4"`` (the fixed-step integrator the model was fitted with).

        Raises:
            ModelFileError: the measurement's inputs differ from the model's.
            ValueError: an unknown solver.
        """
        if solver not in ("reference", "rk4"):
            raise ValueError(f"solver must be 'reference' or 'rk4', got {solver!r}")
        _check_inputs(self, measurement)
        y0 = (self.estimated_initial_states(measurement) if initial_conditions is None
              else initial_conditions)
        if solver == "rk4":
            evaluator = self.evaluator(measurement)
            responses, _ = evaluator.simulate(self.population(evaluator, y0))
            return _shaped(np.asarray(responses[0]).T)
        return self.prepared_simulation(measurement, initial_conditions=y0)()

    def prepared_simulation(self, measurement: Measurement, *,
                            initial_conditions=None) -> Callable[[], np.ndarray]:
        """:meth:`simulate` by the reference solve, compiled (or loaded) now and run when
        the returned function is called, which may be in another thread: a convergence
        check's reference solved beside other work
        (:func:`gpjax._convergence.reference_started`). Arguments and errors as
        :meth:`simulate`'s."""
        _check_inputs(self, measurement)
        y0 = (self.estimated_initial_states(measurement) if initial_conditions is None
              else initial_conditions)
        solve = prepared_reference_response(self, measurement.time, measurement.inputs, y0,
                                            scale=measurement_scale(measurement))
        return lambda: _shaped(solve()[0])

    def simulate_inputs(self, time: np.ndarray, inputs: dict[str, np.ndarray],
                        initial_conditions, *, scale=None) -> np.ndarray:
        """The response ((N,) for one coordinate, else (N, D)) to ``inputs``
        (name -> (N,)) at uniform sample ``time`` (s) from ``initial_conditions``
        ((x, x') or (D, 2)), by the reference solve; NaN if it fails.

        ``scale``: typical sizes of each x and x' ((2,) or (D, 2); the solver's absolute
        tolerance applies to x/scale; :func:`measurement_scale` of a measured response).
        Default: the spread of a first solve scaled by the initial state, solved again at
        that spread where it is more than 10x away (a record started at rest has no scale
        of its own).

        Raises:
            ModelFileError: an input of the model is missing.
        """
        missing = [u for u in self.inputs if u not in inputs]
        if missing:
            raise ModelFileError(f"input {missing[0]!r} of the model is not given; pass every "
                                 f"input of {list(self.inputs)}")
        time = np.asarray(time, dtype=np.float64)
        inputs = {u: np.asarray(inputs[u], dtype=np.float64) for u in self.inputs}
        y0 = np.reshape(np.asarray(initial_conditions, dtype=np.float64), (-1, 2))

        def solve(scale):
            return _shaped(reference_response(self, time, inputs, y0, scale=scale)[0])

        if scale is not None:
            return solve(np.reshape(np.asarray(scale, dtype=np.float64), (-1, 2)))
        used = np.abs(y0)
        response = solve(used)
        if not np.all(np.isfinite(response)) or time.size < 2:
            return response
        spread = _spread(np.reshape(response, (time.size, -1)), time[1] - time[0])
        used = np.where(used > 0, used, 1.0)
        if np.all(spread > 0) and np.any(np.abs(np.log10(spread / used)) > 1):
            response = solve(spread)
        return response

    # --- JSON ---------------------------------------------------------------------------
    def to_json(self) -> dict:
        """The file's content (:mod:`gpjax._model_file`)."""
        from ._model_file import model_to_json
        return model_to_json(self)

    def save(self, path: str | Path) -> None:
        from ._model_file import save_model
        save_model(self, path)

    @classmethod
    def from_json(cls, data: dict, *, source: str = "model") -> "Model":
        """Build from parsed JSON of any version (:func:`gpjax._model_file.model_from_json`).

        Raises:
            ModelFileError: a missing or malformed field, an expression outside the
                whitelist, or an equation that breaks the structure rules.
        """
        from ._model_file import model_from_json
        return model_from_json(data, source=source)

    @classmethod
    def load(cls, path: str | Path) -> "Model":
        """Read ``model.json`` of any version; any problem is a :class:`ModelFileError`."""
        from ._model_file import load_model
        return load_model(path)


def _shaped(responses: np.ndarray) -> np.ndarray:
    """(N,) for one coordinate, else the (N, D) as given."""
    return responses[:, 0] if responses.ndim == 2 and responses.shape[1] == 1 else responses


def _latex_value(text: str) -> str:
    """A constant's text as LaTeX: ``1.2e-05`` as ``1.2 \\cdot 10^{-5}``, in parentheses
    when it carries a ``\\pm``."""
    def power(match):
        return rf"{match.group(1)} \cdot 10^{{{int(match.group(2))}}}"
    out = re.sub(r"([0-9.]+)e([+-]?[0-9]+)", power, text)
    return f"({out})" if r"\pm" in out or out.startswith("-") else out


def _latex_name(name: str) -> str:
    """``k1`` as ``k_{1}``; ``x2.k1`` as ``k_{1}^{(x_{2})}``."""
    coordinate, _, own = name.rpartition(".")
    letter, digits = own[0], own[1:]
    base = f"{letter}_{{{digits}}}" if digits else letter
    return f"{base}^{{({sp.latex(sp.Symbol(coordinate))})}}" if coordinate else base


def measurement_scale(measurement: Measurement) -> np.ndarray:
    """(D, 2): typical sizes of every coordinate's x and x' in a measurement, the spreads
    of its response and of its sample-to-sample rate."""
    return _spread(measurement.responses, measurement.dt)


def _spread(x: np.ndarray, dt: float) -> np.ndarray:
    """(D, 2): the spreads of every column of ``x`` (N, D) and of its rate (``dt`` in s)."""
    return np.stack([x.std(axis=0), np.diff(x, axis=0).std(axis=0) / dt], axis=1)


#: Evaluators kept for repeated simulations (:func:`_evaluator`), most recent last.
_EVALUATORS: OrderedDict = OrderedDict()
EVALUATOR_CACHE_SIZE = 8


def _evaluator(measurement: Measurement, symbols: Symbols, **settings) -> PopulationEvaluator:
    """An RK4 evaluator on ``measurement`` with ``settings`` (default: one model per
    call), reused across calls with the same data and settings (its compiled simulation
    with it)."""
    key = (measurement.fingerprint(), symbols, tuple(sorted(settings.items())))
    if key in _EVALUATORS:
        _EVALUATORS.move_to_end(key)
        return _EVALUATORS[key]
    evaluator = PopulationEvaluator(measurement, symbols, **{
        "batch": 1, "n_bins": min(default_n_bins(measurement.response), 256), **settings})
    _EVALUATORS[key] = evaluator
    while len(_EVALUATORS) > EVALUATOR_CACHE_SIZE:
        _EVALUATORS.popitem(last=False)
    return evaluator


def release_evaluators() -> None:
    """Drop the evaluators kept for repeated simulations (their arrays and programs),
    e.g. between a fit and a diagnosis of another record length or step count."""
    _EVALUATORS.clear()


def _check_inputs(model: Model, measurement: Measurement) -> None:
    if tuple(measurement.input_names) != tuple(model.inputs):
        raise ModelFileError(f"the model's inputs {list(model.inputs)} differ from the "
                             f"data's {list(measurement.input_names)}; pass the same --input columns")


#: Gauss–Newton steps of :func:`fitted_initial_state` at most.
INITIAL_STATE_STEPS = 4


def fitted_initial_state(model: Model, measurement: Measurement, start) -> np.ndarray:
    """The initial state with which ``model`` best reproduces ``measurement``'s
    response(s), (2,) or (D, 2): Gauss–Newton steps on the simulated response from
    ``start`` (eq. 13's estimate), by the evaluator's own initial-state step (exact
    sensitivities), while the objective falls.

    Why not eq. 13's estimate alone: it is a Savitzky–Golay polynomial evaluated at the
    record's first sample, the point where its noise is largest, and a lightly damped
    model carries that error through the whole record (a 2-mass chain started at rest:
    x1(0) estimated 5σ from 0, 5 % NRMS against 1 % from the true state)."""
    evaluator = model.evaluator(measurement, fit_initial_conditions=True)
    y0, best = np.asarray(start, dtype=np.float64), math.inf
    for _ in range(INITIAL_STATE_STEPS):
        scores = evaluator.score(model.population(evaluator, y0))
        objective = float(scores.objective[0])
        if not (math.isfinite(objective) and objective < best * (1 - 1e-6)):
            break
        y0, best = np.asarray(scores.y0[0], dtype=np.float64), objective
    return y0


def simulate_model(model: Model, measurement: Measurement, *, initial_conditions=None):
    """Simulate ``model`` by its fixed-step RK4 (``model.substeps``) on ``measurement``'s
    time grid and inputs.

    Returns (response (N,) or (N, D), scores). Initial conditions: the argument, else
    estimated from the measurement (eq. 13).
    """
    _check_inputs(model, measurement)
    y0 = (model.estimated_initial_states(measurement) if initial_conditions is None
          else initial_conditions)
    evaluator = model.evaluator(measurement)
    responses, scores = evaluator.simulate(model.population(evaluator, y0))
    return _shaped(np.asarray(responses[0]).T), scores
