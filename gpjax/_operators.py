"""Random trees and the paper's four genetic operators (§2): crossover, mutation,
perturbation and reproduction. Every operator returns a tree within the size and depth
limits: an offspring that would exceed them is replaced by a copy of its (first) parent,
as in Koza (1992).

All randomness comes from an explicit ``numpy.random.Generator``.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ._config import GPConfig
from ._trees import Tree, arity, depth, is_function, nodes, replace, size, subtree

#: Probability that crossover and mutation pick an internal node rather than a leaf (Koza).
INTERNAL_NODE_BIAS = 0.9
#: Largest depth of a subtree grown by mutation.
MUTATION_DEPTH = 3
#: Relative standard deviation of the perturbation of a numeric leaf.
PERTURBATION_SCALE = 0.1


@dataclasses.dataclass(frozen=True)
class Grammar:
    """The function and terminal sets of one run (eqs. 1–2, 10–11) with the tree limits."""

    functions: tuple[str, ...]
    variables: tuple[Tree, ...]
    named_constants: tuple[str, ...]
    interval_constants: dict[str, tuple[tuple[float, float], ...]]
    real_interval: tuple[float, float]
    int_interval: tuple[int, int]
    max_depth: int
    max_size: int

    @classmethod
    def from_config(cls, config: GPConfig, n_inputs: int) -> "Grammar":
        variables: list[Tree] = []
        for role in config.variables:
            if role == "u":
                variables.extend(("u", k) for k in range(n_inputs))
            else:
                variables.append((role,))
        return cls(
            functions=config.functions, variables=tuple(variables),
            named_constants=tuple(config.named_constants),
            interval_constants=dict(config.interval_constants),
            real_interval=config.real_interval, int_interval=config.int_interval,
            max_depth=config.max_depth, max_size=config.max_size)

    def terminal_kinds(self) -> list[tuple]:
        """One entry per terminal of eq. 11, each drawn with equal probability."""
        kinds: list[tuple] = [("var", v) for v in self.variables]
        kinds += [("c", name) for name in self.named_constants]
        kinds += [("k", name) for name in self.interval_constants]
        kinds += [("real",), ("int",)]
        return kinds

    def random_terminal(self, rng: np.random.Generator) -> Tree:
        kinds = self.terminal_kinds()
        kind = kinds[rng.integers(len(kinds))]
        if kind[0] == "var":
            return kind[1]
        if kind[0] == "c":
            return ("c", kind[1])
        if kind[0] == "k":
            intervals = self.interval_constants[kind[1]]
            lo, hi = intervals[rng.integers(len(intervals))]
            return ("k", kind[1], float(rng.uniform(lo, hi)))
        if kind[0] == "real":
            return ("n", float(rng.uniform(*self.real_interval)))
        lo, hi = self.int_interval
        return ("n", int(rng.integers(lo, hi + 1)))

    def random_tree(self, rng: np.random.Generator, max_depth: int, *, full: bool) -> Tree:
        """A random tree no deeper than ``max_depth`` (Koza's "full" or "grow" method)."""
        n_terminals = len(self.terminal_kinds())
        p_function = len(self.functions) / (len(self.functions) + n_terminals)
        if max_depth == 0 or (not full and rng.random() >= p_function):
            return self.random_terminal(rng)
        name = self.functions[rng.integers(len(self.functions))]
        return (name, *(self.random_tree(rng, max_depth - 1, full=full)
                        for _ in range(arity(name))))

    def within_limits(self, tree: Tree) -> bool:
        return depth(tree) <= self.max_depth and size(tree) <= self.max_size


def initial_population(grammar: Grammar, rng: np.random.Generator, count: int,
                       depth_range: tuple[int, int]) -> list[Tree]:
    """Ramped half-and-half: depths spread over ``depth_range``, half full, half grown.

    Duplicates are redrawn so the first generation is diverse; every tree is within the
    size and depth limits.
    """
    low, high = depth_range
    depths = list(range(low, high + 1))
    population: list[Tree] = []
    seen: set[Tree] = set()
    for i in range(count):
        target = depths[i % len(depths)]
        tree = None
        for attempt in range(40):
            # After 20 misses (duplicates or over the size limit) grow shallower trees.
            candidate = grammar.random_tree(rng, max(1, target - attempt // 20),
                                            full=bool(i % 2) and attempt < 20)
            if grammar.within_limits(candidate):
                tree = candidate
                if candidate not in seen:
                    break
        if tree is None:  # size limit below even a depth-1 tree: a lone terminal
            tree = grammar.random_terminal(rng)
        seen.add(tree)
        population.append(tree)
    return population


def _pick_node(tree: Tree, rng: np.random.Generator) -> tuple[int, ...]:
    all_nodes = list(nodes(tree))
    internal = [p for p, n in all_nodes if is_function(n)]
    leaves = [p for p, n in all_nodes if not is_function(n)]
    pool = internal if internal and rng.random() < INTERNAL_NODE_BIAS else leaves
    return pool[rng.integers(len(pool))]


def crossover(a: Tree, b: Tree, grammar: Grammar, rng: np.random.Generator) -> Tree:
    """Replace a random subtree of ``a`` with a random subtree of ``b`` (Figs. 1–4)."""
    child = replace(a, _pick_node(a, rng), subtree(b, _pick_node(b, rng)))
    return child if grammar.within_limits(child) else a


def mutation(a: Tree, grammar: Grammar, rng: np.random.Generator) -> Tree:
    """Replace a random subtree of ``a`` with a newly grown one (Fig. 5)."""
    new = grammar.random_tree(rng, int(rng.integers(0, MUTATION_DEPTH + 1)), full=False)
    child = replace(a, _pick_node(a, rng), new)
    return child if grammar.within_limits(child) else a


def perturbation(a: Tree, grammar: Grammar, rng: np.random.Generator) -> Tree:
    """Give one random leaf a new value, or a new terminal (Fig. 6)."""
    leaves = [p for p, n in nodes(a) if not is_function(n)]
    path = leaves[rng.integers(len(leaves))]
    leaf = subtree(a, path)
    if leaf[0] in ("n", "k") and rng.random() < 0.5:
        value = leaf[-1] * (1.0 + PERTURBATION_SCALE * rng.standard_normal())
        if leaf[0] == "n" and isinstance(leaf[1], int):
            value = int(round(value))
        new = leaf[:-1] + (value,)
    else:
        new = grammar.random_terminal(rng)
    return replace(a, path, new)


def reproduction(a: Tree) -> Tree:
    """A copy of ``a``."""
    return a
