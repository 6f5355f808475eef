"""Island settings, checked before any data is read or any engine imported: how islands
exchange structures (:class:`Migration`), one config per island (:func:`island_configs`),
their seeds (:func:`island_seeds`) and the check of a whole island request
(:func:`island_plan`). The island run itself is :mod:`gpjax._islands`.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ._cluster import check_scheduler_address
from ._config import GPConfig
from ._errors import ConfigError, UserInputError

TOPOLOGIES = ("ring", "random")


@dataclasses.dataclass(frozen=True, kw_only=True)
class Migration:
    """How islands exchange structures.

    Attributes:
        every: generations per epoch (between migrations).
        migrants: best distinct structures each island sends; they replace the receiver's
            worst.
        topology: ``"ring"`` (island i sends to i + 1) or ``"random"`` (a ring in a random
            order, drawn anew each epoch from the seed).

    Raises:
        ConfigError: a value out of range.
    """

    every: int = 2
    migrants: int = 2
    topology: str = "ring"

    def __post_init__(self):
        for name in ("every", "migrants"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int):
                raise ConfigError(f"migration {name} must be an integer, got {value!r}")
        if self.every < 1:
            raise ConfigError(f"migration every must be at least 1 generation, got {self.every}")
        if self.migrants < 0:
            raise ConfigError(f"migrants must be >= 0, got {self.migrants}")
        if self.topology not in TOPOLOGIES:
            raise ConfigError(f"topology must be one of {', '.join(TOPOLOGIES)}, got "
                              f"{self.topology!r}")


def island_configs(config: GPConfig, islands: int) -> list[GPConfig]:
    """One config per island: ``config.population`` shared out (sizes differ by at most 1).

    Raises:
        UserInputError: ``islands`` is not a positive integer, or an island would be smaller
            than the minimum population (or the tournament size).
    """
    if isinstance(islands, bool) or not isinstance(islands, (int, np.integer)) or islands < 1:
        raise UserInputError(f"islands must be a positive integer, got {islands!r}; use e.g. 2")
    sizes = [config.population // islands + (i < config.population % islands)
             for i in range(islands)]
    try:
        return [config.replace(population=size) for size in sizes]
    except ConfigError as err:
        raise UserInputError(f"population {config.population} is too small for {islands} "
                             f"islands ({err}); raise the population or use fewer islands") from None


def island_seeds(seed: int, islands: int) -> list[int]:
    """Independent seeds of the islands, from ``SeedSequence(seed).spawn(islands)``."""
    return [int(child.generate_state(1, np.uint64)[0])
            for child in np.random.SeedSequence(seed).spawn(islands)]


def island_plan(config: GPConfig, islands: int | None, *, scheduler: str | None = None,
                migration: Migration | None = None) -> tuple[list[GPConfig], Migration]:
    """The islands' configs and the migration of an island request, checked whole.

    Raises:
        UserInputError: no ``islands`` given (a scheduler or migration settings alone),
            bad island settings, migrants that would fill an island, or a malformed
            scheduler address.
    """
    if islands is None:
        raise UserInputError("a scheduler or migration settings need islands; give "
                             "islands=K (--islands K)")
    migration = migration or Migration()
    configs = island_configs(config, islands)
    if migration.migrants >= configs[-1].population:
        raise UserInputError(f"{migration.migrants} migrants would replace a whole island of "
                             f"{configs[-1].population}; send fewer (--migrants) or use "
                             "fewer islands")
    if scheduler is not None:
        check_scheduler_address(scheduler)
    return configs, migration
