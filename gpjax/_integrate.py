"""Fixed-step RK4 for whole populations: the tableau for diffrax and the ``lax.scan`` step.

Both integrators of :class:`gpjax._evaluator.PopulationEvaluator` run the classical RK4
tableau on the same stage grid: :func:`rk4_scan` (default; a hand-written step in
``lax.scan``, no per-step bookkeeping) and diffrax with :func:`rk4_solver`. The converged
reference that checks them is :mod:`gpjax._reference`.

gpjax computes in float64: :func:`enable_float64` switches JAX's ``jax_enable_x64`` on
when gpjax first builds something that computes (an evaluator, a reference solve), not
when it is imported, and turns on the persistent compilation cache
(:mod:`gpjax._jaxcache`).
"""

from __future__ import annotations

import functools
import os
from typing import Callable, ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from ._jaxcache import enable_compilation_cache


def enable_float64() -> None:
    """Switch JAX to float64 (``jax_enable_x64``) for the rest of the process, turn on
    gpjax's persistent compilation cache (:func:`gpjax._jaxcache.enable_compilation_cache`)
    keep XLA from running two batched solves at once (:func:`schedule_solves_apart`) and
    give its CPU backend a host device per usable core (:func:`split_over_host_cores`).

    Called by gpjax's constructors that compute; it affects arrays a user's own JAX code
    creates afterwards too (see the README, "Precision").
    """
    enable_compilation_cache()
    schedule_solves_apart()
    split_over_host_cores()
    if not jax.config.jax_enable_x64:
        jax.config.update("jax_enable_x64", True)


#: XLA's CPU option that keeps independent LAPACK solves from running at once.
SERIAL_SOLVES = "--xla_cpu_enable_concurrency_optimized_scheduler=false"


def schedule_solves_apart() -> None:
    """Add :data:`SERIAL_SOLVES` to ``XLA_FLAGS`` (unless the user's flags set that option):
    jaxlib's batched LAPACK kernels (LU, Cholesky) split a large batch over XLA's intra-op
    thread pool and wait for the parts, and XLA's concurrency-optimised schedule runs two
    independent solves at once; on a pool of two threads (a 2-core machine) both then wait
    and neither part runs. A 3-mass chain's refinement (26 free constants, 8 systems a
    call) hung so in every run of one record, and 512 batched 8 × 8 solves twice in one
    program hang alike; with the option neither does. It takes effect only if XLA's CPU
    backend has not started yet (gpjax computes first in a process)."""
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_cpu_enable_concurrency_optimized_scheduler" not in flags:
        os.environ["XLA_FLAGS"] = f"{flags} {SERIAL_SOLVES}".strip()


#: XLA's CPU option for the number of host devices.
HOST_DEVICES = "xla_force_host_platform_device_count"
#: Most host devices :func:`split_over_host_cores` makes: the evaluator's smallest batch
#: (:data:`gpjax._evaluator.SMALL_BATCHES`). A call is padded to a multiple of the devices,
#: so more would pad a call of a few models past its rows.
MAX_HOST_DEVICES = 16
#: The host devices gpjax chose for this process (0: none; the user's flags or a started
#: backend decide).
_CHOSEN = [0]


