"""Run configuration: one frozen object that validates itself on construction.

Every field has a documented default; ``GPConfig.from_toml`` and ``GPConfig.from_dict``
refuse unknown keys and wrong types with a :class:`~gpjax.ConfigError` naming the key.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from pathlib import Path
from typing import Any

from ._convergence import MAX_SUBSTEPS
from ._data import INPUT_INTERPOLATIONS
from ._errors import ConfigError, read_user_file

#: Function-set names and their arity. ``div`` is protected (a/0 is 1); ``sqrt`` and ``log``
#: act on |a| (log 0 is 0). The unary functions go beyond the paper's eq. 10; a state term
#: they make must be a member of the feature bank (:mod:`gpjax._features`).
FUNCTIONS = {"add": 2, "sub": 2, "mul": 2, "div": 2, "sin": 1, "cos": 1, "tanh": 1, "exp": 1,
             "sinh": 1, "cosh": 1, "abs": 1, "sign": 1, "sqrt": 1, "log": 1}
#: Variable roles a tree may use: the response x, its derivatives, every input u, time t.
VARIABLES = ("x", "x_dot", "x_ddot", "u", "t")
COEFFICIENT_MODES = ("least_squares", "tree")
#: How an input may enter the forcing (``GPConfig.input_forcing``).
INPUT_FORCINGS = ("linear", "any")
#: The wide function set the README documents (friction, pendulums, saturation, stiffening).
WIDE_FUNCTIONS = ("add", "sub", "mul", "sin", "abs", "sign", "tanh", "exp")
#: Fields of one coordinate's grammar, not (yet) of the search over systems: a system's
#: trees use the states and inputs, its constants come from least squares, and its initial
#: states are found. Its functions are those of
#: :data:`gpjax._system_bank.SYSTEM_FUNCTIONS`.
ONE_COORDINATE = ("variables", "named_constants", "interval_constants",
                  "coefficients", "initial_conditions")


@dataclasses.dataclass(frozen=True, kw_only=True)
class GPConfig:
    """Settings of one genetic-programming run (paper §2, §5; defaults follow the paper).

    Attributes:
        population: individuals per generation (paper: 500).
        generations: maximum number of generations, stop rule 1 (paper: 10).
        epsilon: stop when the best objective f <= epsilon × f_0, stop rule 2, eq. 12; f_0
            is the objective of the constant model at the response's mean
            (:func:`gpjax._objective.stop_objective`), so the rule does not depend on the
            response's units. Default 0: off, every run has its ``generations`` (the
            paper's f <= 0.01 is in its record's units; :meth:`paper` sets 0.01).
        p_crossover, p_mutation, p_perturbation, p_reproduction: operator probabilities
            (paper: 0.63 / 0.27 / 0.09 / 0.01); they must sum to 1.
        functions: function set, eq. 1/10; names from ``add, sub, mul, div`` (div is
            protected) and, beyond the paper, ``sin, cos, tanh, exp, sinh, cosh, abs, sign,
            sqrt, log``
            (their state terms must be feature-bank members, :mod:`gpjax._features`).
        variables: variable roles a tree may use, eq. 2/11: ``x`` (response), ``x_dot``,
            ``x_ddot``, ``u`` (every input column), ``t`` (time).
        named_constants: constants with a fixed value, e.g. ``{"J": 7.918e-5, "N1": 19}``.
        interval_constants: constants drawn afresh each time they enter a tree, uniformly from
            one of their intervals, e.g. ``{"k1": [[0.1, 20], [800, 1000]]}`` (eq. 11).
        real_interval: interval of ephemeral random reals ``Rnd[real]``.
        int_interval: interval of ephemeral random integers ``Rnd[int]``.
        max_depth: tree depth limit (root has depth 0); offspring deeper than this are
            replaced by a copy of their parent.
        max_size: node-count limit, likewise.
        init_depth: (min, max) depth of the ramped half-and-half initial population.
        max_degree: highest power of x or x_dot a canonical term may carry; a higher one makes
            the candidate invalid (a limit against bloat, not a physical rule).
        tournament_size: individuals drawn per tournament when selecting parents;
            ``None`` means min(7, population).
        w_time, w_freq: weights w1, w2 of the objective, eq. 7 (paper: 1, 1).
        n_bins: number m of spectral amplitudes in f_freq, eq. 9; ``None`` picks the
            smallest m whose bins (DC included) hold 99 % of the measured response's AC
            spectral energy (:func:`gpjax._objective.default_n_bins`).
        coefficients: ``"least_squares"`` sets every candidate's coefficients by
            equation-error least squares (the structure comes from GP, the numbers from data);
            ``"tree"`` uses the constants written in the tree, as the paper does.
        refine_top: best distinct structures per generation whose coefficients are refined
            on the simulated response (optimistix Levenberg–Marquardt); 0 turns it off.
            In tree mode every new candidate is refined from its tree's constants before
            it competes (Lamarckian), and refine_top only matters as 0 (no refinement).
        refine_iterations: maximum Levenberg–Marquardt steps per refinement.
        substeps: fixed RK4 steps per sample interval, or ``"auto"``: chosen from the data's
            bandwidth for the search, then raised (and the reported model refitted) until
            the reported model's RK4 response agrees with an adaptive high-order reference
            solve to ``convergence_tolerance`` (:mod:`gpjax._convergence`). A number is
            used as given, and the check is still made and reported.
        convergence_tolerance: the largest RMS difference between the reported model's RK4
            and reference responses, as a fraction of its RMS residual (default 1 %).
        input_interpolation: how inputs are reconstructed between samples at the RK4 stage
            times: ``"linear"``, ``"bandlimited"`` (for inputs with content near the
            Nyquist frequency) or ``"hold"`` (for inputs applied by a DAC, each sample held
            for one period); :func:`gpjax._data.between_samples`.
        initial_conditions: ``(x0, x_dot0)`` at the first sample, or ``None`` to estimate
            them from the data (eq. 13).
        selection_alpha: level of the held-out predictive test that picks the reported
            model (:mod:`gpjax._select`): a simpler neighbour (fewer fitted constants)
            replaces the current model unless the current one predicts the held-out
            windows of the equation error (blocked cross-validation) better at this
            level. Lower keeps fewer constants. Several coordinates also test each
            term of the converged fit against 0 at this level over the number of
            features its equation chose from (:mod:`gpjax._system_search`).
        local_search: best distinct structures per generation whose one-term extensions
            (a power of x or x', a constant, an input) are built as trees and compete for
            the next generation; 0 gives the paper's pure GP. In tree mode an added state
            term starts from a value drawn from the interval constants (Rnd[real] if none),
            and each named constant is also tried as the structure's inertia coefficient.
        local_steps: several coordinates: most one-term descent steps from each of the
            ``local_search`` best systems per generation (:mod:`gpjax._system_search`).
        p_swap: several coordinates: probability that a crossover swaps a whole equation
            between the parents instead of two subtrees of one equation.
        input_forcing: how a measured input may enter the forcing side: ``"linear"`` (the
            default) as g·u only — a measured force or torque acts linearly, and a
            nonlinear function of an input measured inside a feedback loop (tanh u,
            exp u) can stand in for friction or stiffness, since such an input follows the
            state; ``"any"``: any function of time and inputs, the paper's rule (eq. 3's
            F_k(t)). Constants and functions of time alone are allowed either way.
        third_law: several coordinates: each coupling force (a power of x_i − x_j or
            x_i' − x_j') acts on both of its coordinates with opposite signs, its constants
            shared (:mod:`gpjax._system_couplings`); no effect on one coordinate.
    """

    population: int = 500
    generations: int = 10
    epsilon: float = 0.0
    p_crossover: float = 0.63
    p_mutation: float = 0.27
    p_perturbation: float = 0.09
    p_reproduction: float = 0.01
    functions: tuple[str, ...] = ("add", "sub", "mul")
    variables: tuple[str, ...] = ("x", "x_dot", "x_ddot", "u")
    named_constants: dict[str, float] = dataclasses.field(default_factory=dict)
    interval_constants: dict[str, tuple[tuple[float, float], ...]] = dataclasses.field(
        default_factory=dict
    )
    real_interval: tuple[float, float] = (-10.0, 10.0)
    int_interval: tuple[int, int] = (1, 5)
    max_depth: int = 6
    max_size: int = 40
    init_depth: tuple[int, int] = (2, 4)
    max_degree: int = 4
    tournament_size: int | None = None
    w_time: float = 1.0
    w_freq: float = 1.0
    n_bins: int | None = None
    coefficients: str = "least_squares"
    refine_top: int = 5
    refine_iterations: int = 10
    substeps: int | str = "auto"
    convergence_tolerance: float = 0.01
    input_interpolation: str = "linear"
    initial_conditions: tuple[float, float] | None = None
    selection_alpha: float = 0.05
    local_search: int = 3
    local_steps: int = 4
    p_swap: float = 0.3
    third_law: bool = False
    input_forcing: str = "linear"

    def __post_init__(self) -> None:
        _validate(self)

    # --- construction -------------------------------------------------------------------
    @classmethod
    def from_dict(cls, values: dict[str, Any], *, source: str = "config") -> "GPConfig":
        """Build from a plain mapping; unknown keys and wrong types raise ConfigError."""
        known = {f.name: f for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - set(known))
        if unknown:
            raise ConfigError(
                f"{source}: unknown key {unknown[0]!r}; valid keys are: {', '.join(known)}"
            )
        converted = {name: _convert(name, value, source) for name, value in values.items()}
        return cls(**converted)

    @classmethod
    def from_toml(cls, path: str | Path) -> "GPConfig":
        """Read a TOML file of top-level keys (the field names above)."""
        text = read_user_file(path, "config file", ConfigError)
        try:
            values = tomllib.loads(text)
        except tomllib.TOMLDecodeError as err:
            raise ConfigError(f"config file {path} is not valid TOML ({err}); fix the syntax") from None
        return cls.from_dict(values, source=str(path))

    @classmethod
    def paper(cls, **overrides: Any) -> "GPConfig":
        """The paper's settings (eqs. 10–12, §5) for the gear example; φ is in degrees."""
        values: dict[str, Any] = dict(
            functions=("add", "sub", "mul"),
            epsilon=0.01,
            variables=("x", "x_ddot", "u", "t"),
            input_forcing="any",
            named_constants={"J": 7.918e-5, "N1": 19.0, "r1": 0.038},
            interval_constants={
                "k1": ((0.1, 20.0), (800.0, 1000.0)),
                "k2": ((0.1, 20.0), (800.0, 1000.0)),
            },
        )
        values.update(overrides)
        return cls(**values)

    @property
    def tournament(self) -> int:
        """The tournament size in use."""
        if self.tournament_size is not None:
            return self.tournament_size
        return min(7, self.population)

    def replace(self, **changes: Any) -> "GPConfig":
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON/TOML-ready values (tuples become lists; ``None`` keys are dropped)."""
        out = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if value is None:
                continue
            out[f.name] = _plain(value)
        return out


def _plain(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    return value


_INT_FIELDS = {"population", "generations", "max_depth", "max_size", "max_degree",
               "tournament_size", "n_bins", "refine_top", "refine_iterations", "local_search",
               "local_steps"}
_FLOAT_FIELDS = {"epsilon", "p_crossover", "p_mutation", "p_perturbation", "p_reproduction",
                 "w_time", "w_freq", "selection_alpha", "convergence_tolerance",
                 "p_swap"}


def _number(name: str, value: Any, source: str, *, integer: bool) -> float | int:
    ok = isinstance(value, int) if integer else isinstance(value, (int, float))
    if isinstance(value, bool) or not ok:
        kind = "an integer" if integer else "a number"
        raise ConfigError(f"{source}: {name} must be {kind}, got {value!r}")
    return int(value) if integer else float(value)


def _convert(name: str, value: Any, source: str) -> Any:
    """Check the type of one raw value and convert lists to the field's tuple form."""
    if name in _INT_FIELDS:
        if name in ("n_bins", "tournament_size") and value is None:
            return None
        return _number(name, value, source, integer=True)
    if name in _FLOAT_FIELDS:
        return _number(name, value, source, integer=False)
    if name in ("functions", "variables"):
        if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
            raise ConfigError(f"{source}: {name} must be a list of names, got {value!r}")
        return tuple(value)
    if name == "substeps":
        if value == "auto":
            return value
        return _number(name, value, source, integer=True)
    if name == "third_law":
        if not isinstance(value, bool):
            raise ConfigError(f"{source}: third_law must be true or false, got {value!r}")
        return value
    if name in ("coefficients", "input_interpolation", "input_forcing"):
        if not isinstance(value, str):
            raise ConfigError(f"{source}: {name} must be a string, got {value!r}")
        return value
    if name == "named_constants":
        if not isinstance(value, dict):
            raise ConfigError(f"{source}: named_constants must be a table of name = number")
        return {k: _number(f"named_constants.{k}", v, source, integer=False) for k, v in value.items()}
    if name == "interval_constants":
        if not isinstance(value, dict):
            raise ConfigError(f"{source}: interval_constants must be a table of name = [[lo, hi], ...]")
        return {k: _intervals(f"interval_constants.{k}", v, source) for k, v in value.items()}
    if name in ("real_interval", "int_interval", "init_depth", "initial_conditions"):
        if name == "initial_conditions" and value is None:
            return None
        integer = name in ("int_interval", "init_depth")
        if not isinstance(value, (list, tuple)) or len(value) != 2:
            raise ConfigError(f"{source}: {name} must be a pair [a, b], got {value!r}")
        return tuple(_number(name, v, source, integer=integer) for v in value)
    raise AssertionError(f"unhandled config field {name}")  # every field is listed above


