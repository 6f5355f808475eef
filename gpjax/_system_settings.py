"""Settings of the search over systems: a :class:`gpjax.GPConfig` (the one source of the GP's
settings) and the few that only systems have.

A config file for a system run is the ordinary TOML config with an optional ``[system]``
table of :class:`SystemSearch`'s own fields, e.g.::

    population = 100
    generations = 3
    [system]
    third_law = true
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from pathlib import Path
from typing import Any

from ._config import GPConfig
from ._errors import ConfigError, read_user_file

#: The GP settings of a system search unless given: smaller trees and fewer refinements
#: than one coordinate's defaults, since a system has one tree per coordinate.
SYSTEM_CONFIG = GPConfig(population=200, max_degree=3, max_depth=5, max_size=30,
                         refine_top=3, local_search=2)
#: GPConfig fields the system search does not use: they must keep GPConfig's defaults
#: (a system's trees use add, sub, mul on the states and inputs; constants come from
#: least squares; its refinements take 20 steps; RK4 steps and initial states are found).
UNUSED = ("functions", "variables", "named_constants", "interval_constants", "coefficients",
          "refine_iterations", "substeps", "initial_conditions", "selection_alpha")


@dataclasses.dataclass(frozen=True, kw_only=True)
class SystemSearch:
    """Settings of :func:`gpjax.engine.search_system`.

    Attributes:
        config: the GP settings (population, generations, epsilon, operator
            probabilities, tree limits, max_degree, tournament size, refine_top,
            local_search, input_interpolation, the objective's
            weights and bins, convergence_tolerance); :data:`UNUSED` fields must keep
            their defaults.
        p_swap: probability that a crossover swaps a whole equation between the parents.
        local_steps: most one-term descent steps per local-search start.
        third_law: each coupling force acts on both of its coordinates with opposite
            signs, its constants shared (:mod:`gpjax._system_couplings`).
        selection_tolerance: the reported system is the simplest whose objective is within
            this fraction of the best (the one-coordinate GP's held-out test,
            ``GPConfig.selection_alpha``, is not yet used for systems).

    Raises:
        ConfigError: a value out of range or of the wrong type, or a :data:`UNUSED` field
            changed.
    """

    config: GPConfig = SYSTEM_CONFIG
    p_swap: float = 0.3
    local_steps: int = 4
    third_law: bool = False
    selection_tolerance: float = 0.05

    def __post_init__(self) -> None:
        if not isinstance(self.config, GPConfig):
            raise ConfigError(f"config must be a GPConfig, got {type(self.config).__name__}")
        defaults = GPConfig()
        changed = [k for k in UNUSED if getattr(self.config, k) != getattr(defaults, k)]
        if changed:
            raise ConfigError(f"{changed[0]} is not used by the search over systems; leave it "
                              "at its default")
        if isinstance(self.p_swap, bool) or not isinstance(self.p_swap, (int, float)) or not (
                math.isfinite(self.p_swap) and 0 <= self.p_swap <= 1):
            raise ConfigError(f"p_swap must be a number in [0, 1], got {self.p_swap!r}")
        if isinstance(self.local_steps, bool) or not isinstance(self.local_steps, int) or \
                self.local_steps < 0:
            raise ConfigError(f"local_steps must be a non-negative integer, got "
                              f"{self.local_steps!r}")
        if isinstance(self.selection_tolerance, bool) or not isinstance(
                self.selection_tolerance, (int, float)) or not 0 <= self.selection_tolerance < 1:
            raise ConfigError("selection_tolerance must be a number in [0, 1), got "
                              f"{self.selection_tolerance!r}")
        if not isinstance(self.third_law, bool):
            raise ConfigError(f"third_law must be true or false, got {self.third_law!r}")

    @classmethod
    def of(cls, *, config: GPConfig = SYSTEM_CONFIG, **settings: Any) -> "SystemSearch":
        """Settings from keywords: :class:`gpjax.GPConfig` fields change ``config``, the
        others are this class's own (``SystemSearch.of(population=60, third_law=True)``)."""
        own = {f.name for f in dataclasses.fields(cls)}
        changes = {k: v for k, v in settings.items() if k not in own}
        return cls(config=config.replace(**changes) if changes else config,
                   **{k: v for k, v in settings.items() if k in own})

    @classmethod
    def from_dict(cls, values: dict[str, Any], *, config: GPConfig = SYSTEM_CONFIG,
                  source: str = "config") -> "SystemSearch":
        """This class's own fields from a mapping (a config file's ``[system]`` table).

        Raises:
            ConfigError: an unknown key or a bad value.
        """
        own = sorted(f.name for f in dataclasses.fields(cls) if f.name != "config")
        if not isinstance(values, dict):
            raise ConfigError(f"{source}: [system] must be a table of {', '.join(own)}")
        unknown = sorted(set(values) - set(own))
        if unknown:
            raise ConfigError(f"{source}: unknown key {unknown[0]!r} in [system]; valid keys "
                              f"are: {', '.join(own)}")
        try:
            return cls(config=config, **values)
        except ConfigError as err:
            raise ConfigError(f"{source}: {err}") from None

    @classmethod
    def from_toml(cls, path: str | Path) -> "SystemSearch":
        """A config file: its top-level keys are :class:`gpjax.GPConfig`'s (defaults
        GPConfig's own), its ``[system]`` table this class's fields.

        Raises:
            ConfigError: unreadable or invalid file, an unknown key or a bad value.
        """
        text = read_user_file(path, "config file", ConfigError)
        try:
            values = tomllib.loads(text)
        except tomllib.TOMLDecodeError as err:
            raise ConfigError(f"config file {path} is not valid TOML ({err}); fix the "
                              "syntax") from None
        system = values.pop("system", {})
        return cls.from_dict(system, config=GPConfig.from_dict(values, source=str(path)),
                             source=str(path))
