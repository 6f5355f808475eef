"""The genetic-programming driver (paper §2, §5), run on the CPU, for any number of
coordinates: :class:`GenerationLoop` runs the generations, stop rules, history,
checkpoints and island migrants of one coordinate's :class:`Evolution` (below) and of a
system's :class:`gpjax._system_search.SystemEvolution` (one tree per equation).

One coordinate, each generation: offspring are made by crossover / mutation /
perturbation / reproduction (probabilities from the config) from parents chosen by
tournament; offspring are scored (new structures only, in one batch); the best distinct
structures are refined and extended by one term (memetic step); the next population is
the best ``population`` of parents ∪ offspring ∪ extensions (elitist replacement, repeats
of a feature set ranked after all distinct ones). In tree mode (``coefficients="tree"``)
every new candidate is refined from its tree's constants before it competes (see
:meth:`Evolution._score`). The run stops after
``generations`` generations or when the best objective f <= epsilon × f_0 (eq. 12,
:func:`gpjax._objective.stop_objective`).

Selection is a tournament: it depends only on the ranking, so it is unaffected by the
objective's scale (the paper's f spans the data's units, and invalid candidates carry a
penalty of 1e12), and it needs no fitness normalisation.

The whole state between generations (population, RNG state, caches, history) is a plain
JSON-ready dict, so a run can be checkpointed after every generation and resumed exactly.
"""

from __future__ import annotations

import dataclasses
import functools
import time

import numpy as np
import sympy as sp

from . import _progress, _trees
from ._canonical import feature_name
from ._config import GPConfig
from ._evaluator import OK
from ._expressions import parse_expression
from ._fitness import Fitness, Record, feature_set_key
from ._objective import stop_objective
from ._operators import Grammar, crossover, initial_population, mutation, perturbation


@dataclasses.dataclass
class GenerationStats:
    """One row of ``history.csv``."""

    generation: int
    best_objective: float
    median_objective: float | None  # of the valid candidates; None when there are none
    valid_fraction: float
    unique_structures: int
    seconds: float
    best_key: str


@dataclasses.dataclass
class RunState:
    """Everything needed to continue a run after a generation (written as JSON by
    :meth:`GenerationLoop.state_json`)."""

    generation: int
    population: list[tuple]
    rng_state: dict
    history: list[GenerationStats]
    done: bool = False


@dataclasses.dataclass(frozen=True)
class Standing:
    """Where a population's individuals stand: ``objectives`` (P,); ``usable`` (P,): a valid
    structure whose evaluation succeeded; ``keys``: each individual's structure (``None``
    where it is not a valid one); ``order``: the individuals best first; ``best_key``: the
    best one's structure as text."""

    objectives: np.ndarray
    usable: np.ndarray
    keys: list
    order: list[int]
    best_key: str

    @functools.cached_property
    def ranks(self) -> np.ndarray:
        """Each individual's place in :attr:`order` (0: the best; computed once, read by
        every tournament of a generation)."""
        ranks = np.empty(len(self.order), dtype=np.int64)
        ranks[self.order] = np.arange(len(self.order))
        return ranks


def _rank_key(record: Record, tree: tuple) -> tuple:
    return (record.objective, record.n_terms if record.valid else 10**6, _trees.size(tree))


def tournament(values: np.ndarray, rng: np.random.Generator, size: int) -> int:
    """The index of the least of ``size`` entries of ``values`` drawn with replacement
    (at most as many as there are)."""
    entrants = rng.integers(len(values), size=min(size, len(values)))
    return int(entrants[np.argmin(values[entrants])])


def distinct_first(order, keys: list, count: int) -> list[int]:
    """The first ``count`` of the indices ``order`` with each repeat of a key put after
    every distinct one (elitist replacement that keeps the population diverse)."""
    seen: set = set()
    first, repeats = [], []
    for i in order:
        (repeats if keys[i] in seen else first).append(i)
        seen.add(keys[i])
    return (first + repeats)[:count]


def evolution_for(measurement, config: GPConfig):
    """The GP engine of ``measurement``: :class:`Evolution` for one coordinate, else
    :class:`gpjax._system_search.SystemEvolution`."""
    if measurement.n_coordinates > 1:
        from ._system_search import SystemEvolution

        return SystemEvolution(measurement, config)
    return Evolution(Fitness(measurement, config), config)


