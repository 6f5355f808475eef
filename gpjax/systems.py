"""Synthetic systems with a known truth, for benchmarks and tests.

:data:`SYSTEMS` (by name; :data:`PHYSICS_SUITE` the nine of the physics benchmark),
:class:`System` (equations, constants, excitation), :func:`generate` (fit and
extrapolation records with noise, :class:`SyntheticRecord`), :func:`write_csv`,
:func:`truth_error` (the truth against its own noisy data: the no-chaos check),
:func:`cramer_rao` (the identifiability floor of the truth's constants),
:func:`truth_refit` (the truth's constants refitted to the measured data) and the
scorer of :mod:`gpjax._scoring` (:func:`simulate_equations`, :func:`compare_structure`,
:func:`nrms`). See :mod:`gpjax._systems` and :mod:`gpjax._synthetic`.
"""

from ._scoring import (SimulationError, compare_structure, features, nrms,
                       simulate_equations)
from ._synthetic import (Record, SyntheticRecord, cramer_rao, generate, integrate, truth_error,
                         truth_refit, write_csv)
from ._systems import (PHYSICS_SUITE, SYSTEMS, Excitation, Multisine, StageLoop, System,
                       get_system, state_symbols)

__all__ = ["PHYSICS_SUITE", "SYSTEMS", "Excitation", "Multisine", "Record",
           "SimulationError", "StageLoop", "SyntheticRecord", "System", "compare_structure", "cramer_rao",
           "features", "generate", "get_system", "integrate", "nrms", "simulate_equations",
           "state_symbols", "truth_error", "truth_refit", "write_csv"]