def _intervals(name: str, value: Any, source: str) -> tuple[tuple[float, float], ...]:
    if not isinstance(value, (list, tuple)) or not value:
        raise ConfigError(f"{source}: {name} must be a non-empty list of [lo, hi] pairs")
    pairs = value if isinstance(value[0], (list, tuple)) else [value]
    out = []
    for pair in pairs:
        if not isinstance(pair, (list, tuple)) or len(pair) != 2:
            raise ConfigError(f"{source}: {name} must be a list of [lo, hi] pairs, got {value!r}")
        out.append(tuple(_number(name, v, source, integer=False) for v in pair))
    return tuple(out)


def _validate(c: GPConfig) -> None:
    def need(condition: bool, message: str) -> None:
        if not condition:
            raise ConfigError(message)

    for name in _INT_FIELDS:
        value = getattr(c, name)
        if value is not None and (isinstance(value, bool) or not isinstance(value, int)):
            raise ConfigError(f"{name} must be an integer, got {value!r}")
    for name in _FLOAT_FIELDS:
        value = getattr(c, name)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ConfigError(f"{name} must be a finite number, got {value!r}")
    need(c.population >= 4, f"population must be at least 4, got {c.population}")
    need(c.generations >= 1, f"generations must be at least 1, got {c.generations}")
    need(c.epsilon >= 0, f"epsilon must be >= 0, got {c.epsilon}")
    probs = (c.p_crossover, c.p_mutation, c.p_perturbation, c.p_reproduction)
    need(all(p >= 0 for p in probs), f"operator probabilities must be >= 0, got {probs}")
    need(abs(sum(probs) - 1.0) < 1e-9,
         f"operator probabilities must sum to 1, got {sum(probs):.6g}; adjust p_crossover, "
         "p_mutation, p_perturbation, p_reproduction")
    bad = [f for f in c.functions if f not in FUNCTIONS]
    need(not bad, f"unknown function {bad[0]!r} in functions; choose from {', '.join(FUNCTIONS)}"
         if bad else "")
    need(any(f in c.functions for f in ("add", "sub")),
         "functions must contain add or sub, or no tree can hold more than one term")
    bad = [v for v in c.variables if v not in VARIABLES]
    need(not bad, f"unknown variable {bad[0]!r} in variables; choose from {', '.join(VARIABLES)}"
         if bad else "")
    need("x_ddot" in c.variables, "variables must contain x_ddot: eq. 3 needs an acceleration term")
    need("x" in c.variables or "x_dot" in c.variables,
         "variables must contain x or x_dot, or the model cannot depend on the response")
    reserved = set(VARIABLES)
    for name, value in c.named_constants.items():
        need(name.isidentifier() and name not in reserved,
             f"named constant {name!r} must be an identifier other than {', '.join(VARIABLES)}")
        need(math.isfinite(value), f"named constant {name} must be finite, got {value}")
    for name, pairs in c.interval_constants.items():
        need(name.isidentifier() and name not in reserved and name not in c.named_constants,
             f"interval constant {name!r} must be a new identifier")
        for lo, hi in pairs:
            need(math.isfinite(lo) and math.isfinite(hi) and lo < hi,
                 f"interval of {name} must satisfy lo < hi, got [{lo}, {hi}]")
    lo, hi = c.real_interval
    need(math.isfinite(lo) and math.isfinite(hi) and lo < hi,
         f"real_interval must be finite with lo < hi, got [{lo}, {hi}]")
    lo, hi = c.int_interval
    need(lo <= hi, f"int_interval must satisfy lo <= hi, got [{lo}, {hi}]")
    need(c.max_depth >= 1, f"max_depth must be at least 1, got {c.max_depth}")
    need(c.max_size >= 3, f"max_size must be at least 3, got {c.max_size}")
    dmin, dmax = c.init_depth
    need(1 <= dmin <= dmax <= c.max_depth,
         f"init_depth must satisfy 1 <= min <= max <= max_depth, got {c.init_depth}")
    need(c.max_degree >= 1, f"max_degree must be at least 1, got {c.max_degree}")
    need(c.tournament_size is None or 2 <= c.tournament_size <= c.population,
         f"tournament_size must be between 2 and population ({c.population}), got "
         f"{c.tournament_size}")
    need(c.w_time >= 0 and c.w_freq >= 0 and c.w_time + c.w_freq > 0,
         f"weights must be >= 0 and not both 0, got w_time={c.w_time}, w_freq={c.w_freq}")
    need(c.n_bins is None or c.n_bins >= 1, f"n_bins must be at least 1, got {c.n_bins}")
    need(c.coefficients in COEFFICIENT_MODES,
         f"coefficients must be one of {', '.join(COEFFICIENT_MODES)}, got {c.coefficients!r}")
    need(c.refine_top >= 0, f"refine_top must be >= 0, got {c.refine_top}")
    need(c.refine_iterations >= 1, f"refine_iterations must be at least 1, got {c.refine_iterations}")
    need(c.substeps == "auto" or (isinstance(c.substeps, int) and not isinstance(c.substeps, bool)
                                  and 1 <= c.substeps <= MAX_SUBSTEPS),
         f"substeps must be \"auto\" or an integer between 1 and {MAX_SUBSTEPS}, got "
         f"{c.substeps!r}")
    need(0 < c.convergence_tolerance < 1,
         f"convergence_tolerance must be in (0, 1), got {c.convergence_tolerance}")
    need(c.input_interpolation in INPUT_INTERPOLATIONS,
         f"input_interpolation must be one of {', '.join(INPUT_INTERPOLATIONS)}, got "
         f"{c.input_interpolation!r}")
    if c.initial_conditions is not None:
        need(all(math.isfinite(v) for v in c.initial_conditions),
             f"initial_conditions must be finite, got {c.initial_conditions}")
    need(c.local_search >= 0, f"local_search must be >= 0, got {c.local_search}")
    need(c.local_steps >= 0, f"local_steps must be >= 0, got {c.local_steps}")
    need(0 <= c.p_swap <= 1, f"p_swap must be in [0, 1], got {c.p_swap}")
    need(c.input_forcing in INPUT_FORCINGS,
         f"input_forcing must be one of {', '.join(INPUT_FORCINGS)}, got {c.input_forcing!r}")
    need(isinstance(c.third_law, bool), f"third_law must be true or false, got {c.third_law!r}")
    need(0 < c.selection_alpha < 1,
         f"selection_alpha must be in (0, 1), got {c.selection_alpha}")


def check_system_config(config: GPConfig) -> None:
    """Raise :class:`gpjax.ConfigError` if ``config``, for several responses, changes a
    :data:`ONE_COORDINATE` field, names a function outside
    :data:`gpjax._system_bank.SYSTEM_FUNCTIONS`, or has bank functions with ``third_law``."""
    from ._system_bank import SYSTEM_FUNCTIONS, kinds_for

    defaults = GPConfig()
    changed = [k for k in ONE_COORDINATE if getattr(config, k) != getattr(defaults, k)]
    if changed:
        raise ConfigError(f"{changed[0]} is not supported with several responses yet; leave "
                          "it at its default")
    other = [f for f in config.functions if f not in SYSTEM_FUNCTIONS]
    if other:
        raise ConfigError(f"function {other[0]!r} is not supported with several responses; "
                          f"choose from {', '.join(SYSTEM_FUNCTIONS)}")
    if config.third_law and kinds_for(config.functions):
        raise ConfigError("third_law takes polynomial couplings only; drop it or the "
                          "functions beyond add, sub, mul")
