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


def run_child(tree: Path, script: str, *args: str):
    """``script`` (Python source) run with ``args`` in a fresh process on the tree at
    ``tree`` (CPU, compilation cache off: it compiles as a first run does); its last stdout
    line parsed as JSON. Raises ``subprocess.CalledProcessError`` when the child fails."""
    env = dict(os.environ, PYTHONPATH=str(tree), JAX_PLATFORMS="cpu",
               GPJAX_COMPILATION_CACHE="off")
    out = subprocess.run([sys.executable, "-c", script, *args], env=env, check=True,
                         capture_output=True, text=True, cwd=tree)
    return json.loads(out.stdout.strip().splitlines()[-1])
