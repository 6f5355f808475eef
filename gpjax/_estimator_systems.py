""":meth:`gpjax.Identifier.fit` on a measurement of several coordinates: the report.

The GP over systems (:class:`gpjax._system_search.SystemEvolution`: one equation per
coordinate) runs in :meth:`gpjax.Identifier.fit`'s loop, with its checkpoints, resume and
islands; :func:`finish_system` then runs its final model selection and the fit at
converged integration, and fills the same attributes and run folder as one coordinate:
``model_`` (a :class:`gpjax.Model` of D
equations, its metrics per coordinate), ``history_``, ``equations_`` (the reported system,
one row), ``convergence_``, ``stopped_by`` and ``timings_``; the folder holds
``model.json``, ``history.csv``, ``equations.csv``, ``equations.json``, ``config.json``
and ``fit.png`` (one row of panels per coordinate).
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from . import _progress
from ._aot import compiled_since
from ._data import Measurement
from ._report import history_csv, write_bytes_atomic, write_text_atomic


def finish_system(identifier, evolution, seed: int, state, *, began: float,
                  compiled: tuple[float, int], out: Path | None, interrupted: bool) -> None:
    """Report the system of a finished search into ``identifier`` (module docstring):
    ``evolution`` the :class:`gpjax._system_search.SystemEvolution` holding its scores,
    ``state`` its last generation, ``began`` the run's start and ``compiled`` the
    :func:`gpjax._aot.compile_ledger` then; ``out``: the run folder or ``None``."""
    from ._system_diagnose import residual_statistics

    config, measurement = identifier.config, evolution.measurement
    selecting = time.perf_counter()
    result = evolution.finish(state)
    fit = result.fit
    # the last check's reference response is the reported model's, as one coordinate's
    # residuals take it (Identifier._set_residuals); solved again only where the check
    # covered a window of the record
    covered = fit.reference is not None and len(fit.reference) == measurement.n_samples
    residuals = residual_statistics(fit.model, measurement,
                                    simulated=fit.reference if covered else None)
    history = result.history
    identifier.stopped_by = ("interrupted" if interrupted else
                             "epsilon" if history[-1]["best_objective"] <= evolution.stop_objective
                             else "generations")
    # the width check where one coordinate's is: in the convergence record, with the
    # reason its narrowing stopped unconverged
    identifier.model_ = dataclasses.replace(
        fit.model, uncertainty=fit.uncertainty,
        convergence=fit.checks[-1].to_json()
        | ({"sign_width": result.sign_width} if result.sign_width else {})
        | ({"stopped": result.stopped} if result.stopped else {}),
        metrics={"rms": {k: v["rms"] for k, v in residuals.items()},
                 "nrms": {k: v["nrms"] for k, v in residuals.items()},
                 "objective": float(fit.scores.objective[0]), "residuals": residuals},
        provenance={"seed": seed, "generations": history[-1]["generation"],
                    "stopped_by": identifier.stopped_by, "population": config.population,
                    "data": measurement.fingerprint(), **identifier._provenance})
    identifier.measurement_ = measurement
    identifier.history_ = [dict(row) for row in history]
    identifier.convergence_ = list(fit.checks)
    identifier._equation_models = [identifier.model_]
    model = identifier.model_
    identifier.equations_ = [{
        "complexity": len(model.constants()), "objective": model.metrics["objective"],
        "rms": float(np.sqrt(np.mean(np.square([np.nan if v is None else v  # None: diverged
                                                for v in model.metrics["rms"].values()])))),
        "equation": "; ".join(str(model.sympy(i)) for i in range(model.n_coordinates)),
        "selected": True,
        "constants": ", ".join(f"{k} = {v}" for k, v in model.constant_texts().items())}]
    writing = time.perf_counter()
    if out is not None:
        _write(identifier, out)
    ended = time.perf_counter()
    timings = result.timings
    identifier.timings_ = {
        "total_s": ended - began, "search_s": selecting - began,
        "selection_s": timings["selection_s"],
        "convergence_s": writing - selecting - timings["selection_s"],  # and the residuals
        "writing_s": ended - writing, **compiled_since(compiled),
        "generations": history[-1]["generation"],
        "finished_at": time.time()}


def _write(identifier, out: Path) -> None:
    """The run folder of a system (module docstring)."""
    _progress.stage(f"writing results to {out}/")
    model, measurement = identifier.model_, identifier.measurement_
    out.mkdir(parents=True, exist_ok=True)
    model.save(out / "model.json")
    write_text_atomic(out / "history.csv", history_csv(identifier.history_))
    write_text_atomic(out / "equations.csv", history_csv(identifier.equations_))
    write_text_atomic(out / "equations.json", json.dumps([model.to_json()], indent=1) + "\n")
    write_text_atomic(out / "config.json",
                      json.dumps(identifier.config.to_dict(), indent=2) + "\n")
    calculated = model.simulate(measurement, initial_conditions=model.initial_states)
    write_bytes_atomic(out / "fit.png", _figure(measurement, calculated, str(model)))


def _figure(measurement: Measurement, calculated: np.ndarray, title: str) -> bytes:
    """PNG bytes: every coordinate's measured and calculated response, one panel each."""
    from matplotlib.figure import Figure

    from ._report import png_bytes

    count = measurement.n_coordinates
    figure = Figure(figsize=(9, 2.6 * count + 0.8), constrained_layout=True)
    axes = np.atleast_1d(figure.subplots(count, 1, sharex=True))
    for d, ax in enumerate(axes):
        ax.plot(measurement.time, measurement.responses[:, d], color="0.55", lw=1.2,
                label="measured")
        ax.plot(measurement.time, calculated[:, d], color="C3", lw=1.0, ls="--",
                label="calculated (reference solve)")
        ax.set_ylabel(measurement.response_names[d])
        ax.legend(loc="upper right")
    axes[0].set_title(title, fontsize=8)
    axes[-1].set_xlabel(f"{measurement.time_name} [s]")
    return png_bytes(figure, dpi=110)