class GenerationLoop:
    """The GP driver for any number of coordinates: generations from a seed, the stop
    rules, the history, checkpoints and island migrants. An individual is one tree
    (:class:`Evolution`, one coordinate) or one tree per equation
    (:class:`gpjax._system_search.SystemEvolution`); a subclass gives how individuals are
    made, scored, improved and kept (``_first_population``, ``_child``,
    ``_next_population``, ``_standing``) and how its caches are written and read."""

    config: GPConfig
    stop_objective: float

    # --- the generations ----------------------------------------------------------------
    def start(self, seed: int) -> RunState:
        """Generation 0 from ``seed``, scored."""
        rng = np.random.default_rng(seed)
        _progress.stage(self._first_message())
        began = time.perf_counter()
        population = self._first_population(rng)
        return self._closed(RunState(generation=0, population=population, rng_state={},
                                     history=[]), rng, began)

    def step(self, state: RunState) -> RunState:
        """One generation: offspring of parents chosen by tournament, then the subclass's
        scoring, local moves, refinement and elitist replacement."""
        began = time.perf_counter()
        rng = np.random.default_rng()
        rng.bit_generator.state = state.rng_state
        parents = state.population
        standing = self._standing(parents)
        offspring = [self._child(parents, standing, rng) for _ in range(self.config.population)]
        population = self._next_population(parents, offspring, standing, rng)
        return self._closed(RunState(generation=state.generation + 1, population=population,
                                     rng_state={}, history=state.history), rng, began)

    def _closed(self, state: RunState, rng: np.random.Generator, began: float) -> RunState:
        """``state`` with the generator's state, its history row and its stop flag."""
        standing = self._standing(state.population)
        objectives, usable = standing.objectives, standing.usable
        best = standing.order[0]
        state.rng_state = rng.bit_generator.state
        state.history.append(GenerationStats(
            generation=state.generation, best_objective=float(objectives[best]),
            median_objective=float(np.median(objectives[usable])) if usable.any() else None,
            valid_fraction=float(usable.mean()),
            unique_structures=len({k for k in standing.keys if k is not None}),
            seconds=time.perf_counter() - began, best_key=standing.best_key))
        state.done = bool(state.generation >= self.config.generations
                          or objectives[best] <= self.stop_objective)
        return state

    # --- checkpoints and islands --------------------------------------------------------
    def state_json(self, state: RunState) -> dict:
        """``state`` as plain JSON, with the scored records a resumed run cannot recompute
        and the evaluator's forcing columns (:meth:`load_state` reads it)."""
        return {"generation": state.generation,
                "population": [self._individual_json(t) for t in state.population],
                "rng_state": state.rng_state,
                "history": [dataclasses.asdict(h) for h in state.history],
                "done": state.done, "records": self._records_json(),
                "forcing_features": self.forcing_columns()}

    def load_state(self, data: dict) -> RunState:
        """Inverse of :meth:`state_json` (the records go into the caches)."""
        names = self._variable_names()
        for text in data["forcing_features"]:
            self._evaluator.forcing_index(parse_expression(text, names))
        self._load_records(data["records"], names)
        return RunState(generation=data["generation"],
                        population=[self._individual(t) for t in data["population"]],
                        rng_state=data["rng_state"],
                        history=[GenerationStats(**h) for h in data["history"]],
                        done=data["done"])

    def emigrants(self, state: RunState, count: int) -> list[dict]:
        """The population's ``count`` best usable distinct structures as ``{"tree",
        "record"}``."""
        standing, out, seen = self._standing(state.population), [], set()
        for i in standing.order:
            if len(out) == count:
                break
            if standing.usable[i] and standing.keys[i] not in seen:
                seen.add(standing.keys[i])
                out.append({"tree": self._individual_json(state.population[i]),
                            "record": self._record_json(state.population[i])})
        return out

    def forcing_columns(self) -> list[str]:
        """The evaluator's forcing columns, as text."""
        return [feature_name(f) for f in self._evaluator.forcing_features]


