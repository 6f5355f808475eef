"""Expression trees: immutable nested tuples, hashable so that canonical forms can be cached.

Node forms:
    ("add" | "sub" | "mul" | "div", left, right)   binary functions (div is protected)
    ("sin" | "cos" | "tanh" | "exp" | "sinh" | "cosh" | "abs" | "sign" | "sqrt" | "log",
     argument)
                                                    unary functions (sqrt, log protected)
    ("x",) ("x_dot",) ("x_ddot",) ("t",)            response, its derivatives, time
    ("u", k)                                        k-th input column
    ("s", name)                                     a system equation's named variable
                                                    (x_i, x_i', d_ij, ...: gpjax._system_grammar)
    ("c", name)                                     named constant (fixed value)
    ("k", name, value)                              interval constant with its drawn value
    ("n", value)                                    ephemeral random number
"""

from __future__ import annotations

from functools import lru_cache
from typing import Iterator

Tree = tuple

BINARY_NODES = ("add", "sub", "mul", "div")
UNARY_NODES = ("sin", "cos", "tanh", "exp", "sinh", "cosh", "abs", "sign", "sqrt", "log")
FUNCTION_NODES = BINARY_NODES + UNARY_NODES
VARIABLE_NODES = ("x", "x_dot", "x_ddot", "t")


def is_function(node: Tree) -> bool:
    return node[0] in FUNCTION_NODES


def arity(name: str) -> int:
    """Number of arguments of a function node."""
    return 1 if name in UNARY_NODES else 2


@lru_cache(maxsize=1 << 16)  # a population is ranked by size every generation
def size(tree: Tree) -> int:
    """Number of nodes."""
    if is_function(tree):
        return 1 + sum(size(child) for child in tree[1:])
    return 1


def depth(tree: Tree) -> int:
    """Depth of the deepest node; a lone terminal has depth 0."""
    if is_function(tree):
        return 1 + max(depth(child) for child in tree[1:])
    return 0


def nodes(tree: Tree, path: tuple[int, ...] = ()) -> Iterator[tuple[tuple[int, ...], Tree]]:
    """Every (path, subtree) pair in prefix order; a path lists child indices (1, 2)."""
    yield path, tree
    if is_function(tree):
        for index in range(1, len(tree)):
            yield from nodes(tree[index], path + (index,))


def subtree(tree: Tree, path: tuple[int, ...]) -> Tree:
    for i in path:
        tree = tree[i]
    return tree


def replace(tree: Tree, path: tuple[int, ...], new: Tree) -> Tree:
    """A copy of ``tree`` with the subtree at ``path`` replaced by ``new``."""
    if not path:
        return new
    head, rest = path[0], path[1:]
    children = list(tree)
    children[head] = replace(tree[head], rest, new)
    return tuple(children)


def to_json(tree: Tree) -> list:
    """Nested lists (JSON-ready); the inverse of :func:`from_json`."""
    if is_function(tree):
        return [tree[0], *map(to_json, tree[1:])]
    return list(tree)


def from_json(data: list) -> Tree:
    """Rebuild a tree from :func:`to_json` output, checking every node's form."""
    if not isinstance(data, list) or not data or not isinstance(data[0], str):
        raise ValueError(f"malformed tree node {data!r}")
    head = data[0]
    if head in FUNCTION_NODES and len(data) == 1 + arity(head):
        return (head, *map(from_json, data[1:]))
    if head in VARIABLE_NODES and len(data) == 1:
        return (head,)
    if head == "u" and len(data) == 2 and isinstance(data[1], int):
        return ("u", data[1])
    if head in ("c", "s") and len(data) == 2 and isinstance(data[1], str):
        return (head, data[1])
    if head == "k" and len(data) == 3 and isinstance(data[1], str) and _is_real(data[2]):
        return ("k", data[1], float(data[2]))
    if head == "n" and len(data) == 2 and _is_real(data[1]):
        return ("n", data[1])
    raise ValueError(f"malformed tree node {data!r}")


def _is_real(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def to_text(tree: Tree, names: dict[str, str] | None = None) -> str:
    """Prefix notation like the paper's figures, e.g. ``plus(times(J, x_ddot), x)``."""
    names = names or {}
    head = tree[0]
    if is_function(tree):
        return f"{head}({', '.join(to_text(child, names) for child in tree[1:])})"
    if head == "u":
        return names.get(f"u{tree[1]}", f"u{tree[1]}")
    if head in ("c", "k"):
        return tree[1]
    if head == "n":
        return repr(tree[1])
    return names.get(head, head)