def usable_cores() -> int:
    """The CPU cores this process may run on (its affinity mask where the OS has one)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


def split_over_host_cores() -> None:
    """Give XLA's CPU backend one host device per usable core, at most
    :data:`MAX_HOST_DEVICES`, unless ``XLA_FLAGS`` sets the count (``=1`` keeps one).
    Every call's models are independent and split over the devices (``shard_map``,
    :class:`gpjax._evaluator.PopulationEvaluator`); on one device XLA runs a call's RK4
    scan, a sequence of small operations, on one thread, so a second core stayed idle
    (``benchmarks/new_record_devices.json``: the same equations, whole fits 7–18 %
    shorter on 2 cores). Takes effect only if the backend has not started yet."""
    flags = os.environ.get("XLA_FLAGS", "")
    if HOST_DEVICES in flags:
        return
    count = min(usable_cores(), MAX_HOST_DEVICES)
    if count > 1:
        os.environ["XLA_FLAGS"] = f"{flags} --{HOST_DEVICES}={count}".strip()
        _CHOSEN[0] = count


def host_device_flags(workers: int) -> str | None:
    """``XLA_FLAGS`` for each of ``workers`` processes started on this machine: the host
    devices gpjax chose shared among them (at least one each), so they do not ask for
    more threads than there are cores; ``None`` where gpjax chose none (the user's flags
    stand)."""
    if not _CHOSEN[0]:
        return None
    flags = [f for f in os.environ.get("XLA_FLAGS", "").split()
             if not f.startswith(f"--{HOST_DEVICES}=")]
    return " ".join(flags + [f"--{HOST_DEVICES}={max(1, _CHOSEN[0] // workers)}"])


@functools.cache
def rk4_solver():
    """diffrax's solver for the classical fourth-order Runge–Kutta method, for fixed steps
    (no error estimate): diffrax 0.7 has no RK4 class; this one is built from its Butcher
    tableau.

    diffrax is imported here, on first use, as in :mod:`gpjax._reference` and with
    optimistix in :mod:`gpjax._refine`: a process whose compiled programs all come from
    the cache (:mod:`gpjax._aot`) traces nothing and never imports them (about 0.6 s of
    its start on 2 cores).
    """
    import diffrax

    class RK4(diffrax.AbstractERK):
        tableau: ClassVar[diffrax.ButcherTableau] = diffrax.ButcherTableau(
            c=np.array([0.5, 0.5, 1.0]),
            b_sol=np.array([1 / 6, 1 / 3, 1 / 3, 1 / 6]),
            b_error=np.zeros(4),
            a_lower=(np.array([0.5]), np.array([0.0, 0.5]), np.array([0.0, 0.0, 1.0])),
        )
        interpolation_cls: ClassVar[Callable] = (
            diffrax.ThirdOrderHermitePolynomialInterpolation.from_k)

        def order(self, terms):
            del terms
            return 4

    return RK4()


def rk4_scan(rates, y0, forces, saved, *, h: float, t0: float, substeps: int,
             split_stages: bool, fold=None):
    """Classical RK4 over a stage grid in ``lax.scan`` for a tuple of states, one scan step
    per sample interval (its ``substeps`` RK4 steps an inner scan): what is saved or
    folded is computed at the samples only.

    Args:
        rates: ``rates(y, force, t)`` gives dy/dt for the tuple of states y.
        y0: the tuple of initial states.
        forces: arrays with the forcing rows first. Shared layout (``split_stages``
            False): rows t0, t0 + h/2, t0 + h, … (2·steps + 1). Split layout: every
            step's start, middle and end-left-limit rows (3·steps).
        saved: ``saved(y)`` picks what is returned at the sample times.
        h: step (s); t0: time of the first row (s); substeps: steps per sample interval.
        fold: ``(fn, acc)``: also carry ``acc = fn(acc, y, k)`` at every sample k = 1, 2,
            … after the first (a running sum instead of a saved path: no (N, …) array is
            written).

    Returns:
        The tuple ``saved`` picks, each at the sample times with the initial value first;
        with ``fold``, (that tuple, the final acc).
    """
    def along(y, k, c):
        return tuple(a + c * b for a, b in zip(y, k))

    def rk4_step(carry, stage):
        y, i = carry
        f0, f_half, f1 = stage
        t = t0 + i * h
        k1 = rates(y, f0, t)
        k2 = rates(along(y, k1, 0.5 * h), f_half, t + 0.5 * h)
        k3 = rates(along(y, k2, 0.5 * h), f_half, t + 0.5 * h)
        k4 = rates(along(y, k3, h), f1, t + h)
        y = tuple(a + h / 6 * (b1 + 2 * b2 + 2 * b3 + b4)
                  for a, b1, b2, b3, b4 in zip(y, k1, k2, k3, k4))
        return (y, i + 1), None

    def sample_step(carry, stage):
        y, i, acc = carry
        if substeps == 1:
            (y, i), _ = rk4_step((y, i), stage)
        else:
            (y, i), _ = jax.lax.scan(rk4_step, (y, i), stage)
        if fold is not None:
            acc = fold[0](acc, y, i // substeps)
        return (y, i, acc), saved(y)

    if split_stages:
        stages = jax.tree_util.tree_map(lambda f: (f[0::3], f[1::3], f[2::3]), forces)
    else:
        stages = jax.tree_util.tree_map(lambda f: (f[0:-1:2], f[1::2], f[2::2]), forces)
    if substeps > 1:  # (samples − 1, substeps, …): a sample interval's steps together
        stages = jax.tree_util.tree_map(
            lambda f: f.reshape((f.shape[0] // substeps, substeps) + f.shape[1:]), stages)
    stages = jax.tree_util.tree_transpose(
        jax.tree_util.tree_structure(forces), jax.tree_util.tree_structure((0, 0, 0)), stages)
    (_, _, acc), path = jax.lax.scan(sample_step, (y0, jnp.zeros((), jnp.int32),
                                                   () if fold is None else fold[1]), stages)
    out = tuple(jnp.concatenate([first[None], p]) for first, p in zip(saved(y0), path))
    return out if fold is None else (out, acc)
