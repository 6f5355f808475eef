"""Diagnosis: effects that this record cannot tell apart, and the input that would.

When an effect is accepted, every other candidate of the round that also passed the
acceptance test is compared with it by the same held-out test
(:func:`gpjax._diagnose_acceptance.predictive_test`, one-sided: does the accepted effect
predict the held-out segment better?). Those it does not beat at level ``alpha`` explain
the record equally well: the report names them with the accepted one as a set and says
this record cannot separate them. Around a record's operating point, for example, a cubic
stiffness acts mostly as a constant force, so a static offset predicts as well.

Then the models of the set (each fitted on the estimation part) are simulated under a few
changes of the measured input: a larger amplitude, a static level added, and the input
played at half its speed (a lower band). The change whose responses differ most, relative
to the accepted model's held-out RMS residual (an upper bound of the noise), is proposed
as the next experiment.
"""

from __future__ import annotations

import numpy as np

from ._diagnose_acceptance import predictive_test


def input_changes(time: np.ndarray, inputs: dict[str, np.ndarray]) -> dict[str, dict]:
    """Name -> the changed inputs (name -> (N,)) of each change this module proposes from:
    the record itself, amplitude × 1.5 about the mean, a static level of one standard
    deviation added, and the record played at half speed."""
    def each(change):
        return {name: change(np.asarray(u, dtype=float)) for name, u in inputs.items()}

    t = np.asarray(time, dtype=float)
    return {"this record": each(lambda u: u),
            "amplitude x1.5": each(lambda u: u.mean() + 1.5 * (u - u.mean())),
            "static level +1 std": each(lambda u: u + u.std()),
            "half speed (lower band)": each(lambda u: np.interp(t[0] + (t - t[0]) / 2, t, u))}


def indistinguishable(results: list, passing: list[int], best: int, *,
                      alpha: float) -> list[tuple[int, float]]:
    """(index, p) of each passing candidate other than ``best`` that ``best`` does not
    predict the held-out segment better than at level ``alpha`` (one-sided p)."""
    out = []
    for i in passing:
        if i == best:
            continue
        p = predictive_test(results[i].holdout, results[best].holdout)["p_value"]
        if not p < alpha:
            out.append((i, float(p)))
    return out


def separating_input(models: list, time: np.ndarray, inputs: dict[str, np.ndarray],
                     noise: float) -> dict:
    """The input change of :func:`input_changes` under which ``models`` (the accepted one
    first) differ most: per change, the largest RMS difference of a model's response from
    the first's in units of ``noise`` (``None`` where a model's solve fails), and the
    change that maximises it (``None`` if every solve failed)."""
    start = models[0].initial_conditions or (0.0, 0.0)
    separation = {}
    for name, changed in input_changes(time, inputs).items():
        responses = [m.simulate_inputs(time, changed, start) for m in models]
        gaps = [float(np.sqrt(np.mean((r - responses[0]) ** 2))) / noise
                for r in responses[1:]]
        separation[name] = max(gaps) if np.all(np.isfinite(gaps)) else None
    proposals = {k: v for k, v in separation.items() if k != "this record" and v is not None}
    return {"change": max(proposals, key=proposals.get) if proposals else None,
            "separation": separation, "noise": noise}