class Evolution(GenerationLoop):
    """GP on one coordinate: an individual is one tree; ``fitness`` holds the caches."""

    def __init__(self, fitness: Fitness, config: GPConfig):
        self.fitness = fitness
        self.config = config
        self.stop_objective = stop_objective(fitness.measurement, config)
        self.grammar = Grammar.from_config(config, len(fitness.measurement.inputs))
        self.fresh_columns = self.forcing_columns()

    @property
    def _evaluator(self):
        return self.fitness.evaluator

    def _variable_names(self) -> set[str]:
        return self.fitness.symbols.names()

    @staticmethod
    def _individual_json(tree: tuple):
        return _trees.to_json(tree)

    @staticmethod
    def _individual(item) -> tuple:
        return _trees.from_json(item)

    def _records_json(self) -> list[dict]:
        return [r.to_json() for r in self.fitness.records.values() if r.valid]

    def _load_records(self, items: list[dict], names: set[str]) -> None:
        for item in items:
            record = Record.from_json(item, names)
            self.fitness.records[record.key] = record

    def _record_json(self, tree: tuple) -> dict:
        return self.fitness.records_for([tree])[0].to_json()

    def reset(self) -> None:
        """Forget every scored record (a reused island engine)."""
        self.fitness.records.clear()

    def _standing(self, population: list[tuple]) -> Standing:
        records = self.fitness.records_for(population)
        order = sorted(range(len(population)),
                       key=lambda i: _rank_key(records[i], population[i]) + (i,))
        return Standing(objectives=np.array([r.objective for r in records]),
                        usable=np.array([r.valid and r.status == OK for r in records]),
                        keys=[r.key if r.valid else None for r in records], order=order,
                        best_key=records[order[0]].key)

    def _first_message(self) -> str:
        return (f"generation 0: compiling (or loading) the population evaluator, scoring "
                f"{self.config.population} candidates")

    def _first_population(self, rng: np.random.Generator) -> list[tuple]:
        """A ramped half-and-half population with the linear model in place of its last
        tree (least-squares coefficients; :meth:`_linear_tree`), scored, extended and
        refined."""
        population = initial_population(self.grammar, rng, self.config.population,
                                        self.config.init_depth)
        linear = self._linear_tree()
        if linear is not None and linear not in population:
            population[-1] = linear
        self._score(population)
        return self._refined(self._replace(population + self._extensions(population, rng)))

    def _next_population(self, parents, offspring, standing, rng) -> list[tuple]:
        """The offspring scored, the union's one-term extensions, the best ``population``
        of all, their best refined."""
        union = parents + offspring
        self._score(offspring)
        union += self._extensions(union, rng)
        return self._refined(self._replace(union))

    def _refined(self, population: list[tuple]) -> list[tuple]:
        """``population`` after refining its best distinct structures, ranked again."""
        self._refine_best(self.fitness.records_for(population))
        return self._replace(population)

    def _score(self, trees: list[tuple]) -> None:
        """Score new trees; in tree mode also refine every new valid candidate (Lamarckian;
        ``refine_top = 0`` turns refinement off in both modes).

        A tree's random constants almost never give the right natural frequency, and over
        the ~24 periods of the gear example a wrong one wraps the phase, so an unrefined
        oscillating model scores worse than a near-constant response and the right
        structure is lost before the best few get refined. Refining each new candidate
        from its tree's constants makes it compete with what Levenberg–Marquardt reaches
        from them: the constants (and so the intervals they are drawn from) set the start,
        and decide success. The refined constants become the record's values.
        """
        records = self.fitness.records_for(trees)
        if self.config.coefficients == "tree" and self.config.refine_top:
            self.fitness.refine(records)

    def _linear_tree(self) -> tuple | None:
        """The linear model in the run's variables, m·x'' + c·x' + k·x = Σ g·u (None if
        it exceeds the tree limits, and in tree mode, which keeps the paper's all-random
        first generation: its tree's constants, all 1, would not be the model's).

        Beyond the paper, whose first generation is all random: the linear model is the
        first-order expansion of every smooth model about equilibrium, and the foothold of
        a driven record. Without it a free oscillator x'' + k·x = 0 can be the best of
        a run and stay so: its response stays near zero, while each one-term extension
        scores worse — with the input but no damping it resonates, with damping and no
        input it decays — so the memetic step never crosses to the forced, damped models
        (physics suite, Coulomb + viscous seed 6, Duffing seed 4: the reported model had
        lost the input). The search then only has to find the nonlinearity.
        """
        if self.config.coefficients == "tree":
            return None
        symbols, roles = self.fitness.symbols, self.config.variables
        terms = [("state", self.fitness.feature_tree(z), 1.0)
                 for role, z in (("x_dot", symbols.x_dot), ("x", symbols.x)) if role in roles]
        if "u" in roles:
            terms += [("forcing", self.fitness.feature_tree(u), 1.0) for u in symbols.u]
        tree = _sum_tree(1.0, terms)
        return tree if self.grammar.within_limits(tree) else None

    def _refine_best(self, records: list[Record]) -> None:
        if self.config.refine_top:
            self.fitness.refine(_best_distinct(records, self.config.refine_top))

    def _extensions(self, trees: list[tuple], rng: np.random.Generator) -> list[tuple]:
        """Trees of the best distinct structures' one-term extensions (memetic step).

        For each of the ``local_search`` best distinct valid feature sets, every feature the
        configured variables can express and the set lacks (x^k, x'^k for k up to
        max_degree, a constant force, each input) is added; the extended structure is
        written as a compact sum-of-terms tree, kept if within the tree limits. The old
        terms keep the record's (refined) coefficients. The new term's coefficient is 1 in
        least-squares mode (the data set it). In tree mode it is drawn (see
        :meth:`_new_coefficient`), each set is also tried with each named constant as its
        inertia coefficient (the one constant no added term can change; a tree's random
        constants rarely give J·x'', and refinement cannot move an inertia by orders of
        magnitude), and each new tree is refined at once (Lamarckian: the refined constants
        become its record's), so it competes with the constants the start led
        Levenberg–Marquardt to, not with a phase-wrapped start.
        """
        if not self.config.local_search:
            return []
        best = _best_distinct(self.fitness.records_for(trees), self.config.local_search)
        candidates = [(part, feature, self.fitness.feature_tree(feature))
                      for part, features in self.fitness.basis_features().items()
                      for feature in features]
        tree_mode = self.config.coefficients == "tree"
        out = []
        for record in best:
            model = record.coefficients
            terms = [(part, self.fitness.feature_tree(feature), value)
                     for part in ("state", "forcing")
                     for feature, value in getattr(model, part).items()]
            present = {_trees.to_json(t).__repr__() for _, t, _ in terms}
            trees = []
            for part, feature, tree in candidates:
                if repr(_trees.to_json(tree)) in present:
                    continue
                value = self._new_coefficient(part, feature, rng) if tree_mode else 1.0
                trees.append(_sum_tree(model.mass, terms + [(part, tree, value)]))
            if tree_mode:
                trees += [_sum_tree(mass, terms) for mass in self.config.named_constants.values()
                          if mass != model.mass]
            out += [tree for tree in trees if self.grammar.within_limits(tree)]
        if tree_mode:
            self._score(out)
        return out

    def _new_coefficient(self, part: str, feature: sp.Expr, rng: np.random.Generator) -> float:
        """Tree mode: the start value of a term an extension adds.

        A state term (a stiffness- or damping-like coefficient) gets an interval constant
        drawn by eq. 11's rule (one configured interval constant at random, one of its
        intervals at random, a uniform value), or Rnd[real] where none is configured; the
        first input gets 1 (the canonical normaliser); any other forcing term Rnd[real].
        So the intervals set the Levenberg–Marquardt start of every added stiffness term.
        """
        inputs = self.fitness.symbols.u
        if part == "forcing" and inputs and str(feature) == str(inputs[0]):
            return 1.0
        intervals = self.config.interval_constants
        if part == "state" and intervals:
            pairs = intervals[list(intervals)[rng.integers(len(intervals))]]
            return float(rng.uniform(*pairs[rng.integers(len(pairs))]))
        return float(rng.uniform(*self.config.real_interval))

    def _child(self, parents: list[tuple], standing: Standing, rng: np.random.Generator):
        c, ranks = self.config, standing.ranks
        draw = rng.random()

        def pick() -> tuple:
            return parents[tournament(ranks, rng, c.tournament)]

        if draw < c.p_crossover:
            return crossover(pick(), pick(), self.grammar, rng)
        if draw < c.p_crossover + c.p_mutation:
            return mutation(pick(), self.grammar, rng)
        if draw < c.p_crossover + c.p_mutation + c.p_perturbation:
            return perturbation(pick(), self.grammar, rng)
        return pick()

    def _replace(self, candidates: list[tuple]) -> list[tuple]:
        """The best ``population`` candidates; repeats of a structure go after distinct ones."""
        records = self.fitness.records_for(candidates)
        order = sorted(range(len(candidates)),
                       key=lambda i: _rank_key(records[i], candidates[i]) + (i,))
        keys = [feature_set_key(r) if r.valid else repr(t) for r, t in zip(records, candidates)]
        return [candidates[i] for i in distinct_first(order, keys, self.config.population)]


def _best_distinct(records: list[Record], count: int) -> list[Record]:
    """The best usable record of each of the ``count`` best distinct feature sets, best
    first (in tree mode the best coefficient variant of each set, not the best variants)."""
    distinct: dict[str, Record] = {}
    for record in sorted((r for r in records if r.valid and r.status == OK),
                         key=lambda r: (r.objective, r.n_terms)):
        distinct.setdefault(feature_set_key(record), record)
        if len(distinct) >= count:
            break
    return list(distinct.values())


def _sum_tree(mass: float, terms: list[tuple[str, tuple, float]]) -> tuple:
    """``mass·x'' + Σ c·state − Σ g·forcing`` as a balanced tree (the form E = 0)."""
    leaves = [("mul", ("n", float(mass)), ("x_ddot",))]
    leaves += [("mul", ("n", float(value if part == "state" else -value)), feature)
               for part, feature, value in terms]
    while len(leaves) > 1:
        leaves = [("add", leaves[i], leaves[i + 1]) if i + 1 < len(leaves) else leaves[i]
                  for i in range(0, len(leaves), 2)]
    return leaves[0]
