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

**The measured input's noise.** A simulation is driven by the *measured* input, whose sensor
noise rings through the model's dynamics into the residual, in the response's own band: a
correct model's residual is then above the response's floor σ̂ by that share, and more so
the coarser the sampling (the same noise per sample has a larger density at the resonance).
On a Duffing oscillator sampled at 20 Hz with 2 % noise on response and input (a record
outside the repository) the true model's residual (its input reconstructed band-limited) was
2.7× σ̂, all of it the input noise's, and the run flagged it and suggested physics it did
not miss. So each input's own white-noise floor σ_u is estimated much as the response's is
(its Hann-windowed periodogram above its own 99 %-energy band,
:func:`gpjax._diagnose_noise.input_noise_sigma`), seeded draws of it are added to the input,
and the model is simulated with and without them (RK4 at its step count): the RMS difference
σ_in is the input noise's share, and the gate compares the residual with √(σ̂² + σ_in²)
(``ratio_with_input``). That share is a linear propagation only where the response moves in
proportion to the noise: the same draws halved must move it about half as much (a scaling of
2). On a strongly driven hardening Duffing (a record outside the repository) the noise moved
the response by 43 % of its RMS and half of it by as much (scaling 0.96; 1.98–2.00 on four
smooth records): the response is not a smooth function of its input there, the share is not
counted and the line says so. An input without bins above its band (a broadband drive) has
no floor and counts for nothing, as before.
"""

from __future__ import annotations

import numpy as np

from ._config import WIDE_FUNCTIONS
from ._data import Measurement
from ._diagnose_evidence import input_lines
from ._diagnose_noise import PROPORTIONAL_FROM, models_input_noise, noise_floor
from ._diagnose_residual import FAR_ABOVE, describe_residual
from ._model import Model
from ._weak_form import smoothed_derivatives, smoothing_cutoff_hz


def residual_statistics(model: Model, measurement: Measurement, *, alpha: float = 0.05,
                        simulated: np.ndarray | None = None) -> dict[str, dict]:
    """Per coordinate name: ``rms`` (response units), ``nrms``, ``noise`` (the noise floor's
    ``sigma``, ``ratio`` = RMS/σ̂, ``band_hz``, ``p_excess``, and where an input has a noise
    floor ``input_sigma``, the measured input's noise rung through the model, and
    ``input_scaling``, and where that scaling is proportional (≥ :data:`PROPORTIONAL_FROM`)
    ``ratio_with_input`` = RMS/√(σ̂² + input_sigma²), which the gate uses (module
    docstring); ``None`` on a record too short for it; all ``None`` where the model diverges
    on the record) and ``unexplained`` (the residual described, or ``None`` where it is not
    far above its noise). ``simulated``: the model's (N, D) response (D = 1: also (N,)) if
    already computed (default: :meth:`Model.simulate` from the fitted initial states,
    reference solve).

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
    rung = None
    out = {}
    for d, name in enumerate(model.coordinates):
        single = measurement.coordinate(d)
        residual = single.response - simulated[:, d]
        if not np.all(np.isfinite(residual)):  # the reference solve failed: diverged
            out[name] = {"rms": None, "nrms": None, "noise": None, "unexplained": None}
            continue
        rms = float(np.sqrt(np.mean(residual ** 2)))
        floor = noise_floor(residual, single.dt, smoothing_cutoff_hz(single))
        if floor is not None:
            rung = input_noise_response(model, measurement) if rung is None else rung
            count_input_noise(floor, rung, d)
        unexplained = None
        if floor is not None and gate_ratio(floor) >= FAR_ABOVE and floor["p_excess"] < alpha:
            states = smoothed_derivatives(single)
            unexplained = describe_residual(residual, x=states.x, x_dot=states.x_dot,
                                            dt=single.dt, input_lines=lines, alpha=alpha)
        out[name] = {"rms": rms, "nrms": rms / float(np.std(single.response) or 1.0),
                     "noise": floor, "unexplained": unexplained}
    return out


def count_input_noise(floor: dict, rung: tuple[np.ndarray, np.ndarray], d: int) -> None:
    """Give a noise floor (:func:`gpjax._diagnose_noise.noise_floor` of coordinate ``d``'s
    residual) the measured input's share ``rung`` (:func:`input_noise_response`), in place:
    ``input_sigma``, ``input_scaling`` and, where the scaling is proportional,
    ``ratio_with_input``; nothing where ``rung`` is empty."""
    if not rung[0].size:
        return
    floor["input_sigma"], floor["input_scaling"] = float(rung[0][d]), float(rung[1][d])
    if floor["input_scaling"] >= PROPORTIONAL_FROM:
        floor["ratio_with_input"] = floor["rms"] / float(np.hypot(floor["sigma"], rung[0][d]))


def gate_ratio(floor: dict) -> float:
    """The ratio the flag's gate compares with :data:`FAR_ABOVE`: RMS over the response's
    floor and the measured input's noise together where the latter is known, else over σ̂."""
    return floor.get("ratio_with_input", floor["ratio"])


def input_noise_response(model: Model, measurement: Measurement
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Per coordinate (D,), the RMS of ``model``'s response to its measured inputs' noise
    and its scaling with the noise (:func:`gpjax._diagnose_noise.models_input_noise`,
    module docstring), simulated from its fitted initial states; both empty where no input
    has a floor or a response to a noisy input diverges."""
    evaluator = model.evaluator(measurement)
    rms, scaling = models_input_noise(evaluator, model.population(evaluator,
                                                                  model.initial_states))
    return (rms[0], scaling[0]) if rms.size else (rms, scaling)


def input_noise_words(floor: dict) -> str:
    """The measured input's share of a noise floor in words (\"; …\"), or \"\" where it has
    none (:func:`count_input_noise`)."""
    if "input_sigma" not in floor:
        return ""
    if "ratio_with_input" in floor:
        return (f"; with the measured input's noise rung through the model (RMS "
                f"{floor['input_sigma']:.3g}) {floor['ratio_with_input']:.2f}×")
    return (f"; the measured input's noise moves the simulated response by RMS "
            f"{floor['input_sigma']:.3g}, half that noise by about as much (×"
            f"{floor['input_scaling']:.2f}, not 2): the response is not a smooth function of "
            "its input here (chaotic or near a jump), so neither the residual nor the "
            "constants' intervals can be read against the noise")


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
    small = ("" if floor is None or flag or gate_ratio(floor) >= FAR_ABOVE
             or floor["p_excess"] >= alpha else
             f"; below the {FAR_ABOVE:g}× gate, so not flagged")
    rung = "" if floor is None else input_noise_words(floor)
    noise = ("noise floor not estimable (record too short)" if floor is None else
             f"{floor['ratio']:.2f}× its noise floor σ̂ = {floor['sigma']:.3g}{rung} "
             f"(in-band excess p = {floor['p_excess']:.2g}{small})")
    return (f"  residual of {name}: RMS {statistics['rms']:.4g} (NRMS "
            f"{statistics['nrms']:.3%}), {noise}{flag}")
