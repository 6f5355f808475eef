"""Memory a fit needs, estimated before it allocates, against what the machine has free.

Model (float64 numbers, 8 bytes each; N samples, S = 2·(N − 1)·substeps + 1 RK4 stage
times, C = 16 forcing columns — the evaluator's smallest forcing capacity):

* evaluator (:class:`gpjax._evaluator.PopulationEvaluator`): the forcing basis, S × C,
  held once in numpy and once on the device; one compiled call holds
  ``EVALUATOR_ARRAYS`` stage arrays of S × B (B = min(population, 512), capped so
  B·S ≤ :data:`gpjax._evaluator.STAGE_ELEMENTS_PER_CALL`) and the responses, N × B;
* refiner (:class:`gpjax._refine.Refiner`): per model of its batch R, the forcing
  directions, S × Q (Q = its most free constants), and the Jacobian, N × Q, each held
  ``REFINER_COPIES`` times (stage slices, tangents, Levenberg–Marquardt's copies);
* weak form and derivatives (:mod:`gpjax._weak_form`): O(N), ``RECORD_ARRAYS`` × N;
* ``BASE_BYTES``: Python, JAX and XLA's compiled code, independent of N.

Calibration (``benchmarks/bench_scaling.py``, 2 CPU cores, population 24, substeps 1): the
estimate lies above the measured peak resident memory of ``gpjax fit`` by the margin
stated at :data:`BASE_BYTES`.
"""

from __future__ import annotations

import os

from ._errors import UserInputError
from ._evaluator import STAGE_ELEMENTS_PER_CALL
from ._refine import BATCH, MAX_FREE

FLOAT_BYTES = 8
FORCING_COLUMNS = 16
EVALUATOR_ARRAYS = 4
REFINER_COPIES = 3
RECORD_ARRAYS = 24
#: N-independent part; with the factors above the estimate exceeds the measured peak RSS
#: by 15–30 % (N = 10⁴ … 10⁶, see the module docstring).
BASE_BYTES = 700 * 2 ** 20


def fit_bytes(*, n_samples: int, substeps: int, population: int,
              refine_batch: int = BATCH, max_free: int = MAX_FREE) -> int:
    """Estimated peak memory of a fit, in bytes (see the module docstring)."""
    stages = 2 * (n_samples - 1) * substeps + 1
    batch = max(1, min(population, 512, STAGE_ELEMENTS_PER_CALL // stages))
    evaluator = 2 * stages * FORCING_COLUMNS + EVALUATOR_ARRAYS * stages * batch \
        + n_samples * batch
    refiner = REFINER_COPIES * refine_batch * max_free * (stages + n_samples)
    return BASE_BYTES + FLOAT_BYTES * (evaluator + refiner + RECORD_ARRAYS * n_samples)


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


def check_fit_memory(*, n_samples: int, substeps: int, population: int) -> None:
    """Raise :class:`UserInputError` if a fit's estimated need exceeds available memory."""
    need, free = fit_bytes(n_samples=n_samples, substeps=substeps,
                           population=population), available_bytes()
    if need > free:
        raise UserInputError(
            f"this run needs about {_gb(need)} of memory but {_gb(free)} are available "
            f"({n_samples:,} samples, substeps {substeps}, population {population}); "
            "shorten the record, or lower population or substeps")


def _gb(count: int) -> str:
    return f"{count / 1e9:.1f} GB"
