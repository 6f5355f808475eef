"""A git revision's tree for benchmarks that compare against a baseline in the same run."""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


@contextlib.contextmanager
def baseline_tree(revision: str):
    """A temporary git worktree of ``revision`` (its path), removed on exit; raises
    ``subprocess.CalledProcessError`` where git does not know the revision."""
    with tempfile.TemporaryDirectory() as folder:
        tree = Path(folder) / "baseline"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(tree),
                        revision], check=True, capture_output=True)
        try:
            yield tree
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tree)],
                           check=True, capture_output=True)


def in_tree(tree: Path | None, **variables: str) -> dict:
    """``subprocess.run``'s ``env`` and ``cwd`` for a child process that runs the code at
    ``tree`` (this tree when ``None``), with ``variables`` added to the environment: the
    tree first on ``PYTHONPATH`` and as the working folder, since ``python -m`` and
    ``python -c`` put the working folder on ``sys.path`` before ``PYTHONPATH`` (from this
    repository a baseline's child would import this tree's code)."""
    tree = ROOT if tree is None else tree
    return {"env": dict(os.environ, **variables, PYTHONPATH=str(tree)), "cwd": tree}


def run_child(tree: Path, script: str, *args: str):
    """``script`` (Python source) run with ``args`` in a fresh process on the tree at
    ``tree`` (CPU, compilation cache off: it compiles as a first run does); its last stdout
    line parsed as JSON. Raises ``subprocess.CalledProcessError`` when the child fails."""
    out = subprocess.run([sys.executable, "-c", script, *args], check=True,
                         capture_output=True, text=True,
                         **in_tree(tree, JAX_PLATFORMS="cpu", GPJAX_COMPILATION_CACHE="off"))
    return json.loads(out.stdout.strip().splitlines()[-1])


def same_model(a, b) -> bool:
    """Whether two runs' models (:class:`gpjax.Model`) are the same model: the same
    equations with named constants (:meth:`gpjax.Model.equation`), every number inline (a
    held constant, a sign's scale) within 0.1 % of the other run's, and every named constant
    within one standard error of the other run's (the larger of the two; 6 significant
    digits where a run reports none). Two runs whose sums were ordered otherwise stop their
    Levenberg–Marquardt at another step once the constants are resolved to a fraction of
    their standard error, which is no other model. (Rounding every number of the numeric
    equations to 3 significant digits called 0.99863 and 0.99870 two models: sympy rounds
    a Float's binary mantissa, and the two straddled a rounding boundary.)"""
    import math

    import sympy as sp

    def shape(model):
        rows = []
        for i in range(model.n_coordinates):
            equation = model.equation(i)
            numbers = equation.atoms(sp.Float)
            rows.append((equation.xreplace({f: sp.Symbol("_number") for f in numbers}),
                         sorted(float(f) for f in numbers)))
        return rows

    def same_shape(x, y) -> bool:
        return all(ex == ey and len(nx) == len(ny) and all(
            math.isclose(p, q, rel_tol=1e-3) for p, q in zip(nx, ny))
            for (ex, nx), (ey, ny) in zip(x, y)) and len(x) == len(y)

    def errors(model):
        return {} if model.uncertainty is None else model.uncertainty.standard_errors

    ca, cb = a.constants(), b.constants()
    if not same_shape(shape(a), shape(b)) or set(ca) != set(cb):
        return False
    ea, eb = errors(a), errors(b)
    for name, value in ca.items():
        other = cb[name]
        se = max(ea.get(name, 0.0), eb.get(name, 0.0))
        se = se if 0 < se < float("inf") else 1e-6 * max(abs(value), abs(other))
        if abs(value - other) > se:
            return False
    return True
