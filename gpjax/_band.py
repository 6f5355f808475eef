"""A 95 % prediction band of a model's simulated response from its constants' uncertainty.

``gpjax simulate --band`` and :func:`prediction_band`. The constants are drawn from the
distribution their intervals state (:mod:`gpjax._uncertainty`): each constant's t
distribution with its own degrees of freedom, scaled by its standard error, the draws
correlated as the constants are (a Gaussian copula of their correlation matrix). Every
draw is simulated in one batched call of the fixed-step RK4 evaluator the model was fitted
with; the band at each sample is the reference response plus the 2.5 % and 97.5 %
quantiles of the draws' departures from the RK4 response at the reported constants, so
the integrator's own error cancels and the band sits on the reference solve.

Why draws and not the linearised band J·Cov·Jᵀ: a lightly damped response is far from
linear in its stiffness and damping over a long record (a small change of the natural
frequency becomes a phase drift that grows with time), and a draw that makes the model
diverge is counted, not extrapolated. The initial state is held at the given one: the band
is that of the constants.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy import special

from ._data import Measurement
from ._errors import UserInputError
from ._uncertainty import constant_columns

#: Draws of the constants per band (the 2.5 % quantile then rests on 12 draws).
DRAWS = 500


@dataclasses.dataclass(frozen=True)
class Band:
    """A simulated response with its pointwise band.

    Attributes:
        response: (N,), or (N, D) for several coordinates, the reference response at the
            reported constants.
        low, high: the band's lower and upper edge, shaped as ``response`` (its units).
        level: the band's coverage probability per sample (0.95).
        draws: constant draws simulated.
        diverged: draws whose simulation failed (not in the band).
        constants: the names of the constants drawn.
    """

    response: np.ndarray
    low: np.ndarray
    high: np.ndarray
    level: float
    draws: int
    diverged: int
    constants: tuple[str, ...]


def prediction_band(model, time: np.ndarray, inputs: dict[str, np.ndarray],
                    initial_conditions, *, scale=None, seed: int = 0, draws: int = DRAWS,
                    level: float = 0.95) -> Band:
    """The ``level`` band of ``model``'s response (any number of coordinates) to
    ``inputs`` (name -> (N,)) at uniform sample ``time`` (s) from ``initial_conditions``
    ((x, x') or (D, 2)), from ``draws`` draws of its constants (module docstring);
    ``scale`` as :meth:`gpjax.Model.simulate_inputs` takes it, ``seed`` makes the draws
    reproducible.

    Raises:
        UserInputError: the model has no uncertainty, a constant has no finite standard
            error, or the reference solve at the reported constants fails.
    """
    uncertainty = model.uncertainty
    if uncertainty is None:
        raise UserInputError("the model file has no uncertainty section; refit its constants "
                             "(gpjax fit, or gpjax.refit) to get one before asking for --band")
    response = model.simulate_inputs(time, inputs, initial_conditions, scale=scale)
    if not np.all(np.isfinite(response)):
        raise UserInputError("the model diverged on this input (the reference solve failed); "
                             "check the input's units and the initial state")
    # The evaluator scores against a response; the reference one serves (scores unused).
    record = Measurement(time=time, responses=np.reshape(response, (time.size, -1)),
                         inputs=inputs, time_name=model.time, response_names=model.coordinates)
    evaluator = model.evaluator(record, batch=min(draws + 1, 512))
    base = model.population(evaluator, initial_conditions)
    columns = {name: column for column, name in constant_columns(
        evaluator.layout, model, evaluator).items() if not name.endswith("(0)")}
    names = tuple(n for n in uncertainty.names if n in columns)
    index = [uncertainty.names.index(n) for n in names]
    se = np.sqrt(np.diag(uncertainty.covariance))[index]
    unknown = [n for n, s in zip(names, se) if not np.isfinite(s)]
    if unknown:
        raise UserInputError(f"constant {unknown[0]!r} has no finite standard error (its "
                             "record cannot bound it: docs/limitations.md), so the model has "
                             "no band")
    flat = np.repeat(evaluator.layout.pack(base), draws + 1, axis=0)
    flat[1:, [columns[n] for n in names]] += _draws(
        uncertainty.correlation[np.ix_(index, index)], uncertainty.dof[index], draws,
        np.random.default_rng(seed)) * se
    mass, state, forcing, inner, y0 = evaluator.layout.split(flat)
    paths, _ = evaluator.simulate(dataclasses.replace(
        base, mass=mass, state=state, forcing=forcing[..., :base.forcing.shape[-1]],
        inner=inner, y0=y0))
    offsets = np.reshape(np.moveaxis(np.asarray(paths), -1, 1), (draws + 1,) + response.shape)
    offsets = offsets[1:] - offsets[0]  # (draws, N[, D])
    finite = np.all(np.isfinite(offsets.reshape(draws, -1)), axis=1)
    tail = (1 - level) / 2
    low, high = (np.quantile(offsets[finite], [tail, 1 - tail], axis=0) if finite.any()
                 else np.full((2,) + response.shape, np.nan))
    return Band(response=response, low=response + low, high=response + high, level=level,
                draws=draws, diverged=int(draws - finite.sum()), constants=names)


def _draws(correlation: np.ndarray, dof: np.ndarray, count: int,
           rng: np.random.Generator) -> np.ndarray:
    """(count, k) draws in standard errors: normal scores correlated by ``correlation``
    (a square root of it; a singular one's negative eigenvalues clipped at 0), each carried to the t
    distribution of its ``dof`` through the normal CDF."""
    eigenvalues, vectors = np.linalg.eigh(np.nan_to_num(correlation))
    root = vectors * np.sqrt(np.clip(eigenvalues, 0.0, None))
    scores = rng.standard_normal((count, correlation.shape[0])) @ root.T
    return special.stdtrit(np.maximum(dof, 1.0), special.ndtr(scores))
