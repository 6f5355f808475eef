"""Memory a fit needs, estimated before it allocates, against what the machine has free.

Model (float64 numbers, 8 bytes each; N samples, S = 2·(N − 1)·substeps + 1 RK4 stage
times, C forcing columns — the evaluator's first forcing capacity). The peak is
what stays for the whole fit plus the larger of one evaluator call and one refiner call
(they run one after the other):

* always held: ``BASE_BYTES`` (Python, JAX, XLA's compiled code; independent of N), the
  forcing basis S × C in numpy and on the device, and ``RECORD_ARRAYS`` × N (record,
  Savitzky–Golay derivatives, weak-form columns — :mod:`gpjax._weak_form` is O(N));
* one evaluator call (:class:`gpjax._evaluator.PopulationEvaluator`):
  ``EVALUATOR_ARRAYS`` stage arrays of S × B (B = min(population, 512), capped so
  B·S ≤ :data:`gpjax._evaluator.STAGE_ELEMENTS_PER_CALL`) and the responses, N × B;
* one refiner call (:class:`gpjax._refine.Refiner`): per model of its batch R (capped by
  :func:`gpjax._refine.refine_batch`), the forcing directions, S × Q (Q = its most free
  constants) and the Jacobian, N × Q, each held ``REFINER_COPIES`` times (stage slices,
  tangents, Levenberg–Marquardt's copies).

A later stage of the same process (the diagnosis's fits, :class:`gpjax._diagnose_fits.FitProblem`)
is checked when it starts, at its own substeps and batch, for :func:`fit_bytes` less
``BASE_BYTES`` (which the process holds already), its simulator's evaluator arrays held
beside its refiner's (a diagnosis keeps the current model's simulator through a round),
against the memory then available. On the Silverbox estimation record at 10 steps per
sample (``gpjax fit --diagnose``, the README's command): 1.36 GB (batch 5) on 0.97 GB
resident when the rounds start (2.34 GB; their peak, another run's trace, 2.30 GB) and
1.24 GB (batch 3) on 1.18 GB when the whole-record refit starts (2.42 GB; the process's
peak, in that last stage, 2.40 GB): an estimate at the measured peak, not above it with a
margin.

A system of D coordinates holds the record's arrays and each call's D times (the forcing
basis once). Against measured peaks of ``gpjax fit`` (population 500, 2,001 samples): a
2-mass chain at 1 step per sample 903 MB estimated, 958 MB measured; a 3-mass chain at 3
steps 1,560 MB estimated, 1,221 MB measured.

Calibration against the peak resident memory of ``gpjax fit`` (population 24,
substeps 1, ``benchmarks/bench_scaling.py``; 2 CPU cores): see :data:`BASE_BYTES`.
"""

from __future__ import annotations

import os

from ._errors import UserInputError
from ._evaluator import STAGE_ELEMENTS_PER_CALL
from ._evaluator_columns import first_forcing_capacity
from ._refine import BATCH, MAX_FREE, refine_batch

FLOAT_BYTES = 8
EVALUATOR_ARRAYS = 6
REFINER_COPIES = 4
RECORD_ARRAYS = 32
#: N-independent part. Estimate / measured peak RSS: see benchmarks/bench_scaling.json
#: (N = 10⁴, 10⁵, 10⁶: the estimate lies 12–18 % above: 766, 1,359, 2,623 MB
#: against 683, 1,147, 2,334 MB measured).
BASE_BYTES = 700 * 2 ** 20


def fit_bytes(*, n_samples: int, substeps: int, population: int, coordinates: int = 1,
              together: bool = False) -> int:
    """Estimated peak memory of a fit of ``coordinates`` responses, in bytes (see the
    module docstring: every per-coordinate array is held once per coordinate);
    ``together``: an evaluator call's arrays held beside a refiner call's, not after it."""
    stages = 2 * (n_samples - 1) * substeps + 1
    batch = max(1, min(population, 512, STAGE_ELEMENTS_PER_CALL // stages))
    models = refine_batch(BATCH, n_samples=n_samples, substeps=substeps, max_free=MAX_FREE)
    held = 2 * stages * first_forcing_capacity(stages) + RECORD_ARRAYS * n_samples * coordinates
    evaluator = coordinates * (EVALUATOR_ARRAYS * stages * batch + n_samples * batch)
    refiner = coordinates * REFINER_COPIES * models * MAX_FREE * (stages + n_samples)
    calls = evaluator + refiner if together else max(evaluator, refiner)
    return BASE_BYTES + FLOAT_BYTES * (held + calls)


def available_bytes() -> int:
    """Memory the system can give without swapping: ``MemAvailable`` of /proc/meminfo, or
    free physical pages where that file is missing."""
    try:
        with open("/proc/meminfo") as handle:
            for line in handle:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")


def check_fit_memory(*, n_samples: int, substeps: int, population: int,
                     coordinates: int = 1, stage: str | None = None) -> None:
    """Raise :class:`UserInputError` if a fit's estimated need exceeds available memory.

    ``stage``: the name of a later stage of a running process (the diagnosis's fits), whose
    :data:`BASE_BYTES` the process already holds and the available memory already excludes:
    only the rest of :func:`fit_bytes` is needed, at the stage's own substeps and batch, with
    its simulator's arrays beside its refiner's (``together``)."""
    need = fit_bytes(n_samples=n_samples, substeps=substeps, population=population,
                     coordinates=coordinates, together=stage is not None) - (
                         BASE_BYTES if stage else 0)
    free = available_bytes()
    if need > free and stage:
        raise UserInputError(
            f"not enough memory for {stage}: about {_gb(need)} more needed, {_gb(free)} "
            f"available ({n_samples:,} samples at {substeps} RK4 steps each); shorten the "
            "record")
    if need > free:
        raise UserInputError(
            f"this run needs about {_gb(need)} of memory but {_gb(free)} are available "
            f"({n_samples:,} samples, substeps {substeps}, population {population}); "
            "shorten the record, or lower population or substeps")


def release_memory() -> None:
    """Hand memory a finished stage freed back to the system: a garbage collection (JAX
    arrays in reference cycles), then glibc's ``malloc_trim`` (freed heap pages that the
    allocator keeps otherwise: a later stage's arrays then land on top of the earlier ones'
    holes, and the resident size grows stage by stage — the remedy Dask's workers apply
    too, by ``MALLOC_TRIM_THRESHOLD_``). No-op for the allocator where libc has no
    ``malloc_trim`` (macOS, musl)."""
    import ctypes
    import gc

    gc.collect()
    try:
        ctypes.CDLL(None).malloc_trim(0)
    except (AttributeError, OSError):
        pass


def _gb(count: int) -> str:
    return f"{count / 1e9:.1f} GB"
