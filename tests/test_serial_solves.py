"""The XLA options gpjax sets (gpjax._integrate): batched LAPACK solves do not deadlock
XLA's CPU thread pool, and the CPU backend gets a host device per usable core."""

from __future__ import annotations

import os
import subprocess
import sys

from gpjax import _integrate
from gpjax._evaluator import SMALL_BATCHES
from gpjax._integrate import (MAX_HOST_DEVICES, SERIAL_SOLVES, host_device_flags,
                              schedule_solves_apart, split_over_host_cores, usable_cores)

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


def test_a_fresh_process_gets_a_host_device_per_usable_core():
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    program = ("import gpjax._integrate as i; i.enable_float64(); import jax; "
               "print(len(jax.devices()))")
    done = subprocess.run([sys.executable, "-c", program], env=env | {"JAX_PLATFORMS": "cpu"},
                          capture_output=True, text=True, timeout=120, check=True)
    assert int(done.stdout) == min(usable_cores(), MAX_HOST_DEVICES)


def test_host_devices_are_shared_among_workers_and_a_users_count_is_kept(monkeypatch):
    assert MAX_HOST_DEVICES == SMALL_BATCHES[0]  # no call padded past its rows by devices
    count = "--xla_force_host_platform_device_count"
    for cores, chosen in ((2, 2), (64, MAX_HOST_DEVICES)):
        monkeypatch.setattr(_integrate, "_CHOSEN", [0])
        monkeypatch.setattr(_integrate, "usable_cores", lambda cores=cores: cores)
        monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_enable_fast_math=false")
        split_over_host_cores()
        split_over_host_cores()
        assert os.environ["XLA_FLAGS"] == f"--xla_cpu_enable_fast_math=false {count}={chosen}"
        assert host_device_flags(2) == f"--xla_cpu_enable_fast_math=false {count}={chosen // 2}"
        assert host_device_flags(3 * chosen).endswith(f"{count}=1")
    monkeypatch.setattr(_integrate, "_CHOSEN", [0])
    monkeypatch.setenv("XLA_FLAGS", f"{count}=1")
    split_over_host_cores()
    assert os.environ["XLA_FLAGS"] == f"{count}=1" and host_device_flags(2) is None
