"""Whitelist parser for expressions in model and configuration files.

Text is parsed with Python's ``ast`` (which only parses, never runs) and every node is
checked against a whitelist before a sympy expression is built from it by hand: numbers,
the allowed names, + − × / **, unary minus, ``Eq(lhs, rhs)`` at the top, and the functions
listed in :data:`FUNCTIONS`. Anything else — attribute access, subscripts, lambdas,
comprehensions, unknown names or functions, strings — is a :class:`ModelFileError`.
``eval``, ``exec``, ``sympify`` and ``parse_expr`` are never applied to file text.
"""

from __future__ import annotations

import ast
from functools import lru_cache

import sympy as sp

from ._errors import ModelFileError

FUNCTIONS = {"sin": sp.sin, "cos": sp.cos, "exp": sp.exp, "tanh": sp.tanh, "sinh": sp.sinh,
             "cosh": sp.cosh, "sign": sp.sign,
             "Abs": sp.Abs, "abs": sp.Abs, "sqrt": sp.sqrt, "log": sp.log}
MAX_LENGTH = 10_000
MAX_DEPTH = 100
#: Largest allowed |exponent|: higher powers would make canonicalisation explode.
MAX_EXPONENT = 32
_BINARY = {ast.Add: sp.Add, ast.Sub: lambda a, b: a - b, ast.Mult: sp.Mul,
           ast.Div: lambda a, b: a / b, ast.Pow: sp.Pow}


def parse_expression(text: str, names: set[str] | frozenset[str], *,
                     allow_equation: bool = False) -> sp.Expr | sp.Eq:
    """Parse ``text`` into sympy using only ``names`` as symbols.

    Raises:
        ModelFileError: the text is not a string, too long, not an expression, or holds a
            construct, name or function outside the whitelist.
    """
    if not isinstance(text, str):
        raise ModelFileError(f"expected an expression string, got {type(text).__name__}")
    return _parse(text, frozenset(names), allow_equation)


@lru_cache(maxsize=20_000)
def _parse(text: str, names: frozenset[str], allow_equation: bool):
    if len(text) > MAX_LENGTH:
        raise ModelFileError(f"expression longer than {MAX_LENGTH} characters; shorten it")
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except (SyntaxError, ValueError) as err:
        raise ModelFileError(f"cannot parse expression {text[:60]!r}: "
                             f"{getattr(err, 'msg', err)}") from None
    except (RecursionError, MemoryError):
        raise ModelFileError(f"expression {text[:60]!r} is nested too deeply") from None
    return _build(tree.body, names, allow_equation, 0, text)


def _build(node: ast.AST, names: frozenset[str], allow_equation: bool, depth: int, text: str):
    if depth > MAX_DEPTH:
        raise ModelFileError(f"expression {text[:60]!r} is nested too deeply")
    recurse = lambda child: _build(child, names, False, depth + 1, text)  # noqa: E731
    if isinstance(node, ast.Constant) and type(node.value) in (int, float):
        return sp.Integer(node.value) if isinstance(node.value, int) else sp.Float(node.value)
    if isinstance(node, ast.Name):
        if node.id in names:
            return sp.Symbol(node.id)
        raise ModelFileError(f"unknown name {node.id!r} in expression {text[:60]!r}; "
                             f"allowed: {', '.join(sorted(names))}")
    if isinstance(node, ast.BinOp) and type(node.op) in _BINARY:
        left, right = recurse(node.left), recurse(node.right)
        if isinstance(node.op, ast.Pow) and not (right.is_number and abs(right) <= MAX_EXPONENT):
            raise ModelFileError(f"exponent must be a number of at most {MAX_EXPONENT} in "
                                 f"{text[:60]!r}")
        return _BINARY[type(node.op)](left, right)
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        operand = recurse(node.operand)
        return -operand if isinstance(node.op, ast.USub) else operand
    if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and not node.keywords):
        name = node.func.id
        if name == "Eq" and allow_equation and len(node.args) == 2:
            return sp.Eq(recurse(node.args[0]), recurse(node.args[1]), evaluate=False)
        if name in FUNCTIONS and len(node.args) == 1:
            return FUNCTIONS[name](recurse(node.args[0]))
        raise ModelFileError(f"function {name!r} is not allowed in {text[:60]!r}; "
                             f"allowed: {', '.join(sorted(FUNCTIONS))}")
    raise ModelFileError(f"{type(node).__name__} is not allowed in expression {text[:60]!r}; "
                         "use numbers, names, + - * / ** and whitelisted functions")
