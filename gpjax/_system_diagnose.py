"""Per-equation diagnosis of a system: every coordinate's residual, described on its own.

For a fitted :class:`gpjax.Model` of several coordinates and a record of all its coordinates,
coordinate i's output-error residual (measured − reference-solve response) is described
as the one-coordinate diagnosis describes its final residual: RMS, NRMS (÷ the response's
standard deviation), the noise floor σ̂ above the coordinate's 99 %-energy band, RMS / σ̂
and the p-value of the in-band excess (:func:`gpjax._diagnose_noise.noise_floor`); where
the residual stays far above its floor (:data:`gpjax._diagnose_residual.FAR_ABOVE` × σ̂
and a significant excess) also its spectral lines, its dependence on x_i and x_i' and
hysteresis, with suggestions (:func:`gpjax._diagnose_residual.describe_residual`). A
coordinate whose residual is far above its noise points at the equation that misses
something (the equations are coupled, so a neighbour's residual may rise with it).
"""

from __future__ import annotations

import numpy as np

from ._config import WIDE_FUNCTIONS
from ._data import Measurement
from ._diagnose_evidence import input_lines
from ._diagnose_noise import noise_floor
from ._diagnose_residual import FAR_ABOVE, describe_residual
from ._model import Model
from ._weak_form import smoothed_derivatives, smoothing_cutoff_hz


def residual_statistics(model: Model, measurement: Measurement, *, alpha: float = 0.05,
                        simulated: np.ndarray | None = None) -> dict[str, dict]:
    """Per coordinate name: ``rms`` (response units), ``nrms``, ``noise`` (the noise floor's
    ``sigma``, ``ratio`` = RMS/σ̂, ``band_hz``, ``p_excess``; ``None`` on a record too
    short for it; all ``None`` where the model diverges on the record) and ``unexplained``
    (the residual described, or ``None`` where it is not far above its noise).
    ``simulated``: the model's (N, D) response (D = 1: also (N,)) if already
    computed (default: :meth:`Model.simulate` from the fitted initial states, reference
    solve).

    Raises:
        ValueError: ``measurement``'s responses are not the model's coordinates.
    """
    if tuple(measurement.response_names) != tuple(model.coordinates):
        raise ValueError(f"the record's responses {list(measurement.response_names)} are not "
                         f"the model's coordinates {list(model.coordinates)}")
    simulated = (model.simulate(measurement, initial_conditions=model.initial_states)
                 if simulated is None else simulated)
    simulated = np.reshape(simulated, (measurement.n_samples, model.n_coordinates))
    lines = input_lines(measurement) if measurement.inputs else []
    out = {}
    for d, name in enumerate(model.coordinates):
        single = measurement.coordinate(d)
        residual = single.response - simulated[:, d]
        if not np.all(np.isfinite(residual)):  # the reference solve failed: diverged
            out[name] = {"rms": None, "nrms": None, "noise": None, "unexplained": None}
            continue
        rms = float(np.sqrt(np.mean(residual ** 2)))
        floor = noise_floor(residual, single.dt, smoothing_cutoff_hz(single))
        unexplained = None
        if floor is not None and floor["ratio"] >= FAR_ABOVE and floor["p_excess"] < alpha:
            states = smoothed_derivatives(single)
            unexplained = describe_residual(residual, x=states.x, x_dot=states.x_dot,
                                            dt=single.dt, input_lines=lines, alpha=alpha)
        out[name] = {"rms": rms, "nrms": rms / float(np.std(single.response) or 1.0),
                     "noise": floor, "unexplained": unexplained}
    return out


def hint(functions: tuple[str, ...] = ()) -> str:
    """What to try where a coordinate's residual is far above its noise floor or the model
    diverges; widening ``--functions`` only where the run's ``functions`` lack part of
    :data:`gpjax._config.WIDE_FUNCTIONS`."""
    widen = ("" if set(WIDE_FUNCTIONS) <= set(functions) else
             f"widen --functions (e.g. {','.join(WIDE_FUNCTIONS)}), ")
    return (f"the model misses physics or diverges: {widen}raise --population and "
            "--generations, or add --diagnose to name the missing effect; a coordinate "
            "without a restoring force (a free mass in a position loop) drifts when "
            "simulated from its measured input, and the search cannot rank models on it "
            "(docs: Known limitations)")


def summary_line(name: str, statistics: dict, functions: tuple[str, ...] = (), *,
                 alpha: float = 0.05) -> str:
    """One line of a coordinate's residual statistics for the terminal (``functions``: the
    run's function set, for :func:`hint`; ``alpha``: the level of
    :func:`residual_statistics`). A significant in-band excess below
    :data:`~gpjax._diagnose_residual.FAR_ABOVE` × σ̂ is marked as not flagged."""
    if statistics["rms"] is None:
        return (f"  residual of {name}: the fitted model diverges on its record  <- "
                f"{hint(functions)}")
    floor = statistics["noise"]
    flag = "  <- misses something" if statistics["unexplained"] is not None else ""
    small = ("" if floor is None or flag or floor["ratio"] >= FAR_ABOVE
             or floor["p_excess"] >= alpha else
             f"; below the {FAR_ABOVE:g}× gate, so not flagged")
    noise = ("noise floor not estimable (record too short)" if floor is None else
             f"{floor['ratio']:.2f}× its noise floor σ̂ = {floor['sigma']:.3g} "
             f"(in-band excess p = {floor['p_excess']:.2g}{small})")
    return (f"  residual of {name}: RMS {statistics['rms']:.4g} (NRMS "
            f"{statistics['nrms']:.3%}), {noise}{flag}")
