import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from gpjax import GPConfig, Symbols, check_structure
from gpjax.engine import check_tree, tree_to_sympy
from gpjax._operators import (Grammar, crossover, initial_population, mutation, perturbation)
from gpjax._trees import depth, from_json, is_function, nodes, size, to_json

CONFIG = GPConfig.paper(max_depth=5, max_size=25)
GRAMMAR = Grammar.from_config(CONFIG, n_inputs=1)
S = Symbols("phi", "t", ("T",))


def _well_formed(tree) -> bool:
    for _, node in nodes(tree):
        if is_function(node):
            if node[0] not in CONFIG.functions or len(node) != 3:
                return False
        elif node[0] not in ("x", "x_dot", "x_ddot", "t", "u", "c", "k", "n"):
            return False
    return True


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_operators_keep_trees_valid_and_within_limits(seed):
    rng = np.random.default_rng(seed)
    population = initial_population(GRAMMAR, rng, 12, CONFIG.init_depth)
    for _ in range(30):
        a, b = population[rng.integers(12)], population[rng.integers(12)]
        for child in (crossover(a, b, GRAMMAR, rng), mutation(a, GRAMMAR, rng),
                      perturbation(a, GRAMMAR, rng)):
            assert _well_formed(child)
            assert depth(child) <= CONFIG.max_depth and size(child) <= CONFIG.max_size
            assert from_json(to_json(child)) == child
            population[rng.integers(12)] = child


def test_initial_population_is_diverse_and_limited():
    rng = np.random.default_rng(1)
    population = initial_population(GRAMMAR, rng, 200, CONFIG.init_depth)
    assert len(set(population)) >= 190
    assert all(GRAMMAR.within_limits(t) for t in population)


def test_interval_constants_are_drawn_from_their_intervals():
    rng = np.random.default_rng(2)
    values = [GRAMMAR.random_terminal(rng) for _ in range(3000)]
    drawn = [v[2] for v in values if v[0] == "k"]
    assert drawn and all(0.1 <= d <= 20 or 800 <= d <= 1000 for d in drawn)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_every_accepted_tree_can_be_solved_for_the_acceleration(seed):
    rng = np.random.default_rng(seed)
    for tree in initial_population(GRAMMAR, rng, 20, (2, 4)):
        expression = tree_to_sympy(tree, S, CONFIG.named_constants)
        check = check_structure(expression, S)
        if check.valid:
            import sympy as sp
            solved = sp.solve(sp.expand(expression), S.x_ddot)
            assert len(solved) == 1
            assert S.x_ddot not in solved[0].free_symbols


@settings(max_examples=40, deadline=None)
@given(st.integers(-5, 5), st.integers(-5, 5), st.integers(1, 4))
def test_equivalent_expressions_share_one_canonical_form(a, b, power):
    import sympy as sp
    x, T = S.x, S.u[0]
    one = 2 * S.x_ddot + a * x**power + b * x - T
    two = sp.expand((S.x_ddot + x) * 2) - 2 * x + (x**power) * a + b * x - T
    c1, c2 = check_structure(one, S), check_structure(two, S)
    assert c1.valid and c2.valid and c1.canonical == c2.canonical


@pytest.mark.parametrize("functions", [("add", "sub", "mul", "div"),
                                       ("add", "sub", "mul", "div", "sin", "abs", "sign",
                                        "tanh", "exp")])
@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_tree_check_agrees_with_the_expression_check(functions, seed):
    """check_tree (ring arithmetic term by term; a subtree with a division or a unary
    function expanded once, not again as a whole) decides like check_structure on the
    expression, with and without division in the tree and with the wide function set."""
    bank = "sin" in functions
    config = GPConfig.paper(max_depth=5, max_size=25, functions=functions)
    grammar = Grammar.from_config(config, n_inputs=1)
    rng = np.random.default_rng(seed)
    for tree in initial_population(grammar, rng, 20, (2, 4)):
        fast = check_tree(tree, S, config.named_constants, max_degree=3, bank=bank)
        slow = check_structure(tree_to_sympy(tree, S, config.named_constants), S, max_degree=3,
                               bank=bank)
        assert fast.valid == slow.valid, (tree, fast.reason, slow.reason)
        if fast.valid:
            for (f1, c1), (f2, c2) in zip(fast.canonical.state + fast.canonical.forcing,
                                          slow.canonical.state + slow.canonical.forcing):
                assert f1 == f2 and np.isclose(c1, c2, rtol=1e-12)
            assert np.isclose(fast.canonical.mass, slow.canonical.mass, rtol=1e-12)


def test_a_constant_beyond_floating_range_makes_a_tree_invalid_not_a_crash():
    """exp(exp(exp(977.6))) (a tree the wide set's initial population wrote, seed 288 of
    the test above) overflows mpmath when sympy evaluates it: the check reports the tree
    as not finite instead of raising."""
    tree = ("add", ("mul", ("k", "k1", 2.0), ("x_ddot",)),
            ("mul", ("exp", ("exp", ("exp", ("k", "k2", 977.637010629853)))), ("x",)))
    check = check_tree(tree, S, {}, max_degree=3, bank=True)
    assert not check.valid and "not finite" in check.reason


def test_a_periodic_function_of_a_constant_beyond_float64_is_invalid_at_once():
    """sin(exp(|exp(N1)|)) with N1 = 19 (the wide set's initial population wrote it, seed 160
    of the test above): exp(exp(19)) ≈ 10^(7.7e7) is beyond float64, and sympy's sin of it
    computes π to ~10^8 digits (the fast tier hung there). The check rejects it instead."""
    import time

    tree = ("add", ("mul", ("k", "k1", 2.0), ("x_ddot",)),
            ("mul", ("sin", ("exp", ("abs", ("exp", ("c", "N1"))))), ("x",)))
    started = time.perf_counter()
    for check in (check_tree(tree, S, {"N1": 19.0}, max_degree=3, bank=True),
                  check_structure(tree_to_sympy(tree, S, {"N1": 19.0}), S, max_degree=3,
                                  bank=True)):
        assert not check.valid and "not finite" in check.reason
    assert time.perf_counter() - started < 10


def test_an_exponential_of_a_constant_beyond_float64_is_invalid_at_once():
    """exp(exp(exp(N1))) with N1 = 7 (exp(exp(7)) ≈ 10^476 overflows float64): sympy
    evaluated the outer exp by computing ln 2 to as many digits (a fresh clone's fast tier
    hung there for 18 minutes in the hypothesis test above). The check rejects it instead."""
    import time

    tree = ("add", ("mul", ("k", "k1", 2.0), ("x_ddot",)),
            ("mul", ("exp", ("exp", ("exp", ("c", "N1")))), ("x",)))
    started = time.perf_counter()
    check = check_tree(tree, S, {"N1": 7.0}, max_degree=3, bank=True)
    assert not check.valid and "not finite" in check.reason
    assert time.perf_counter() - started < 10
