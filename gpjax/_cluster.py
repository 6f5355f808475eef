"""The Dask cluster that island runs and ``fit-many`` use.

Without a scheduler address a ``distributed.LocalCluster`` is started for the call (one
process per worker, one thread each: JAX already uses a worker's cores); with one, the
user's running cluster is used (``dask scheduler`` + ``dask worker ADDRESS``, or
``dask-jobqueue`` on SLURM/PBS). Workers receive the data with each task, so they need no
shared file system.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import signal
import threading
from typing import Iterator

from ._errors import UserInputError

#: Seconds to wait for a user's scheduler to answer.
CONNECT_TIMEOUT_S = 10
_ADDRESS = re.compile(r"(tcp|tls|ws|wss|ucx)://(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9._-]+):(\d{1,5})")


def check_scheduler_address(address: str) -> str:
    """``address`` if it reads ``PROTOCOL://HOST:PORT``; raises UserInputError otherwise."""
    match = _ADDRESS.fullmatch(address)
    if match is None or not 0 < int(match.group(3)) < 65536:
        raise UserInputError(f"scheduler address {address!r} is not PROTOCOL://HOST:PORT; give "
                             "the address a Dask scheduler prints, e.g. tcp://10.0.0.5:8786")
    return address


@contextlib.contextmanager
def dask_client(scheduler: str | None, *, workers: int) -> Iterator:
    """A ``distributed.Client``: to ``scheduler``, or to a new LocalCluster of ``workers``
    processes (closed on exit).

    Raises:
        UserInputError: a malformed or unreachable scheduler address.
    """
    from distributed import Client, LocalCluster

    from ._integrate import host_device_flags  # imports JAX: not before a user error

    if scheduler is None:
        # Workers start with Ctrl-C ignored (inherited), so it reaches only this process,
        # which stops after the current epoch; the cluster stays up to finish it.
        # Each worker gets its share of the host devices (inherited with the environment).
        main = threading.current_thread() is threading.main_thread()
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN) if main else None
        flags, shared = os.environ.get("XLA_FLAGS"), host_device_flags(workers)
        try:
            if shared is not None:
                os.environ["XLA_FLAGS"] = shared
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                   dashboard_address=None, silence_logs=logging.ERROR)
        finally:
            if previous is not None:
                signal.signal(signal.SIGINT, previous)
            if shared is not None and flags is not None:
                os.environ["XLA_FLAGS"] = flags
        with cluster, Client(cluster) as client:
            yield client
        return
    check_scheduler_address(scheduler)
    try:
        client = Client(scheduler, timeout=f"{CONNECT_TIMEOUT_S}s")
    except (OSError, TimeoutError) as err:
        raise UserInputError(f"cannot reach the Dask scheduler at {scheduler} ({err}); start "
                             "one ('dask scheduler', then 'dask worker ADDRESS') or leave out "
                             "--scheduler for a local cluster") from None
    with client:
        yield client


def worker_address() -> str | None:
    """Address of the Dask worker running the current task (``None`` outside one)."""
    from distributed import get_worker

    try:
        return get_worker().address
    except ValueError:
        return None
