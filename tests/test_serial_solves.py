"""Batched LAPACK solves do not deadlock XLA's CPU thread pool (gpjax._integrate)."""

from __future__ import annotations

import os
import subprocess
import sys

from gpjax._integrate import SERIAL_SOLVES, schedule_solves_apart

#: Two independent batched solves in one program, run until one of them would have hung: on
#: a 2-core machine, without the option, the first call or one of the next few hung.
PROGRAM = """
import gpjax._integrate
gpjax._integrate.enable_float64()
import jax, jax.numpy as jnp

@jax.jit
def two(a, b):
    return jnp.linalg.solve(a, b), jnp.linalg.solve(a * 1.01, b)

a = jax.random.normal(jax.random.PRNGKey(0), (4096, 8, 8)) + 5 * jnp.eye(8)
b = jnp.ones((4096, 8, 1))
for _ in range(200):
    jax.block_until_ready(two(a, b))
print("done")
"""


def test_two_batched_solves_in_one_program_finish():
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    done = subprocess.run([sys.executable, "-c", PROGRAM], env=env | {"JAX_PLATFORMS": "cpu"},
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == "done"


def test_the_option_is_added_once_and_a_users_own_setting_is_kept(monkeypatch):
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_enable_fast_math=false")
    schedule_solves_apart()
    schedule_solves_apart()
    assert os.environ["XLA_FLAGS"] == f"--xla_cpu_enable_fast_math=false {SERIAL_SOLVES}"
    own = "--xla_cpu_enable_concurrency_optimized_scheduler=true"
    monkeypatch.setenv("XLA_FLAGS", own)
    schedule_solves_apart()
    assert os.environ["XLA_FLAGS"] == own
